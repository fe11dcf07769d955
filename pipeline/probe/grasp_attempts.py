"""Grasp attempts that re-plan with what they sense (docs/active.md, "The planned grasp").

In the run's restored final state (:func:`pipeline.grasp.restore_world`) the robot plans a grasp
(:func:`pipeline.probe.grasp_plan.plan_grasp`), follows its way in with guarded moves, turns the hand, advances,
closes, and feels the result with what a robot feels: its own position (a move that stops short met something)
and the fingers' opening after closing (nothing between them, or not the width the target's shape gives). A felt
failure re-plans: an object met on the way becomes a sensed obstacle, the hypotheses the failed grasp should
have held lose their weight, and the hand backs out along its lane. When the failed grasp held nearly all of the
set (``PlanningParams.switch_share``), the set was sure and wrong: its segment is not the target's, and the next
attempt is planned on the next-ranked segment's set. Up to ``PlanningParams.attempts`` attempts.

The simulated success rule (:func:`pipeline.grasp.judge_box`, :func:`pipeline.grasp.judge_can`) judges every
attempt for the report; the robot never reads it, nor any object's pose.
"""
from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from pipeline.geometry import Primitive, dot2, primitive_of
from pipeline.grasp import OPEN, GraspParams, close_and_judge, move_to, restore_world, set_fingers
from pipeline.grasp_judge import GRASP_STEP_M
from pipeline.probe.grasp_plan import PlannedGrasp, PlanningParams, Surroundings, held_by, plan_grasp

__all__ = ["Attempt", "Attempts", "attempt_grasps", "felt_width", "NO_REACHABLE_GRASP"]

NO_REACHABLE_GRASP = "no_reachable_grasp"
#: A guarded move stops when an action moves the gripper less than this share of what it commanded.
STALL_SHARE = 0.3
#: A closed hand feels the target held when its opening is within these of the target's width (m), (narrower,
#: wider). A box held on its long faces opened the hand up to 2 mm wider than its short side on the training seeds,
#: and one held on a corner 2-3 mm wider: the opening cannot tell those apart, so a corner is not felt (it can tell
#: an empty hand, another object or the wrong faces; docs/experiments/planned-grasp.md).
WIDTH_TOLERANCE = {"box": (0.003, 0.004), "cylinder": (0.003, 0.004)}
#: Weight kept by the hypotheses a failed grasp should have held.
CONTRADICTED_WEIGHT = 0.02


@dataclass
class Attempt:
    """One attempt.

    Attributes
    ----------
    grasp : PlannedGrasp
    reached : bool
        The pre-grasp point was reached (felt).
    width : float, metres
        The fingers' opening after closing (NaN when the hand did not close).
    felt_ok : bool
        The robot felt the target held.
    success : bool
        The simulated success rule's verdict (for the report only).
    outcome : str
        "ok" or why not.
    """

    grasp: PlannedGrasp
    reached: bool
    width: float
    felt_ok: bool
    success: bool
    outcome: str


@dataclass
class Attempts:
    """Every attempt of one grasp, in order; the last one is the run's outcome."""

    attempts: list[Attempt] = field(default_factory=list)
    wall_s: float = 0.0

    @property
    def first_success(self) -> bool:
        """The first attempt held the target and the robot kept it (a hand that felt a miss lets go)."""
        return bool(self.attempts and self.attempts[0].success and self.attempts[0].felt_ok)

    @property
    def success(self) -> bool:
        """Held at the end: the attempt the robot stopped at succeeded, and the robot kept it."""
        return bool(self.attempts and self.attempts[-1].success and self.attempts[-1].felt_ok)

    @property
    def outcome(self) -> str:
        return "; ".join(f"{i + 1}: {a.outcome}" for i, a in enumerate(self.attempts)) or NO_REACHABLE_GRASP


def felt_width(prim: Primitive) -> float:
    """The hand's opening (m) that a grasp across the target gives: a box's short side, a can's diameter."""
    return 2.0 * float(prim.half[0])


def _finger_opening(world) -> float:
    import pybullet as p

    return float(sum(p.getJointState(world.gripper.body, j, physicsClientId=world.client)[0] for j in (0, 1)))


def _extent(outline: np.ndarray, direction: np.ndarray) -> float:
    """How far (m) the gripper's outline reaches from its centre along a unit ``direction``."""
    return float(np.max(dot2(outline, direction)))


