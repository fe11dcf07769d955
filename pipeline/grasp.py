"""Blind object retrieval, the grasp: restore a run's final state in pybullet, grasp at the estimated pose, and
let the simulated contacts decide whether it worked.

The script is the authors' ``grasp_at_pose`` (docs/retrieval.md, "Grasp in simulation"): an approach offset
in the estimated object frame (FB (0, -0.25) m with yaw wrapped to [-pi/2, pi/2]; BC and IB (0, -0.25) with yaw
in [-pi, 0]; TC (0, -0.2) with the yaw forced to -pi/2, approaching along +x), move to the pre-grasp point, turn
the hand to yaw + pi/2 so the fingers point along the approach, open the fingers (0.055 m each, 30 N), advance
4 x 0.03 m, close (30 N) and let it settle one action. The authors judged success by eye (it is not in their code); here
the rule of the paper is evaluated on the contacts pybullet reports after closing (:func:`judge_box`,
:func:`judge_can`), see docs/retrieval.md:

* cracker box: each finger touches the box, all of a finger's contacts have their normal within
  ``face_angle_deg`` of the box's short axis (i.e. on one of the two long faces), the two fingers are on
  opposite long faces, and the centre of each finger's contacts is at least ``corner_margin`` from the ends of
  the face (not on a corner);
* can: both fingers touch it from opposite sides along the closing axis (mean contact normal within
  ``can_angle_deg`` of it), and the can's centre lies between the finger pads along the approach, i.e. the
  fingers reach past the can's middle: closed around more than half of it.

The restored state is the poses recorded after the last action (``obj_pose``: x, y, yaw of every body's
inertial frame; objects upright at rest height, but those the run left knocked over or leaning, restored as they
lay from ``params.tilted``) and the final gripper position,
settled for ``settle_steps``.
"""
from __future__ import annotations

import copy
import dataclasses
import hashlib
import math
import time
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from pipeline.geometry import TILTED_RAD, Primitive, dot2, primitive_of, quat_tilt, quat_yaw, rot2
from pipeline.grasp_judge import GRASP_STEP_M, PAD_FROM_BASE, FingerContacts, GraspParams, judge_box, judge_can

__all__ = ["GraspPlan", "GraspParams", "GraspResult", "plan_for", "grasp_yaw", "pregrasp", "grasp_at", "grasp_with",
           "judge_box", "judge_can", "restore_world", "FingerContacts", "PLANS", "DEEP_BOX", "DEEP_OFFSET",
           "PAD_FROM_BASE", "set_fingers",
           "finger_contacts", "body_pose", "move_to", "close_and_judge"]

OPEN = 0.055  # m per finger (OPEN_ANGLE)
FINGER_FORCE = 30.0  # N (MAX_GRIPPER_FORCE)


@dataclass(frozen=True)
class GraspPlan:
    """How a task approaches its target (docs/retrieval.md, "Grasp in simulation").

    Attributes
    ----------
    offset : float, metres
        Pre-grasp point at (0, -offset) in the object frame; the approach is along the object's +y.
    yaw_range : (float, float) or None
        Yaw wrapped into [low, low + 2 pi) then, for a pi-symmetric target, into this range (FB [-pi/2, pi/2],
        BC/IB [-pi, 0]).
    fixed_yaw : float or None
        Yaw used whatever the estimate says (TC: -pi/2, approach from -x).
    guarded_steps : int
        Actions the approach may go on for after its planned advance while the hand still moves freely: it stops at
        the first that advances less than :data:`GUARD_STALL_SHARE` of its command (the palm met the target's near
        end), so a target lying further along the approach than estimated is still reached (0: the paper's script,
        a fixed advance; docs/retrieval.md, "Grasp in simulation").
    """

    offset: float = 0.25
    yaw_range: tuple[float, float] | None = (-math.pi / 2, math.pi / 2)
    fixed_yaw: float | None = None
    guarded_steps: int = 0


