"""pipeline.estimators.paper.icp_kernel: the compiled ICP iterations give the bits of the batched numpy form they
replaced (kept here as the reference), jitted and with NUMBA_DISABLE_JIT=1."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pipeline.estimators.paper.choice import min_clearance
from pipeline.estimators.paper.icp import _icp, icp_error, icp_restarts, initial_transforms
from pipeline.estimators.paper.icp_kernel import _npsum, nearest_model
from pipeline.estimators.target_model import model_normals
from pipeline.geometry import apply_pose, rotate
from pipeline.portable import atan2
from pipeline.retrieve import RetrievalParams, model_points, retrieval_rng, target_primitive
from pipeline.robot import load_robot
from pipeline.scenes import load_scene
from pipeline.spd import solve_spd

ROOT = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------- the numpy form (reference, verbatim)
def _np_correspond(tree, moved, radius):
    d, idx = tree.query(moved.reshape(-1, 2), k=1)
    idx = np.minimum(idx, tree.n - 1).reshape(moved.shape[:2])
    return idx, (d <= radius).reshape(moved.shape[:2])


def _np_fit_stats(moved, target, matched):
    r2 = np.where(matched, np.sum((moved - target) ** 2, axis=-1), 0.0)
    n = matched.sum(axis=1)
    return n / matched.shape[1], np.sqrt(np.sum(r2, axis=1) / np.maximum(n, 1))


def _np_point_to_point(points, target, matched):
    w = matched.astype(np.float64)
    n = np.maximum(w.sum(axis=1), 1.0)[:, None]
    p_mean = np.sum(w[..., None] * points[None], axis=1) / n
    q_mean = np.sum(w[..., None] * target, axis=1) / n
    p = points[None] - p_mean[:, None, :]
    q = target - q_mean[:, None, :]
    cross = np.sum(w * (p[..., 0] * q[..., 1] - p[..., 1] * q[..., 0]), axis=1)
    dot = np.sum(w * (p[..., 0] * q[..., 0] + p[..., 1] * q[..., 1]), axis=1)
    theta = atan2(cross, dot)
    return np.column_stack([q_mean - rotate(p_mean, theta), theta])


def _np_point_to_plane_step(moved, target, normals, matched):
    w = matched.astype(np.float64)
    nx, ny = normals[..., 0], normals[..., 1]
    r = (moved[..., 0] - target[..., 0]) * nx + (moved[..., 1] - target[..., 1]) * ny
    J = np.stack([nx, ny, moved[..., 0] * ny - moved[..., 1] * nx], axis=-1)
    wJ = J * w[..., None]
    H = np.sum(wJ[..., :, None] * J[..., None, :], axis=1) + 1e-12 * np.eye(3)
    g = np.sum(wJ * r[..., None], axis=1)
    return -solve_spd(H, g)


def _np_compose(step, tf):
    return np.column_stack([rotate(tf[:, :2], step[:, 2]) + step[:, :2], tf[:, 2] + step[:, 2]])


def _np_icp(points, model, inits, radius, max_iteration, normals):
    tree = cKDTree(model)
    tf = inits.copy()

    def state(tf):
        moved = apply_pose(tf, points)
        idx, matched = _np_correspond(tree, moved, radius)
        return moved, idx, matched, _np_fit_stats(moved, model[idx], matched)

    moved, idx, matched, (fit, rmse) = state(tf)
    active = np.ones(len(tf), dtype=bool)
    for _ in range(max_iteration):
        a = np.flatnonzero(active)
        if not len(a):
            break
        if normals is None:
            new = _np_point_to_point(points, model[idx[a]], matched[a])
        else:
            new = _np_compose(_np_point_to_plane_step(moved[a], model[idx[a]], normals[idx[a]], matched[a]), tf[a])
        new = np.where(matched[a].any(axis=1)[:, None], new, tf[a])
        moved2, idx2, matched2, (fit2, rmse2) = state(new)
        done = (np.abs(fit2 - fit[a]) < 1e-9) & (np.abs(rmse2 - rmse[a]) < 1e-9)
        tf[a], moved[a], idx[a], matched[a], fit[a], rmse[a] = new, moved2, idx2, matched2, fit2, rmse2
        active[a[done]] = False
    return tf


def _np_icp_error(world_to_model, points, model, normals=None):
    moved = apply_pose(world_to_model, points)
    diff = moved[:, :, None, :] - model[None, None, :, :]
    nearest = np.argmin(np.sum(diff ** 2, axis=-1), axis=2)
    d = np.take_along_axis(diff, nearest[..., None, None], axis=2)[:, :, 0, :]
    if normals is None:
        r2 = np.sum(d ** 2, axis=-1)
    else:
        gaps = np.sqrt(np.sum((model[:, None, :] - model[None, :, :]) ** 2, axis=-1))
        np.fill_diagonal(gaps, np.inf)
        half_gap = 0.5 * float(gaps.min(axis=1).max()) if len(model) > 1 else 0.0
        along = np.abs(np.sum(d * np.asarray(normals)[nearest], axis=-1))
        r2 = np.maximum(along, np.linalg.norm(d, axis=-1) - half_gap) ** 2
    return np.sqrt(r2.mean(axis=1))


# ------------------------------------------------------------------------------------------------- cases
def _cases():
    """(name, points, model, normals, inits, radius, max_iteration): a box and a can, segments of 1 to 200 points
    (above 128 numpy's pairwise sum splits), noisy, duplicated, far away, a radius leaving points unmatched."""
    rng = np.random.default_rng(21)
    out = []
    for scene in ("FB", "TC"):
        target = target_primitive(load_scene(scene))[1]
        model = model_points(target, RetrievalParams(), retrieval_rng(3, f"kernel/{scene}")[0])
        normals = model_normals(target, model)
        for m in (1, 2, 3, 7, 8, 9, 13, 31, 130, 200):
            pose = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-np.pi, np.pi)])
            pts = apply_pose(pose, model[rng.integers(0, len(model), m)]) + rng.normal(0, 0.004, (m, 2))
            inits = initial_transforms(pts, model, 30, rng)
            out.append((f"{scene}-{m}", pts, model, normals, inits, 1.0, 30))
            out.append((f"{scene}-{m}-radius", pts, model, normals, inits, 0.02, 30))
        dup = np.repeat(apply_pose(np.array([0.1, 0.2, 0.3]), model[:5]), 3, axis=0)
        out.append((f"{scene}-duplicates", dup, model, normals, initial_transforms(dup, model, 30, rng), 1.0, 30))
        far = rng.normal(5.0, 0.01, (6, 2))
        out.append((f"{scene}-far-unmatched", far, model, normals, initial_transforms(far, model, 30, rng) * 0.0,
                    0.05, 30))
        out.append((f"{scene}-few-iterations", pts, model, normals, inits, 1.0, 2))
    return out