def attempt_grasps(scene, final_poses: np.ndarray, final_ee: np.ndarray, prim: Primitive, poses: np.ndarray,
                   weights: np.ndarray, best: int, surroundings: Surroundings,
                   planning: PlanningParams = PlanningParams(), params: GraspParams = GraspParams(),
                   next_set: Callable[[int], tuple | None] | None = None, tilted: dict | None = None) -> Attempts:
    """Plan, attempt, feel and re-plan, up to ``planning.attempts`` times, in the run's final state (objects'
    (x, y, yaw) ``final_poses`` (B, 3), gripper at ``final_ee`` (2,)), for the plausible set (COM poses (H, 3),
    weights (H,), ``best``). ``next_set(k)`` gives the set and surroundings of the ``k``-th segment ranked after
    the set's, or None (:class:`pipeline.probe.retrieval.ActiveState`); ``tilted`` the bodies that ended knocked
    over or leaning (:func:`pipeline.grasp.restore_world`). The scene gives the simulation and the judge only."""
    t0 = time.perf_counter()
    out = Attempts()
    scale = GRASP_STEP_M
    tid = next(i for i, o in enumerate(scene.objects) if o.target)
    truth_shape = primitive_of(scene.objects[tid])
    w = np.asarray(weights, dtype=np.float64).copy()
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    s = surroundings
    felt: list[np.ndarray] = []  # obstacles the attempts met, kept when the set changes
    switched = 0
    world = restore_world(scene, np.asarray(final_poses, dtype=np.float64), np.asarray(final_ee, dtype=np.float64),
                          params.settle_steps, tilted)
    with world:

        body = world.body_of[tid]
        transit = world.gripper.orientation
        for _ in range(planning.attempts):
            s = s.moved(world.gripper_pose()[0][:2])
            g = plan_grasp(prim, scale, poses, w, best, s, planning, params)
            if not g.reachable:
                out.attempts.append(Attempt(g, False, math.nan, False, False, NO_REACHABLE_GRASP))
                break
            trail, reached = [s.here], True
            for point in g.via:
                reached = move_to(world, point, params, scale, STALL_SHARE)
                trail.append(world.gripper_pose()[0][:2].copy())
                if not reached:
                    break
            if not reached:
                # Something lies just beyond the gripper in the direction it was going.
                at = trail[-1]
                heading = point - at
                heading = heading / max(math.hypot(*heading), 1e-9)
                felt.append(at + (_extent(s.outline, heading) + 0.005) * heading)
                s = s.moved(at, trail).with_obstacle(felt[-1])
                out.attempts.append(Attempt(g, False, math.nan, False, False, "pre-grasp point not reached"))
                continue
            # the judge reads the truth for the report; the robot feels only the fingers' opening
            _, _, ok, why = close_and_judge(world, body, truth_shape, g.yaw, g.approach, g.advance, scale, params)
            width = _finger_opening(world)
            narrower, wider = WIDTH_TOLERANCE[prim.kind]
            felt_ok = -narrower <= width - felt_width(prim) <= wider
            out.attempts.append(Attempt(g, True, width, felt_ok, ok, why))
            if felt_ok or len(out.attempts) == planning.attempts:
                break
            # Felt a miss: what this grasp should have held is not where the set put it; back out along the lane.
            held = held_by(prim, scale, np.array([g.yaw]), g.centre[None, :], np.array([float(g.advance)]),
                           g.offset, poses, params)[0]
            other = next_set(switched + 1) if next_set is not None and \
                float(np.sum(w[held])) >= planning.switch_share * float(np.sum(w)) else None
            if other is not None:
                # the set was sure and found no target: its segment is another object's; take the next one's set
                switched += 1
                belief, around = other
                poses, w, best = belief.poses, np.asarray(belief.weights, dtype=np.float64).copy(), belief.best
                s = dataclasses.replace(around, here=s.here, visited=s.visited, tried=s.tried,
                                        obstacles=np.vstack([around.obstacles, *felt]))
            elif np.any(~held & (w > 0)):
                w = np.where(held, w * CONTRADICTED_WEIGHT, w)
                best = int(np.argmax(w))
            set_fingers(world, OPEN)
            world.advance(0.0, 0.0)
            for _ in range(g.advance):
                world.advance(float(-g.approach[0] * scale), float(-g.approach[1] * scale))
            world.gripper.orientation = transit
            world.advance(0.0, 0.0)
            s = s.moved(world.gripper_pose()[0][:2], trail).with_miss(g.yaw, g.centre)
    out.wall_s = time.perf_counter() - t0
    return out