PLANS: dict[str, GraspPlan] = {
    "FB": GraspPlan(0.25, (-math.pi / 2, math.pi / 2)),
    "BC": GraspPlan(0.25, (-math.pi, 0.0)),
    "IB": GraspPlan(0.25, (-math.pi, 0.0)),
    "TC": GraspPlan(0.2, None, -math.pi / 2),
}


#: Pre-grasp offset (m) of a box target in a scene without a paper plan: the one that would centre the pads' span on
#: the estimate after the script's advance if nothing stopped the hand, 4.5 cm deeper than FB's 0.25 m. The hand's
#: palm meets the box's near end before that and stops against it, so the fingers close at a fixed distance from
#: that end; going deeper lets it reach the end when the estimate lies short along the approach (docs/retrieval.md,
#: "Grasp in simulation"). TC's 0.2 m for a can is this offset to 5 mm.
DEEP_OFFSET = GraspParams().approach_steps * GRASP_STEP_M + (PAD_FROM_BASE[0] + PAD_FROM_BASE[1]) / 2.0

#: The plan of a box target in a scene without a paper plan: FB's yaw range, :data:`DEEP_OFFSET`; :func:`plan_for`
#: lets its approach go on along the box's length (:attr:`GraspPlan.guarded_steps`).
DEEP_BOX = GraspPlan(DEEP_OFFSET, (-math.pi / 2, math.pi / 2))

#: A guarded approach action that advances less than this share of its command has met something (the palm stops).
GUARD_STALL_SHARE = 0.5


