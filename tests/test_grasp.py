"""grasp: the success rule on hand-made contacts, the restored final state, and simulated grasps at hand-placed
true and false poses (a box in the stored FB run's final state, a can in a clear TC scene)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from pipeline.grasp import (
    PAD_FROM_BASE,
    PLANS,
    FingerContacts,
    GraspParams,
    grasp_at,
    judge_box,
    judge_can,
    plan_for,
    pregrasp,
    restore_world,
)
from pipeline.retrieve import load_run, target_primitive
from pipeline.scenes import load_scene

REGRESSION = Path(__file__).resolve().parents[1] / "data" / "regression" / "FB-000.parquet"
P = GraspParams()


@pytest.fixture(scope="module")
def fb_run():
    return load_run(REGRESSION)


def _box():
    return target_primitive(load_scene("FB"))[1]


def _can():
    return target_primitive(load_scene("TC"))[1]


def _finger(points, normals, force=30.0):
    return FingerContacts(np.asarray(points, float).reshape(-1, 2), np.asarray(normals, float).reshape(-1, 2), force)


# ------------------------------------------------------------------------------------------------ rule (no sim)


def test_judge_box_accepts_both_long_faces():
    box = _box()
    pose = np.zeros(3)
    c = box.centre
    f = [_finger(c + [box.half[0], 0.02], [1, 0]), _finger(c + [-box.half[0], 0.03], [-1, 0])]
    assert judge_box(f, box, pose, P) == (True, "ok")


@pytest.mark.parametrize("case, why", [
    ("corner", "on a corner"),
    ("short_face", "not on a long face"),
    ("same_side", "same long face"),
    ("missing", "finger 1 does not touch"),
    ("weak", "presses with"),
])
def test_judge_box_rejects(case, why):
    box = _box()
    c = box.centre
    hx, hy = box.half
    a = _finger(c + [hx, 0.0], [1, 0])
    b = _finger(c + [-hx, 0.0], [-1, 0])
    if case == "corner":
        b = _finger(c + [-hx, hy - 0.004], [-1, 0])
    elif case == "short_face":
        b = _finger(c + [0.0, hy], [0, 1])
    elif case == "same_side":
        b = _finger(c + [hx, 0.03], [1, 0])
    elif case == "missing":
        b = _finger(np.zeros((0, 2)), np.zeros((0, 2)), 0.0)
    else:
        b = _finger(c + [-hx, 0.0], [-1, 0], force=0.2)
    ok, got = judge_box([a, b], box, np.zeros(3), P)
    assert not ok and why in got


def test_judge_box_is_rotation_invariant():
    box = _box()
    pose = np.array([0.3, -0.1, 2.0])
    R = np.array([[math.cos(2.0), -math.sin(2.0)], [math.sin(2.0), math.cos(2.0)]])
    c = box.centre_world(pose)
    f = [_finger(c + R @ [box.half[0], 0.0], R @ [1, 0]), _finger(c + R @ [-box.half[0], 0.01], R @ [-1, 0])]
    assert judge_box(f, box, pose, P)[0]


def test_judge_can_needs_opposite_sides_and_the_centre_between_the_pads():
    can = _can()
    r = can.half[0]
    c = can.centre
    a = np.array([1.0, 0.0])
    base = c - a * 0.08  # centre 8 cm ahead of the base: inside the pads [5.85, 11.22] cm
    left = _finger(c + [0, r], [0, 1])
    right = _finger(c - [0, r], [0, -1])
    assert judge_can([left, right], can, np.zeros(3), base, a, P) == (True, "ok")
    ok, why = judge_can([left, right], can, np.zeros(3), c - a * 0.13, a, P)  # pads short of the centre
    assert not ok and "outside the finger pads" in why
    front = _finger(c + r * np.array([-math.cos(0.6), math.sin(0.6)]), [-math.cos(0.6), math.sin(0.6)])
    ok, why = judge_can([front, right], can, np.zeros(3), base, a, P)
    assert not ok and "off the closing axis" in why
    ok, why = judge_can([left, left], can, np.zeros(3), base, a, P)
    assert not ok and "same side" in why
    assert PAD_FROM_BASE[0] < 0.08 < PAD_FROM_BASE[1]


def test_plans_follow_the_reference_grasp_offsets():
    box = _box()
    est = np.array([0.3, 0.0, 3.0])  # yaw 3.0 wraps to 3.0 - pi in FB's [-pi/2, pi/2]
    yaw, pre, approach = pregrasp(PLANS["FB"], box, est)
    assert yaw == pytest.approx(3.0 - math.pi)
    np.testing.assert_allclose(pre, box.centre_world(est) - 0.25 * approach)
    np.testing.assert_allclose(approach, [-math.sin(yaw), math.cos(yaw)])
    yaw, _, _ = pregrasp(PLANS["BC"], box, np.array([0.0, 0.0, 1.0]))
    assert yaw == pytest.approx(1.0 - math.pi)
    yaw, pre, approach = pregrasp(PLANS["TC"], _can(), np.array([0.18, 0.05, 2.0]))
    assert yaw == pytest.approx(-math.pi / 2)
    np.testing.assert_allclose(approach, [1.0, 0.0], atol=1e-12)
    assert plan_for(load_scene("IB")) is PLANS["IB"]


def test_a_box_scene_without_a_paper_plan_approaches_deeper():
    from pipeline.grasp import DEEP_OFFSET, PAD_FROM_BASE

    real = plan_for(load_scene("REAL"))
    assert (real.offset, real.yaw_range) == (DEEP_OFFSET, PLANS["FB"].yaw_range)
    assert real.guarded_steps == 5  # the cracker box's 15.75 cm in whole 3 cm actions
    assert all(PLANS[name].guarded_steps == 0 for name in PLANS)  # the paper's script: a fixed advance
    assert all(plan_for(load_scene(name)) is PLANS[name] for name in PLANS)  # the paper's tasks keep theirs
    # the offset that would centre the pads' span on the estimate after the script's advance
    assert DEEP_OFFSET == pytest.approx(GraspParams().approach_steps * 0.03 + sum(PAD_FROM_BASE) / 2, abs=1e-12)
    assert DEEP_OFFSET < PLANS["FB"].offset


# ------------------------------------------------------------------------------------------------ simulation


def test_the_deeper_approach_still_reaches_a_box_further_than_estimated(fb_run):
    """The palm stops at the box's near end: a deeper command reaches it when the estimate lies 5.5 cm short along
    the approach, where FB's offset closes on the box's end (docs/retrieval.md, "Grasp in simulation")."""
    from pipeline.grasp import DEEP_BOX, grasp_with

    true = np.asarray(fb_run.true_pose, dtype=np.float64)
    _, _, approach = pregrasp(PLANS["FB"], _box(), true)
    short = np.r_[true[:2] - 0.055 * approach, true[2]]
    held = {}
    for name, plan in (("FB", PLANS["FB"]), ("deep", DEEP_BOX)):
        yaw, pre, app = pregrasp(plan, _box(), short)
        held[name] = grasp_with(fb_run.scene, fb_run.final_poses, fb_run.final_ee, yaw, pre, app).success
    assert held == {"FB": False, "deep": True}


def test_the_guarded_approach_goes_on_to_a_box_further_than_the_deep_offset_reaches(fb_run):
    """Estimated 12 cm short along the approach: the deep plan's fixed advance closes on the box's near end, the
    guarded approach goes on until the palm meets it; at the true pose it stops there too and holds."""
    from pipeline.grasp import DEEP_BOX, grasp_with

    true = np.asarray(fb_run.true_pose, dtype=np.float64)
    _, _, approach = pregrasp(DEEP_BOX, _box(), true)
    held = {}
    for name, est in (("short", np.r_[true[:2] - 0.12 * approach, true[2]]), ("true", true)):
        yaw, pre, app = pregrasp(DEEP_BOX, _box(), est)
        for guarded in (0, 5):
            g = grasp_with(fb_run.scene, fb_run.final_poses, fb_run.final_ee, yaw, pre, app, guarded_steps=guarded)
            held[name, guarded] = g.success
    assert held == {("short", 0): False, ("short", 5): True, ("true", 0): True, ("true", 5): True}


def test_restore_world_puts_objects_at_their_recorded_final_poses(fb_run):
    with restore_world(fb_run.scene, fb_run.final_poses, fb_run.final_ee, P.settle_steps) as world:
        got = world.object_poses()
        pos = world.gripper_pose()[0]
    n = len(fb_run.scene.objects)
    np.testing.assert_allclose(got[:n, :2], fb_run.final_poses[:n, :2], atol=0.01)
    dyaw = (got[:n, 2] - fb_run.final_poses[:n, 2] + math.pi) % (2 * math.pi) - math.pi
    assert np.abs(dyaw).max() < 0.05
    np.testing.assert_allclose(pos[:2], fb_run.final_ee, atol=0.01)


def test_a_body_that_ended_knocked_over_is_restored_as_it_lay_and_recorded_so(fb_run):
    # the FB box laid on its broad face beside its recorded place: restored upright it would stand there; given as
    # tilted it lies, and the world reports it among the tilted bodies (what collect records at a run's end)
    tid = fb_run.target_id
    x, y, _ = fb_run.final_poses[tid]
    half = np.array(fb_run.scene.objects[tid].size) / 2.0
    lying = np.r_[x, y, half[0], 0.0, np.sin(math.pi / 4), 0.0, np.cos(math.pi / 4)]  # 90 deg about y: on its face
    with restore_world(fb_run.scene, fb_run.final_poses, fb_run.final_ee, 0) as world:
        assert world.tilted_poses() == {}  # everything upright, as every body of the stored run ended
    with restore_world(fb_run.scene, fb_run.final_poses, fb_run.final_ee, P.settle_steps, {tid: lying}) as world:
        tilted = world.tilted_poses()
        upright = world.object_poses()
    name = fb_run.scene.body_names[tid]
    assert list(tilted) == [name]
    # still lying where it was put (a lying box rests), the quaternion's tilt about 90 degrees
    assert tilted[name][:2] == pytest.approx(lying[:2], abs=0.01)
    q = np.array(tilted[name][3:])
    assert math.degrees(math.acos(1.0 - 2.0 * (q[0] ** 2 + q[1] ** 2))) == pytest.approx(90.0, abs=5.0)
    others = [i for i in range(len(fb_run.scene.objects)) if i != tid]
    np.testing.assert_allclose(upright[others, :2], fb_run.final_poses[others, :2], atol=0.01)


def _with_tilted(tmp_path, tilted):
    """The stored FB run with ``params.tilted`` set to ``tilted`` (None: the key absent)."""
    import pyarrow.parquet as pq

    from pipeline.schema import read_metadata, write_table

    params = dict(read_metadata(REGRESSION)["params"])
    if tilted is not None:
        params["tilted"] = tilted
    path = tmp_path / "FB-000.parquet"
    write_table(pq.read_table(REGRESSION).replace_schema_metadata(None), path, stage="collect", params=params,
                seed=0, kind="sim_run")
    return path


def test_a_runs_tilted_bodies_are_read_by_index_and_checked(tmp_path):
    from pipeline.schema import SchemaError

    pose = [0.1, 0.2, 0.03, 0.0, math.sin(math.pi / 4), 0.0, math.cos(math.pi / 4)]
    assert load_run(_with_tilted(tmp_path, None)).final_tilted == {}
    info = load_run(_with_tilted(tmp_path, {"cracker_box": pose}))
    tid = info.scene.body_names.index("cracker_box")
    assert list(info.final_tilted) == [tid] and info.final_tilted[tid].tolist() == pose
    for bad in ({"kettle": pose}, {"cracker_box": pose[:6]}, {"cracker_box": [*pose[:3], 0.0, 0.0, 0.0, 2.0]},
                {"cracker_box": "lying"}, {"cracker_box": [None, *pose[1:]]}, ["cracker_box"]):
        with pytest.raises(SchemaError, match="params.tilted"):
            load_run(_with_tilted(tmp_path, bad))


def _shift_across(pose, d):
    """The box pose moved by d along its short axis (across the grasp)."""
    return pose + np.array([d * math.cos(pose[2]), d * math.sin(pose[2]), 0.0])


@pytest.mark.parametrize("name, make, success", [
    ("true pose", lambda t: t, True),
    ("true pose turned by pi (symmetric)", lambda t: t + [0.0, 0.0, math.pi], True),
    ("shifted 5 cm across", lambda t: _shift_across(t, 0.05), False),
    ("shifted 5 cm in x", lambda t: t + [0.05, 0.0, 0.0], False),
    ("rotated 90 deg", lambda t: t + [0.0, 0.0, math.pi / 2], False),
])
def test_box_grasp_in_stored_final_state(fb_run, name, make, success):
    est = make(fb_run.true_pose.copy())
    g = grasp_at(fb_run.scene, fb_run.final_poses, fb_run.final_ee, est, P)
    assert g.success is success, (name, g.outcome)
    assert g.reached
    assert math.isfinite(g.wall_s) and g.wall_s > 0


def _clear_tc_state():
    """TC with the target can where the scene puts it and the clutter moved far away (a hand-made state)."""
    scene = load_scene("TC")
    poses = []
    for i, o in enumerate(scene.objects):
        c, s = math.cos(o.yaw), math.sin(o.yaw)
        com = np.array(o.position) + np.array([[c, -s], [s, c]]) @ np.array(o.com_offset[:2])
        xy = com if o.target else np.array([2.0 + 0.5 * i, 2.0])
        poses.append([xy[0], xy[1], o.yaw + o.com_yaw])
    poses += [[w.position[0], w.position[1], w.yaw] for w in scene.walls]
    return scene, np.array(poses)


@pytest.mark.parametrize("name, delta, success", [
    ("true pose", [0.0, 0.0, 0.0], True),
    ("rotated 90 deg (a can has no yaw)", [0.0, 0.0, math.pi / 2], True),
    ("shifted 5 cm across", [0.0, 0.05, 0.0], False),
    ("shifted 5 cm short", [-0.05, 0.0, 0.0], False),
])
def test_can_grasp_at_hand_placed_poses(name, delta, success):
    scene, poses = _clear_tc_state()
    tid = next(i for i, o in enumerate(scene.objects) if o.target)
    truth = poses[tid]
    # The rotated estimate keeps the can's axis: rotate the COM about it.
    can = _can()
    est = truth + np.asarray(delta)
    if delta[2]:
        axis = can.centre_world(truth)
        c, s = math.cos(est[2]), math.sin(est[2])
        est[:2] = axis - np.array([[c, -s], [s, c]]) @ can.centre
    g = grasp_at(scene, poses, np.array(scene.gripper_start), est, P)
    assert g.success is success, (name, g.outcome)


def test_a_grasp_is_simulated_once_per_process(fb_run, monkeypatch):
    """The same run, pose and parameters again (two estimators agreeing) reuse the first simulation: an equal,
    independent result; other parameters simulate afresh."""
    import pipeline.grasp as grasp_module

    calls = []
    real = grasp_module._simulate_grasp
    monkeypatch.setattr(grasp_module, "_simulate_grasp", lambda *a: calls.append(a) or real(*a))
    monkeypatch.setattr(grasp_module, "_MEMO", type(grasp_module._MEMO)())
    est = fb_run.true_pose + np.array([0.004, -0.003, 0.02])
    a = grasp_at(fb_run.scene, fb_run.final_poses, fb_run.final_ee, est, P)
    b = grasp_at(fb_run.scene, fb_run.final_poses.copy(), fb_run.final_ee.copy(), est.copy(), P)
    assert len(calls) == 1
    assert (b.success, b.outcome, b.reached, b.yaw) == (a.success, a.outcome, a.reached, a.yaw)
    np.testing.assert_array_equal(b.target_pose, a.target_pose)
    for fa, fb in zip(a.fingers, b.fingers):
        np.testing.assert_array_equal(fb.points, fa.points)
        assert fb.force == fa.force
    b.target_pose[0] += 1.0  # a copy: changing it changes neither the first result nor the next one
    assert grasp_at(fb_run.scene, fb_run.final_poses, fb_run.final_ee, est, P).target_pose[0] == a.target_pose[0]
    assert len(calls) == 1
    grasp_at(fb_run.scene, fb_run.final_poses, fb_run.final_ee, est, GraspParams(settle_steps=239))
    moved = fb_run.final_poses.copy()
    moved[-1, 0] = np.nextafter(moved[-1, 0], 1.0)  # one bit of one body's recorded pose
    grasp_at(fb_run.scene, moved, fb_run.final_ee, est, P)
    assert len(calls) == 3


def test_a_waypoint_is_visited_before_the_pre_grasp_point(fb_run, monkeypatch):
    """``via``: the gripper goes to each waypoint first, as it goes to the pre-grasp point. A waypoint at the start
    changes nothing (it is already there), to the bit; one elsewhere is simulated afresh (its own memo entry) and
    the move through it is made."""
    import pipeline.grasp as grasp_module

    monkeypatch.setattr(grasp_module, "_MEMO", type(grasp_module._MEMO)())
    yaw, pre, approach = pregrasp(plan_for(fb_run.scene), _box(), fb_run.true_pose)
    goals = []
    real = grasp_module.move_to
    monkeypatch.setattr(grasp_module, "move_to", lambda w, g, *a: goals.append(np.array(g)) or real(w, g, *a))
    a = grasp_module.grasp_with(fb_run.scene, fb_run.final_poses, fb_run.final_ee, yaw, pre, approach, P)
    b = grasp_module.grasp_with(fb_run.scene, fb_run.final_poses, fb_run.final_ee, yaw, pre, approach, P,
                                via=fb_run.final_ee[None, :])
    assert (b.success, b.outcome, b.reached) == (a.success, a.outcome, a.reached)
    np.testing.assert_array_equal(b.target_pose, a.target_pose)
    assert len(goals) == 3  # a: pre; b: the waypoint, then pre
    np.testing.assert_array_equal(goals[1], fb_run.final_ee)
