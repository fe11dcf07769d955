"""The planned grasp (pipeline/probe/grasp_plan.py) and its attempts (pipeline/probe/grasp_attempts.py): every
approach the shape allows, a way in through sensed free space, re-planning after a felt miss; never ground truth
(docs/active.md, "The planned grasp")."""
from __future__ import annotations

import dataclasses
import inspect
import math
from pathlib import Path

import numpy as np
import pytest

from pipeline.estimators.run_info import load_run
from pipeline.geometry import Primitive
from pipeline.probe import grasp_plan
from pipeline.probe.grasp_attempts import NO_REACHABLE_GRASP, attempt_grasps, felt_width
from pipeline.probe.grasp_plan import PlanningParams, Surroundings, approach_offset, plan_grasp

BOX = Primitive(kind="box", half=(0.0308, 0.07875), centre=np.zeros(2), yaw=0.0)
CAN = Primitive(kind="cylinder", half=(0.039,), centre=np.zeros(2), yaw=0.0)
RING = np.array([[0.0, 0.0], [0.0, 0.0]])  # a gripper of two coincident outline points: plain distances
REGRESSION = Path(__file__).resolve().parents[1] / "data" / "regression"


def grasp_plan_set(poses, weights, best):
    """A stand-in for a plausible set: what :func:`attempt_grasps` reads of one (poses, weights, best)."""
    return dataclasses.make_dataclass("Set", ["poses", "weights", "best"])(np.asarray(poses, dtype=np.float64),
                                                                           np.asarray(weights), best)


def _around(here, visited=None, obstacles=(), walls=()):
    here = np.asarray(here, dtype=np.float64)
    visited = here[None, :] if visited is None else np.asarray(visited, dtype=np.float64)
    return Surroundings(here, visited, np.asarray(obstacles, dtype=np.float64).reshape(-1, 2), list(walls), RING)


def test_a_box_is_approached_along_its_long_axis_from_either_end():
    # the gripper below the box (-y): the near end's approach (+y) is the short way in
    g = plan_grasp(BOX, 0.03, np.zeros((1, 3)), np.ones(1), 0, _around([0.0, -0.4]))
    assert g.reachable and g.share == 1.0
    assert g.approach == pytest.approx([0.0, 1.0], abs=1e-9)
    # from above (+y) it comes in from the other end
    g = plan_grasp(BOX, 0.03, np.zeros((1, 3)), np.ones(1), 0, _around([0.0, 0.4]))
    assert g.reachable and g.approach == pytest.approx([0.0, -1.0], abs=1e-9)
    assert np.linalg.norm(g.pregrasp) == pytest.approx(approach_offset(BOX))


def test_a_blocked_end_is_planned_around_to_the_other():
    # objects sensed all along the near end's lane: the plan goes round to the far end, through unknown space
    lane = np.column_stack([np.linspace(-0.05, 0.05, 11), np.full(11, -0.12)])
    g = plan_grasp(BOX, 0.03, np.zeros((1, 3)), np.ones(1), 0,
                   _around([0.0, -0.4], visited=[[0.0, -0.4], [0.0, -0.2]], obstacles=lane))
    assert g.reachable and g.approach[1] < 0  # from +y
    assert len(g.via) >= 2  # a detour, not the straight move
    assert g.via[-1] == pytest.approx(g.pregrasp)


def _box_in(centre, inner):
    """Four walls (centre (2,), half extents (2,), yaw) enclosing a square of half side ``inner`` around ``centre``."""
    c = np.asarray(centre, dtype=np.float64)
    t = 0.05
    across, up = np.array([inner + 2 * t, t]), np.array([t, inner])
    return [(c + [0.0, inner + t], across, 0.0), (c - [0.0, inner + t], across, 0.0),
            (c + [inner + t, 0.0], up, 0.0), (c - [inner + t, 0.0], up, 0.0)]


def test_no_way_in_is_reported_not_raised():
    # the gripper walled in 6 cm around itself: no pre-grasp point lies in its box
    g = plan_grasp(BOX, 0.03, np.zeros((1, 3)), np.ones(1), 0, _around([0.0, -0.6], walls=_box_in([0.0, -0.6], 0.06)))
    assert not g.reachable and math.isinf(g.cost)


