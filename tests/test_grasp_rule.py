"""The grasp's success rule in geometry (pipeline.grasp_rule): the script's yaw, and the share of a set that the
script aimed at each hypothesis holds (the rule itself against the simulator: tests/test_probe.py)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.estimators.target_model import target_primitive
from pipeline.geometry import outline_point, primitive_pose, rotate
from pipeline.grasp import GraspParams, grasp_yaw, plan_for, pregrasp
from pipeline.grasp_rule import box_success, own_grasp_shares
from pipeline.scenes import load_scene


@pytest.mark.parametrize("scene", ["FB", "BC", "IB", "TC"])
def test_grasp_yaw_is_the_scripts_yaw(scene):
    sc = load_scene(scene)
    _, prim = target_primitive(sc)
    rng = np.random.default_rng(0)
    poses = np.column_stack([rng.uniform(0.1, 0.4, 50), rng.uniform(-0.1, 0.1, 50), rng.uniform(-4, 4, 50)])
    expected = [pregrasp(plan_for(sc), prim, p)[0] for p in poses]
    assert np.allclose(grasp_yaw(plan_for(sc), prim, poses), expected, atol=1e-12)


def test_shares_count_the_weight_each_grasp_holds():
    # three hypotheses within 0.02 rad of each other and one a quarter turn off: a grasp aimed at any of the three
    # holds the three (and not the fourth), the one aimed at the fourth only itself
    sc = load_scene("IB")
    _, prim = target_primitive(sc)
    poses = np.array([[0.25, 0.05, 0.30], [0.25, 0.05, 0.31], [0.25, 0.05, 0.29], [0.25, 0.05, 0.30 + np.pi / 2]])
    w = np.array([1.0, 1.0, 1.0, 2.0])
    share, held = own_grasp_shares(sc, prim, poses, w)
    assert held.tolist() == [[True, True, True, False]] * 3 + [[False, False, False, True]]
    assert np.allclose(share, [0.6, 0.6, 0.6, 0.4])
    # weights need not be normalised; one hypothesis holds all of itself
    share1, held1 = own_grasp_shares(sc, prim, poses[:1], np.array([7.0]))
    assert share1.tolist() == [1.0] and held1.tolist() == [[True]]


def _box_success_arrays(prim, poses, yaw, centre, advance, plan, scale, params=GraspParams(), n_outline=160):
    """The box rule as numpy arrays (G, H, K), the form the compiled kernel replaced: the reference it must match
    bit for bit (pipeline.grasp_rule, module docstring)."""
    from pipeline.grasp import OPEN, PAD_FROM_BASE
    from pipeline.grasp_rule import CONTACT_BAND, _frames

    hx, hy = prim.half[:2]
    approach, closing, base = _frames(yaw, centre, advance, plan, scale)
    pp = primitive_pose(prim, np.asarray(poses, dtype=np.float64).reshape(-1, 3))
    delta = (pp[None, :, 2] - yaw[:, None] + np.pi / 2) % np.pi - np.pi / 2
    local = outline_point((np.arange(n_outline) + 0.5) * (4 * (hx + hy) / n_outline), hx, hy)
    world = pp[:, None, :2] + rotate(local[None, :, :], pp[:, 2, None])
    rel = world[None, :, :, :] - base[:, None, None, :]
    depth = np.sum(rel * approach[:, None, None, :], axis=-1)
    lateral = np.sum(rel * closing[:, None, None, :], axis=-1)
    depth = depth + np.maximum(PAD_FROM_BASE[0] - depth.min(axis=2, keepdims=True), 0.0)
    band = (depth >= PAD_FROM_BASE[0]) & (depth <= PAD_FROM_BASE[1])
    ok = np.abs(delta) <= math.radians(params.face_angle_deg)
    ok &= band.any(axis=2)
    faces = []
    for sign in (1.0, -1.0):
        s = np.where(band, sign * lateral, -np.inf)
        reach = s.max(axis=2, keepdims=True)
        touch = band & (s >= reach - CONTACT_BAND)
        n = np.maximum(touch.sum(axis=2), 1)
        y_mean = np.where(touch, local[None, None, :, 1], 0.0).sum(axis=2) / n
        x_mean = np.where(touch, local[None, None, :, 0], 0.0).sum(axis=2) / n
        ok &= reach[..., 0] <= OPEN
        ok &= np.abs(y_mean) <= hy - params.corner_margin
        ok &= np.abs(x_mean) >= hx - 0.002
        faces.append(np.sign(x_mean))
    return ok & (faces[0] != faces[1])


@pytest.mark.parametrize("scene", ["FB", "BC", "IB"])
def test_compiled_box_rule_gives_the_array_forms_verdicts(scene):
    # sets from tight to a quarter turn wide around the true pose, each grasp aimed at each hypothesis, plus grasps
    # aimed exactly at a corner, at 45 degrees, a set of one and no grasp at all: the same verdict for every pair
    sc = load_scene(scene)
    _, prim = target_primitive(sc)
    plan = plan_for(sc)
    rng = np.random.default_rng(7)
    true = np.array([*sc.target.position[:2], sc.target.yaw])
    held = 0
    for spread in (0.0, 0.002, 0.01, 0.03, 0.1):
        poses = true + rng.normal(0.0, 1.0, (48, 3)) * [spread, spread, 3 * spread]
        yaw = grasp_yaw(plan, prim, poses)
        centre = prim.centre_world(poses)
        centre[:4] += rotate(np.asarray(prim.half[:2])[None, :], poses[:4, 2] + prim.yaw)  # aimed at a corner
        yaw[4:8] += np.pi / 4
        advance = rng.integers(0, 8, len(poses)).astype(np.float64)
        for sel in (slice(None), slice(0, 1), slice(0, 0)):
            want = _box_success_arrays(prim, poses, yaw[sel], centre[sel], advance[sel], plan, sc.action_scale)
            got = box_success(prim, poses, yaw[sel], centre[sel], advance[sel], plan, sc.action_scale)
            assert got.shape == want.shape and np.array_equal(got, want)
            held += int(want.sum())
    assert held > 0  # the comparison covers held grasps, not only misses