def plan_for(scene) -> GraspPlan:
    """The scene's plan (the paper's four tasks), or by target shape for other scenes (a box: :data:`DEEP_BOX`,
    a cylinder: TC's)."""
    if scene.name in PLANS:
        return PLANS[scene.name]
    tgt = scene.target
    if tgt is None:
        raise ValueError(f"{scene.path}: scene {scene.name} has no target to grasp")
    if tgt.shape == "cylinder":
        return PLANS["TC"]
    # As far again as the box is long (the whole actions of it): an estimate off along the approach by up to that is
    # still met by the palm.
    length = 2.0 * float(primitive_of(tgt).half[1])  # along the approach (the box's y)
    return dataclasses.replace(DEEP_BOX, guarded_steps=int(length // GRASP_STEP_M))


@dataclass
class GraspResult:
    """Outcome of one simulated grasp.

    Attributes
    ----------
    success : bool
    outcome : str
        "ok" or why not (one short phrase).
    yaw : float, radians
        Yaw of the plan (the estimate's yaw wrapped, or the plan's fixed yaw).
    pregrasp : ndarray, shape (2,)
    reached : bool
        The pre-grasp point was reached within the tolerance.
    target_pose : ndarray, shape (3,)
        The target's COM pose when judged.
    fingers : list of FingerContacts
    wall_s : float
    """

    success: bool
    outcome: str
    yaw: float
    pregrasp: np.ndarray
    reached: bool
    target_pose: np.ndarray
    fingers: list[FingerContacts] = field(default_factory=list)
    wall_s: float = 0.0


def grasp_yaw(plan: GraspPlan, target: Primitive, poses: np.ndarray) -> np.ndarray:
    """The yaw the script takes from each estimated COM pose (H, 3): the plan's fixed yaw, or the primitive's yaw
    (its long side is its y) wrapped into the plan's range. Returns (H,)."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    if plan.fixed_yaw is not None:
        return np.full(len(poses), float(plan.fixed_yaw))
    lo, hi = plan.yaw_range
    sym = target.symmetry if target.symmetry > 0 else 2 * math.pi
    y = (poses[:, 2] + target.yaw - lo) % sym + lo
    return np.where(y > hi, lo, y)  # a range narrower than the symmetry period cannot hold every yaw: its low end


def pregrasp(plan: GraspPlan, target: Primitive, estimate: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(grasp yaw, pre-grasp point (2,), approach direction (2,)) for an estimated COM pose (3,).

    The grasp is centred on the estimated primitive centre (the authors used the COM, 2.6 mm away for the box
    and 11 mm for the TC can, whose COM moves with its arbitrary estimated yaw).
    """
    est = np.asarray(estimate, dtype=np.float64)
    centre = target.centre_world(est)
    yaw = float(grasp_yaw(plan, target, est)[0])
    approach = rot2(yaw)[:, 1]  # object +y
    return yaw, centre - plan.offset * approach, approach


def restore_world(scene, poses: np.ndarray, ee: np.ndarray, settle_steps: int, tilted: dict | None = None):
    """A :class:`pipeline.sim.World` in a run's final state: every object at its recorded (x, y, yaw), upright at
    rest height, but those in ``tilted`` (body index -> [x, y, z, qx, qy, qz, qw], :attr:`pipeline.estimators.
    run_info.RunInfo.final_tilted`: knocked over or leaning) as they lay; the gripper at ``ee``; settled for
    ``settle_steps``. Sensing effects are switched off."""
    p = _pybullet()
    from pipeline.sim import World  # on first use, as pybullet (see _pybullet)

    eff = dataclasses.replace(scene.effects, settle_steps=0, wrench=False, contact_truth=False, noise_mm=0.0)
    world = World(scene, effects=eff)
    try:
        c = world.client
        for i, spec in enumerate(scene.objects):
            x, y, yaw = (float(v) for v in poses[i])
            if not all(math.isfinite(v) for v in (x, y, yaw)):
                raise ValueError(f"object {spec.name!r}: final pose {poses[i]} is not finite")
            body = world.body_of[i]
            # Recorded poses are of the inertial frame, which sits com_offset[2] above the link frame (upright).
            z = spec.spawn_z + spec.com_offset[2]
            full = (tilted or {}).get(i)
            if full is not None:  # restored upright it would stand where its neighbours lie, or inside them
                p.resetBasePositionAndOrientation(body, tuple(map(float, full[:3])), tuple(map(float, full[3:])),
                                                  physicsClientId=c)
            else:
                p.resetBasePositionAndOrientation(body, (x, y, z), p.getQuaternionFromEuler((0.0, 0.0, yaw)),
                                                  physicsClientId=c)
            p.resetBaseVelocity(body, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), physicsClientId=c)
        world.place(float(ee[0]), float(ee[1]), settle=False)
        world.settle(settle_steps)
    except BaseException:
        world.close()
        raise
    return world


def _pybullet():
    """pybullet, imported through :mod:`pipeline.sim` (which swallows its stderr banner)."""
    # On first use, not at the top: only a process that simulates a grasp pays for pybullet's import and banner
    # (ICP's last-bit differences between processes, once blamed on this import, are Open3D's own: see
    # tests/test_dask_processes.py).
    import pybullet

    import pipeline.sim  # noqa: F401

    return pybullet


def set_fingers(world, target: float) -> None:
    p = _pybullet()

    for j in (0, 1):
        p.setJointMotorControl2(world.gripper.body, j, p.POSITION_CONTROL, targetPosition=target, force=FINGER_FORCE,
                                physicsClientId=world.client)


def finger_contacts(world, body: int) -> list[FingerContacts]:
    p = _pybullet()

    out = []
    for j in (0, 1):
        cps = p.getContactPoints(bodyA=world.gripper.body, bodyB=body, linkIndexA=j, physicsClientId=world.client)
        pts = np.array([cp[6][:2] for cp in cps]).reshape(-1, 2)  # positionOnB (the target)
        nrm = np.array([cp[7][:2] for cp in cps]).reshape(-1, 2)  # contactNormalOnB: target -> finger
        out.append(FingerContacts(points=pts, normals=nrm, force=float(sum(cp[9] for cp in cps))))
    return out


def body_pose(world, body: int) -> np.ndarray:
    p = _pybullet()

    pos, q = p.getBasePositionAndOrientation(body, physicsClientId=world.client)
    return np.array([pos[0], pos[1], quat_yaw(q)])


def grasp_at(scene, poses: np.ndarray, ee: np.ndarray, estimate: np.ndarray,
             params: GraspParams = GraspParams(), tilted: dict | None = None) -> GraspResult:
    """Restore a run's final state and attempt the scripted grasp at an estimated target pose.

    Parameters
    ----------
    scene : pipeline.scenes.Scene
    poses : ndarray, shape (B, 3)
        Every body's recorded final (x, y, yaw) (walls' rows are ignored: walls are static).
    ee : ndarray, shape (2,)
        Final gripper position.
    estimate : ndarray, shape (3,)
        Estimated target COM pose.
    params : GraspParams
    tilted : dict or None
        The bodies that ended knocked over or leaning (:func:`restore_world`).

    Returns
    -------
    GraspResult
    """
    plan = plan_for(scene)
    target = primitive_of(next(o for o in scene.objects if o.target))
    yaw, pre, approach = pregrasp(plan, target, estimate)
    return grasp_with(scene, poses, ee, yaw, pre, approach, params, tilted=tilted, guarded_steps=plan.guarded_steps)


#: Grasps already simulated in this process (:func:`grasp_with`), most recent last; at most 64.
_MEMO: OrderedDict[tuple, GraspResult] = OrderedDict()


def _bits(a) -> bytes:
    return np.ascontiguousarray(a, dtype=np.float64).tobytes()


def grasp_with(scene, poses: np.ndarray, ee: np.ndarray, yaw: float, pre: np.ndarray, approach: np.ndarray,
               params: GraspParams = GraspParams(), approach_steps: int | None = None,
               via: np.ndarray | None = None, tilted: dict | None = None, guarded_steps: int = 0) -> GraspResult:
    """The grasp script of :func:`grasp_at` for a given grasp yaw, pre-grasp point (2,) and unit approach
    direction (2,), advancing ``approach_steps`` actions of the action scale (default ``params.approach_steps``);
    the success rule is the same. ``via`` (V, 2), metres: points moved to first, in order, as to the pre-grasp point;
    ``tilted``: the bodies restored as they lay (:func:`restore_world`); ``guarded_steps``: the approach's guarded
    extension (:attr:`GraspPlan.guarded_steps`).

    A grasp is simulated once per process: the same run, pose and parameters again (two estimators that give
    the same pose, the active protocol's set grasp under each estimator) return a copy of the first result, whose
    ``wall_s`` is then the time of the look-up (docs/experiments/reproduce-time.md)."""
    t0 = time.perf_counter()
    steps = params.approach_steps if approach_steps is None else int(approach_steps)
    # All the outcome depends on, to the bit: scene (fields but the path, file text), restored state, grasp, params.
    via = np.zeros((0, 2)) if via is None else np.asarray(via, dtype=np.float64).reshape(-1, 2)
    key = (repr(dataclasses.replace(scene, path=None)), hashlib.sha256(scene.source.encode()).digest(), _bits(poses),
           _bits(ee), _bits([yaw]), _bits(pre), _bits(approach), params, steps) + \
        ((_bits(via),) if len(via) else ()) + tuple((i, _bits(v)) for i, v in sorted((tilted or {}).items())) + \
        ((("guarded", int(guarded_steps)),) if guarded_steps else ())
    if key in _MEMO:
        _MEMO.move_to_end(key)
        return dataclasses.replace(copy.deepcopy(_MEMO[key]), wall_s=time.perf_counter() - t0)
    result = _simulate_grasp(scene, poses, ee, yaw, pre, approach, params, steps, via, tilted, int(guarded_steps))
    result.wall_s = time.perf_counter() - t0
    _MEMO[key] = copy.deepcopy(result)
    while len(_MEMO) > 64:
        _MEMO.popitem(last=False)
    return result


def move_to(world, goal: np.ndarray, params: GraspParams, scale: float, stall_share: float | None = None) -> bool:
    """The script's move to ``goal`` (2,) (``goal - here`` clipped per axis); whether it got within reach. With
    ``stall_share``, a guarded move: it stops when an action moves the gripper less than that share of what it
    commanded (it met something)."""
    for _ in range(params.max_moves):
        here = world.gripper_pose()[0][:2]
        d = goal - here
        if math.hypot(*d) < params.reach_tolerance:
            return True
        step = np.clip(d / scale, -1.0, 1.0) * scale
        world.advance(float(step[0]), float(step[1]))
        if stall_share is not None and _stalled(world, here, step, stall_share):
            return False
    return bool(math.hypot(*(goal - world.gripper_pose()[0][:2])) < params.reach_tolerance)


def _stalled(world, here: np.ndarray, step: np.ndarray, share: float) -> bool:
    """Whether the action ``step`` (2,), m, just made from ``here`` (2,) moved the gripper less than ``share`` of it
    along itself: the hand met something (what a robot's controller feels)."""
    moved = world.gripper_pose()[0][:2] - here
    return bool(dot2(moved, step) < share * dot2(step, step))


def close_and_judge(world, body: int, target: Primitive, yaw: float, approach: np.ndarray, steps: int,
                    scale: float, params: GraspParams, guarded_steps: int = 0
                    ) -> tuple[list[FingerContacts], np.ndarray, bool, str]:
    """The script from the pre-grasp point on: turn the hand to ``yaw`` (fingers along the unit ``approach`` (2,)),
    open, advance ``steps`` actions of ``scale`` (m), and, while the last of them advanced freely, up to
    ``guarded_steps`` more until one stalls (:attr:`GraspPlan.guarded_steps`; the hand's own motion, as a robot
    feels it); close; then the success rule on the target (``body``, of shape ``target``). Returns (each finger's
    contacts, the target's COM pose (3,), success, why)."""
    p = _pybullet()
    # Fingers along the approach: hand z -> world at angle yaw + pi/2 (Euler (0, pi/2, yaw + pi/2)).
    world.gripper.orientation = tuple(p.getQuaternionFromEuler((0.0, math.pi / 2, yaw + math.pi / 2)))
    world.advance(0.0, 0.0)
    set_fingers(world, OPEN)
    world.advance(0.0, 0.0)
    step = np.asarray(approach, dtype=np.float64) * scale
    for k in range(steps + guarded_steps):
        here = world.gripper_pose()[0][:2] if guarded_steps and k >= steps - 1 else None
        world.advance(float(step[0]), float(step[1]))
        if here is not None and _stalled(world, here, step, GUARD_STALL_SHARE):
            break
    set_fingers(world, 0.0)
    world.advance(0.0, 0.0)
    fingers = finger_contacts(world, body)
    pose = body_pose(world, body)
    if target.kind == "cylinder":
        ok, why = judge_can(fingers, target, pose, world.gripper_pose()[0][:2], approach, params)
    else:
        ok, why = judge_box(fingers, target, pose, params)
    tilt = quat_tilt(_pybullet().getBasePositionAndOrientation(body, physicsClientId=world.client)[1])
    if not ok and tilt > TILTED_RAD:  # the report says why a grasp of the pose could not hold it
        why = f"{why}; the target lies tilted {math.degrees(tilt):.0f} deg"
    return fingers, pose, ok, why


def _simulate_grasp(scene, poses, ee, yaw, pre, approach, params: GraspParams, steps: int, via,
                    tilted: dict | None = None, guarded_steps: int = 0) -> GraspResult:
    """The simulation of :func:`grasp_with` (``wall_s`` left at 0)."""
    tid = next(i for i, o in enumerate(scene.objects) if o.target)
    target = primitive_of(scene.objects[tid])
    pre = np.asarray(pre, dtype=np.float64)
    approach = np.asarray(approach, dtype=np.float64)
    scale = GRASP_STEP_M
    world = restore_world(scene, np.asarray(poses, dtype=np.float64), np.asarray(ee, dtype=np.float64),
                          params.settle_steps, tilted)
    with world:
        for point in via:
            move_to(world, point, params, scale)
        reached = move_to(world, pre, params, scale)
        fingers, pose, ok, why = close_and_judge(world, world.body_of[tid], target, yaw, approach, steps, scale,
                                                 params, guarded_steps)
    if not ok and not reached:
        why = f"{why}; pre-grasp point not reached"
    return GraspResult(success=ok, outcome=why, yaw=yaw, pregrasp=pre, reached=reached, target_pose=pose,
                       fingers=fingers)