def test_sensed_objects_cost_but_do_not_forbid():
    # objects sensed all around the target: the way in passes them (it may push them aside), at a cost
    ring = 0.3 * np.column_stack([np.cos(np.linspace(0, 2 * np.pi, 120)), np.sin(np.linspace(0, 2 * np.pi, 120))])
    free = plan_grasp(BOX, 0.03, np.zeros((1, 3)), np.ones(1), 0, _around([0.0, -0.6]))
    g = plan_grasp(BOX, 0.03, np.zeros((1, 3)), np.ones(1), 0, _around([0.0, -0.6], obstacles=ring))
    assert g.reachable and g.cost > free.cost


def test_a_can_is_approached_from_the_open_side():
    # a wall of sensed objects on three sides of the can: the only open side is -x
    side = np.linspace(-0.12, 0.12, 13)
    walls = np.vstack([np.column_stack([side, np.full(13, 0.12)]), np.column_stack([side, np.full(13, -0.12)]),
                       np.column_stack([np.full(13, 0.12), side])])
    g = plan_grasp(CAN, 0.03, np.zeros((1, 3)), np.ones(1), 0, _around([-0.5, 0.0], obstacles=walls))
    assert g.reachable and g.approach[0] > 0.9


def test_the_set_share_decides_between_centres():
    # two hypotheses 4 cm apart along the box's short axis: a grasp centred between them holds neither fully;
    # with the weight on the second, the plan centres on it
    poses = np.array([[0.0, 0.0, 0.0], [0.04, 0.0, 0.0]])
    g = plan_grasp(BOX, 0.03, poses, np.array([0.1, 0.9]), 0, _around([0.0, -0.5]))
    assert g.share == pytest.approx(0.9)
    assert g.centre[0] == pytest.approx(0.04)


def test_degenerate_sets_stay_finite():
    one = plan_grasp(BOX, 0.03, np.zeros((1, 3)), np.ones(1), 0, _around([0.0, 0.0]))  # starting on the target
    assert np.all(np.isfinite(one.pregrasp))
    same = plan_grasp(BOX, 0.03, np.zeros((5, 3)), np.full(5, 1e-300), 2, _around([0.0, -0.4]))
    assert same.reachable and same.share == pytest.approx(1.0)


def test_the_planner_takes_no_scene():
    # what it may know is its arguments: the target's shape, the action scale, the set and what was sensed
    params = set(inspect.signature(plan_grasp).parameters)
    assert params == {"prim", "scale", "poses", "weights", "best", "surroundings", "params", "grasp"}
    src = inspect.getsource(grasp_plan)
    for truth in ("pipeline.scenes", "pipeline.sim", "run_info", "final_poses", "true_pose", "obj_pose", ".objects"):
        assert truth not in src, truth


def test_the_surroundings_do_not_depend_on_the_objects_true_poses():
    from pipeline.probe.belief import NO_TARGET, Sensing
    from pipeline.probe.retrieval import surroundings_of
    from pipeline.schema import read_run

    info = load_run(REGRESSION / "IB-001.parquet")
    sensing = Sensing(info.run, 0, info.ee[0], read_run(info.path).num_rows)
    moved = dataclasses.replace(info.scene, objects=tuple(dataclasses.replace(o, position=(o.position[0] + 0.3,
                                                                                           o.position[1]))
                                                          for o in info.scene.objects))
    a = surroundings_of(sensing, NO_TARGET, [], info.scene)
    b = surroundings_of(sensing, NO_TARGET, [], moved)
    assert np.array_equal(a.obstacles, b.obstacles) and np.array_equal(a.visited, b.visited)


@pytest.fixture(scope="module")
def ib_run():
    return load_run(REGRESSION / "IB-001.parquet")


def _open_space(info) -> Surroundings:
    """The gripper at the run's end, having visited its whole trail; no obstacle sensed."""
    return Surroundings(info.final_ee.copy(), info.ee.copy(), np.zeros((0, 2)), [], RING)


def test_a_grasp_at_the_true_pose_is_held_on_the_first_attempt(ib_run):
    info = ib_run
    r = attempt_grasps(info.scene, info.final_poses, info.final_ee, info.target, info.true_pose[None, :],
                       np.ones(1), 0, _open_space(info))
    assert r.first_success and r.success and len(r.attempts) == 1
    assert r.attempts[0].width == pytest.approx(felt_width(info.target), abs=0.002)


