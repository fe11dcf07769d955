"""The grasp's success rule on the contacts pybullet reports after closing, and the grasp's parameters
(docs/retrieval.md, "Grasp in simulation"): the cracker box held on its two long faces away from the corners, the
can closed around more than half of it. The simulated grasp (:mod:`pipeline.grasp`) is judged by these; the
geometric form a planner can afford per hypothesis is :mod:`pipeline.grasp_rule`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.constraints import Params
from pipeline.geometry import Primitive, dot2, rot2

__all__ = ["GRASP_STEP_M", "PAD_FROM_BASE", "GraspParams", "FingerContacts", "judge_box", "judge_can", "finger_problem"]

#: Finger pads along the hand's approach axis (hand z), from the base: joint at 0.0584, mesh z in [0, 0.0538]
#: (docs/simulation.md, "World, gripper, stepping"), i.e. world x in [0.0585, 0.1122] for the default orientation.
PAD_FROM_BASE = (0.0585, 0.1122)


#: The grasp script's step, metres: the authors' 3 cm action (MAX_PUSH_DIST), whatever step a scene's rummage takes
#: (the paper's real robot rummaged in 2 cm steps; its grasp is the same grasp).
GRASP_STEP_M = 0.03


@dataclass(frozen=True)
class GraspParams(Params):
    """Grasp script and success rule parameters.

    Attributes
    ----------
    settle_steps : int
        Sim steps at rest after restoring the final state (240 = 1 s).
    max_moves : int
        Actions allowed to reach the pre-grasp point (the authors: 5 s of wall time).
    reach_tolerance : float, metres
        The pre-grasp point is reached within this distance (0.01).
    approach_steps : int
        Actions of 0.03 m along the approach (4).
    face_angle_deg : float
        A box contact is on a long face if its normal is within this angle of the box's short axis.
    corner_margin : float, metres
        A finger's contacts must be centred at least this far from the ends of the long face.
    can_angle_deg : float
        A can contact's mean normal must be within this angle of the closing axis.
    min_normal_force : float, N
        Each finger must press with at least this total normal force.
    """

    settle_steps: int = 240
    max_moves: int = 30
    reach_tolerance: float = 0.01
    approach_steps: int = 4
    face_angle_deg: float = 25.0
    corner_margin: float = 0.01
    can_angle_deg: float = 30.0
    min_normal_force: float = 1.0


@dataclass
class FingerContacts:
    """Contacts of one finger with the target after closing.

    Attributes
    ----------
    points : ndarray, shape (C, 2), metres
        Contact positions on the target (world x, y).
    normals : ndarray, shape (C, 2)
        Contact normals from the target toward the finger (world x, y, unnormalised horizontal part).
    force : float, N
        Total normal force.
    """

    points: np.ndarray
    normals: np.ndarray
    force: float


def judge_box(fingers: list[FingerContacts], target: Primitive, pose: np.ndarray, params: GraspParams
              ) -> tuple[bool, str]:
    """The box rule: both fingers on the two opposite long faces, and not on a corner.

    Parameters
    ----------
    fingers : list of 2 FingerContacts
    target : Primitive
        The box (long side along its y).
    pose : ndarray, shape (3,)
        The box's COM pose when judged.
    """
    pose = np.asarray(pose, dtype=np.float64)
    ang = float(pose[2]) + target.yaw
    r = rot2(ang)
    ax = r[:, 0]  # short axis: normal of the long faces
    ay = r[:, 1]  # long axis
    centre = target.centre_world(pose)
    cos_max = math.cos(math.radians(params.face_angle_deg))
    sides = []
    for k, f in enumerate(fingers):
        problem = finger_problem(k, f, params)
        if problem:
            return False, problem
        n = f.normals / np.maximum(np.linalg.norm(f.normals, axis=1, keepdims=True), 1e-12)
        along = dot2(n, ax)
        if not (np.all(np.abs(along) >= cos_max) and (np.all(along > 0) or np.all(along < 0))):
            return False, f"finger {k} is not on a long face (contact normals at " \
                          f"{np.degrees(np.arccos(np.clip(np.abs(along).min(), 0, 1))):.0f} deg from its normal)"
        y = float(np.mean(dot2(f.points - centre, ay)))
        if abs(y) > target.half[1] - params.corner_margin:
            return False, f"finger {k} is on a corner ({abs(y) * 100:.1f} cm from the centre of a " \
                          f"{target.half[1] * 200:.1f} cm face)"
        sides.append(np.sign(along[0]))
    if sides[0] == sides[1]:
        return False, "both fingers on the same long face"
    return True, "ok"


def finger_problem(k: int, f: FingerContacts, params: GraspParams) -> str | None:
    """Why finger k cannot hold anything (no contact with the target, or too weak a push), or None."""
    if len(f.points) == 0:
        return f"finger {k} does not touch the target"
    if f.force < params.min_normal_force:
        return f"finger {k} presses with {f.force:.2f} N < {params.min_normal_force} N"
    return None


def judge_can(fingers: list[FingerContacts], target: Primitive, pose: np.ndarray, base: np.ndarray,
              approach: np.ndarray, params: GraspParams) -> tuple[bool, str]:
    """The can rule: fingers closed around more than half of it.

    Both fingers touch it from opposite sides along the closing axis (mean normal within ``can_angle_deg``),
    and the can's centre lies between the finger pads along the approach (the pads reach past its middle).

    Parameters
    ----------
    base : ndarray, shape (2,)
        Gripper base position when judged.
    approach : ndarray, shape (2,)
        Unit direction the fingers point (world).
    """
    centre = target.centre_world(np.asarray(pose, dtype=np.float64))
    a = np.asarray(approach, dtype=np.float64) / math.hypot(*approach)
    b = np.array([-a[1], a[0]])
    cos_max = math.cos(math.radians(params.can_angle_deg))
    sides = []
    for k, f in enumerate(fingers):
        problem = finger_problem(k, f, params)
        if problem:
            return False, problem
        m = f.normals.mean(axis=0)
        m = m / max(math.hypot(*m), 1e-12)
        if abs(dot2(m, b)) < cos_max:
            return False, f"finger {k} touches the can {np.degrees(np.arccos(min(abs(dot2(m, b)), 1))):.0f} deg " \
                          f"off the closing axis (less than half enclosed)"
        sides.append(np.sign(dot2(m, b)))
    if sides[0] == sides[1]:
        return False, "both fingers on the same side of the can"
    depth = float(dot2(centre - np.asarray(base, dtype=np.float64), a))
    if not (PAD_FROM_BASE[0] <= depth <= PAD_FROM_BASE[1]):
        return False, f"can centre {depth * 100:.1f} cm ahead of the base, outside the finger pads " \
                      f"[{PAD_FROM_BASE[0] * 100:.1f}, {PAD_FROM_BASE[1] * 100:.1f}] cm"
    return True, "ok"