CASES = _cases()
#: The cases run as Python too (small ones, 5 restarts: pure Python is ~1000x slower): unmatched points, a block
#: of eight accumulators, nothing matched.
NOJIT = [c[:4] + (c[4][:5],) + c[5:] for c in CASES if c[0] in ("FB-2-radius", "FB-9", "TC-far-unmatched")]


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_kernel_gives_the_bits_of_the_numpy_form(case):
    _, pts, model, normals, inits, radius, iters = case
    params = RetrievalParams(max_correspondence_distance=radius, max_iteration=iters)
    for nrm in (None, normals):
        want = _np_icp(pts, model, inits, radius, iters, nrm)
        got = _icp(pts, model, inits, params, nrm)
        assert got.shape == want.shape
        assert np.array_equal(got.view(np.int64), want.view(np.int64)), np.abs(got - want).max()


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_icp_error_and_nearest_points_are_the_numpy_and_cktree_ones(case):
    _, pts, model, normals, inits, _, _ = case
    for nrm in (None, normals):
        assert np.array_equal(icp_error(inits, pts, model, nrm).view(np.int64),
                              _np_icp_error(inits, pts, model, nrm).view(np.int64))
    moved = apply_pose(inits, pts)
    d, i = cKDTree(model).query(moved.reshape(-1, 2), k=1)
    idx, d2 = nearest_model(moved, model)
    assert np.array_equal(idx.reshape(-1), i)
    assert np.array_equal(np.sqrt(d2).reshape(-1).view(np.int64), d.view(np.int64))


def test_kernel_moves_the_far_unmatched_segment_nowhere():
    _, pts, model, normals, inits, radius, iters = next(c for c in CASES if c[0] == "FB-far-unmatched")
    got = _icp(pts, model, inits, RetrievalParams(max_correspondence_distance=radius), None)
    assert np.array_equal(got, inits)


@pytest.mark.parametrize("n", [0, 1, 7, 8, 9, 15, 16, 127, 128, 129, 136, 255, 256, 257, 1000, 4099])
def test_pairwise_sum_is_numpy_s(n):
    rng = np.random.default_rng(n)
    a = rng.normal(0, 1, n) * 10.0 ** rng.integers(-8, 8, n)
    assert np.float64(_npsum(a)).view(np.int64) == np.sum(a).view(np.int64)


def _nojit_lines(cases, robot):
    """What the no-JIT run prints: every field of icp_restarts and a min_clearance per case, as hex bits."""
    lines = []
    for name, pts, model, normals, inits, radius, iters in cases:
        for est in ("point_to_plane",):  # point-to-point, then point-to-plane from its result
            p = RetrievalParams(max_correspondence_distance=radius, max_iteration=iters, estimation=est)
            r = icp_restarts(pts, model, inits, p, normals)
            pen = min_clearance(robot, model, r.poses, r.poses[:, :2] + 0.05)
            lines.append(" ".join([name, est] + [a.tobytes().hex() for a in (r.world_to_model, r.poses, r.rmse,
                                                                              r.valid, pen)]))
    return lines


def test_without_jit_the_same_bits():
    """NUMBA_DISABLE_JIT=1 runs the kernels as Python (math's functions, Python floats): the same bits."""
    code = ("import sys; sys.path.insert(0, 'tests'); import test_icp_kernel as t\n"
            "from pipeline.robot import load_robot\n"
            "print('\\n'.join(t._nojit_lines(t.NOJIT, load_robot('panda'))))\n")
    env = dict(os.environ, NUMBA_DISABLE_JIT="1", PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True,
                         check=True).stdout.split("\n")
    assert out[:-1] == _nojit_lines(NOJIT, load_robot("panda"))


def test_min_clearance_is_the_grid_query_bit_for_bit():
    panda = load_robot("panda")
    rng = np.random.default_rng(4)
    for _ in range(30):
        model = rng.normal(0, 0.05, (30, 2))
        poses = np.column_stack([rng.uniform(-0.3, 0.3, (20, 2)), rng.uniform(-3, 3, 20)])
        ee = rng.uniform(-0.4, 0.4, (int(rng.integers(1, 40)), 2))
        world = apply_pose(poses, model)
        every = panda.query(world[:, :, None, :] - ee[None, None]).reshape(len(world), -1).min(axis=1)
        got = min_clearance(panda, model, poses, ee)
        assert np.array_equal(got.view(np.int64), every.view(np.int64))
        assert (got < panda.outside_value).any()