def test_a_grasp_that_lands_on_a_corner_or_on_nothing_is_felt_and_retried(ib_run):
    info = ib_run
    true = np.asarray(info.true_pose, dtype=np.float64)
    # a set whose most likely hypothesis lies 4.5 cm across the box from the truth (a finger then closes on its
    # edge or beside it), and a less likely one at the truth
    across = np.array([math.cos(true[2]), math.sin(true[2])])
    wrong = np.r_[true[:2] + 0.045 * across, true[2]]
    r = attempt_grasps(info.scene, info.final_poses, info.final_ee, info.target, np.vstack([wrong, true]),
                       np.array([0.8, 0.2]), 0, _open_space(info), PlanningParams(advances=(4,)))
    first = r.attempts[0]
    assert not first.success and not first.felt_ok  # the robot felt the miss without reading the judge
    assert len(r.attempts) >= 2 and r.success


def _sure_elsewhere(info) -> np.ndarray:
    """A set of one hypothesis 15 cm beside the true pose (-x), in free space: a grasp there reaches its
    pre-grasp point and closes on nothing."""
    true = np.asarray(info.true_pose, dtype=np.float64)
    return np.r_[true[:2] + [-0.15, 0.0], true[2]][None, :]


def test_a_sure_set_that_finds_no_target_turns_to_the_next_segment(ib_run):
    info = ib_run
    asked = []

    def next_set(k):
        asked.append(k)
        belief = grasp_plan_set(info.true_pose[None, :], np.ones(1), 0)
        return (belief, _open_space(info)) if k == 1 else None

    r = attempt_grasps(info.scene, info.final_poses, info.final_ee, info.target, _sure_elsewhere(info),
                       np.ones(1), 0, _open_space(info), next_set=next_set)
    assert asked == [1]  # asked once, after the first attempt's felt miss
    assert not r.attempts[0].felt_ok and not r.first_success
    assert len(r.attempts) == 2 and r.success


def test_a_set_that_was_not_sure_keeps_its_segment(ib_run):
    info = ib_run
    asked = []
    # the first grasp holds 60 % of the set (a hypothesis in free space), under switch_share: its miss moves the
    # weight to the set's other hypothesis, not to another segment (the last attempt asks for nothing)
    beside = np.r_[info.true_pose[:2] + [0.1, -0.15], info.true_pose[2]]
    r = attempt_grasps(info.scene, info.final_poses, info.final_ee, info.target,
                       np.vstack([beside, info.true_pose]), np.array([0.6, 0.4]), 0, _open_space(info),
                       PlanningParams(attempts=2), next_set=lambda k: asked.append(k))
    assert asked == [] and len(r.attempts) == 2
    assert r.attempts[0].reached and not r.attempts[0].felt_ok
    assert np.hypot(*(r.attempts[1].grasp.centre - info.true_pose[:2])) < 0.02  # the set's other hypothesis


def test_no_next_segment_falls_back_to_the_set_itself(ib_run):
    info = ib_run
    asked = []
    wrong = _sure_elsewhere(info)
    r = attempt_grasps(info.scene, info.final_poses, info.final_ee, info.target, wrong, np.ones(1), 0,
                       _open_space(info), PlanningParams(attempts=2), next_set=lambda k: asked.append(k))
    # asked for the first next segment after the first miss, got none, and tried its own set again
    assert asked == [1] and len(r.attempts) == 2 and not r.success
    assert all(np.hypot(*(a.grasp.centre - wrong[0, :2])) < 0.05 for a in r.attempts)


def test_an_unreachable_target_ends_with_a_note(ib_run):
    info = ib_run
    # the gripper walled in 5 cm around itself (walls of the plan's world only): no pre-grasp point in its box
    around = Surroundings(info.final_ee.copy(), info.final_ee[None, :].copy(), np.zeros((0, 2)),
                          _box_in(info.final_ee, 0.05), RING)
    r = attempt_grasps(info.scene, info.final_poses, info.final_ee, info.target, info.true_pose[None, :],
                       np.ones(1), 0, around)
    assert not r.success and r.attempts[-1].outcome == NO_REACHABLE_GRASP


def test_a_gripper_against_the_target_can_still_leave_and_plan():
    # the gripper stopped 3 mm from the box's long face, with the real gripper's outline
    from pipeline.probe.planning import gripper_outline
    from pipeline.robot import load_robot

    outline = gripper_outline(load_robot("panda"))
    here = np.array([BOX.half[0] + 0.003 + float(np.max(-outline[:, 0])), 0.0])
    s = Surroundings(here, here[None, :], np.zeros((0, 2)), [], outline)
    g = plan_grasp(BOX, 0.03, np.zeros((1, 3)), np.ones(1), 0, s)
    assert g.reachable and len(g.via) >= 1


def test_a_gripper_already_at_the_pregrasp_point_still_has_a_way_in():
    pre = np.array([0.0, -approach_offset(BOX)])
    g = plan_grasp(BOX, 0.03, np.zeros((1, 3)), np.ones(1), 0, _around(pre + [0.001, 0.0]))
    assert g.reachable and len(g.via) >= 1 and np.allclose(g.via[-1], g.pregrasp)


@pytest.mark.parametrize("weights", [np.zeros(2), np.array([np.nan, 1.0]), np.array([-1.0, 2.0])])
def test_a_set_without_usable_weights_is_refused_in_one_line(weights):
    with pytest.raises(ValueError, match="finite weights >= 0, not all 0"):
        plan_grasp(BOX, 0.03, np.zeros((2, 3)), weights, 0, _around([0.0, -0.4]))


def test_a_lane_through_a_wall_is_never_taken():
    # a wall just beyond the box's -y end: the near end's lane (+y approach from -y) would sweep it
    wall = [(np.array([0.0, -0.16]), np.array([0.2, 0.01]), 0.0)]
    g = plan_grasp(BOX, 0.03, np.zeros((1, 3)), np.ones(1), 0, _around([0.3, 0.0], walls=wall))
    assert g.reachable and g.approach[1] < 0  # from the +y end


def test_a_can_is_not_approached_with_a_sensed_object_between_the_fingers():
    # the gripper below the can, an object sensed just below it: the short lane from below would close the fingers
    # on that object (or push it into the can); the plan pays to come in from a side with nothing between them
    here = [0.0, -0.45]
    visited = [[0.0, -0.45], [0.0, -0.25]]
    blocker = [[0.0, -0.09]]
    open_way = plan_grasp(CAN, 0.03, np.zeros((1, 3)), np.ones(1), 0, _around(here, visited=visited))
    assert open_way.approach[1] > 0.9  # from below when nothing was sensed there
    g = plan_grasp(CAN, 0.03, np.zeros((1, 3)), np.ones(1), 0, _around(here, visited=visited, obstacles=blocker))
    assert g.reachable
    disc = np.asarray(blocker[0]) + [0.0, grasp_plan.PlanningParams().object_radius]  # beyond, seen from below
    rel = disc - g.pregrasp
    along = float(np.dot(rel, g.approach))
    across = abs(float(np.dot(rel, [g.approach[1], -g.approach[0]])))
    short_of_target = approach_offset(CAN) - CAN.half[0] + PlanningParams().object_radius
    assert not (0.0 <= along <= short_of_target and across <= grasp_plan.OPEN)  # not between the open fingers
    # priced out only as a cost: with the lane costs off, the short lane is taken again
    cheap = dataclasses.replace(PlanningParams(), between_cost=0.0, lane_cost=0.0)
    g0 = plan_grasp(CAN, 0.03, np.zeros((1, 3)), np.ones(1), 0, _around(here, visited=visited, obstacles=blocker),
                    cheap)
    assert g0.approach[1] > 0.9


def test_a_way_round_a_sensed_object_is_not_cut_short_through_it():
    # the grid path goes round a costly block (a sensed object, 5 per metre); a shortcut checked for free space only
    # cuts straight through it, the priced one keeps the way's cost (a corner at most grazed, never crossed)
    from pipeline.probe.plane_grid import simplify_path

    def weight(q):
        return np.where((np.abs(q[:, 0] - 0.5) < 0.3) & (np.abs(q[:, 1]) < 0.12), 5.0, 1.0)

    up = np.column_stack([np.zeros(16), np.linspace(0.0, 0.15, 16)])
    across = np.column_stack([np.linspace(0.0, 1.0, 101), np.full(101, 0.15)])
    down = np.column_stack([np.ones(16), np.linspace(0.15, 0.0, 16)])
    path = np.vstack([up, across[1:], down[1:]])

    def cost(points):
        pts = np.vstack([path[:1], points]) if points is not path else points
        line = np.vstack([a + np.linspace(0, 1, 400)[:, None] * (b - a) for a, b in zip(pts[:-1], pts[1:])])
        return float(np.sum(np.hypot(*np.diff(line, axis=0).T) * weight(0.5 * (line[1:] + line[:-1]))))

    free_only = simplify_path(path, lambda q: np.ones(len(q), dtype=bool))
    assert len(free_only) == 1 and cost(free_only) > cost(path) + 1.0  # straight through the block
    priced = simplify_path(path, lambda q: np.ones(len(q), dtype=bool), weight)
    assert cost(priced) <= cost(path) + 0.02 * len(priced) + 1e-9
    assert priced[-1] == pytest.approx(path[-1])
    assert len(priced) <= 4  # still simplified: a few corners, not every cell
