"""The grasp's success rule in geometry: whether the paper's grasp script, aimed at one pose, holds the target at
another (docs/active.md, "A grasp for the set" and "Choosing the estimate the grasp needs").

The rule follows the script (:mod:`pipeline.grasp`): the hand advances along the approach until its palm (the
finger bases, ``PAD_FROM_BASE[0]`` ahead of the base) would meet the object, the pads span ``PAD_FROM_BASE`` ahead
of the base, and each closing finger touches the object where it reaches farthest across the closing axis within
the pads' span (every outline point within ``CONTACT_BAND`` of that extreme: the pads are compliant). A box grasp
holds when both fingers touch the two long faces (relative yaw within ``face_angle_deg``) with the centre of their
contacts at least ``corner_margin`` from the face's ends; a can grasp when its centre is within the pads' span and
the fingers can close around it. The simulated rule (:func:`pipeline.grasp.judge_box`, :func:`~pipeline.grasp.
judge_can`) is the judge; this form is what a planner can afford per hypothesis: arrays (grasps, hypotheses).
"""
from __future__ import annotations

import math

import numpy as np

from pipeline.geometry import Primitive, outline_point, primitive_pose, rotate
from pipeline.grasp import OPEN, PAD_FROM_BASE, GraspParams, GraspPlan, grasp_yaw, plan_for

__all__ = ["CONTACT_BAND", "box_success", "can_success", "holds", "own_grasp_shares"]

#: Outline points within this distance (m) of a finger's farthest reach touch it (compliant pads): calibrated so
#: that a box turned by 0.05 rad holds and one turned by 0.10 rad slips to the corner, as simulated
#: (docs/retrieval.md, "Where grasps are lost").
CONTACT_BAND = 0.0015


def _frames(yaw: np.ndarray, centre: np.ndarray, advance: np.ndarray, plan: GraspPlan, scale: float):
    """Approach (G, 2), closing axis (G, 2) and final base (G, 2) of grasps."""
    r = np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)
    approach = np.stack([-r[:, 1], r[:, 0]], axis=-1)  # rot2(yaw)[:, 1]
    closing = r  # rot2(yaw)[:, 0]: the box's short axis when aligned
    base = centre - (plan.offset - advance * scale)[:, None] * approach
    return approach, closing, base


def box_success(prim: Primitive, poses: np.ndarray, yaw: np.ndarray, centre: np.ndarray, advance: np.ndarray,
                plan: GraspPlan, scale: float, params: GraspParams = GraspParams(), n_outline: int = 160
                ) -> np.ndarray:
    """Whether each grasp (G: yaw (G,), centre (G, 2), advance (G,)) holds each box hypothesis (COM poses (H, 3)),
    by the geometric rule of the module docstring. Returns bool (G, H)."""
    hx, hy = prim.half[:2]
    approach, closing, base = _frames(yaw, centre, advance, plan, scale)
    pp = primitive_pose(prim, np.asarray(poses, dtype=np.float64).reshape(-1, 3))  # (H, 3)
    delta = (pp[None, :, 2] - yaw[:, None] + np.pi / 2) % np.pi - np.pi / 2  # (G, H)
    local = outline_point((np.arange(n_outline) + 0.5) * (4 * (hx + hy) / n_outline), hx, hy)  # (K, 2)
    world = pp[:, None, :2] + rotate(local[None, :, :], pp[:, 2, None])  # (H, K, 2)
    rel = world[None, :, :, :] - base[:, None, None, :]  # (G, H, K, 2)
    depth = np.sum(rel * approach[:, None, None, :], axis=-1)
    lateral = np.sum(rel * closing[:, None, None, :], axis=-1)
    # The palm stops at the object: shift the object's depth so that its nearest point is at the finger bases.
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
        ok &= reach[..., 0] <= OPEN  # the box fits inside the open finger
        ok &= np.abs(y_mean) <= hy - params.corner_margin  # not on a corner
        ok &= np.abs(x_mean) >= hx - 0.002  # on a long face, not an end
        faces.append(np.sign(x_mean))
    return ok & (faces[0] != faces[1])


def can_success(prim: Primitive, poses: np.ndarray, yaw: np.ndarray, centre: np.ndarray, advance: np.ndarray,
                plan: GraspPlan, scale: float) -> np.ndarray:
    """Whether each grasp holds each can hypothesis: its centre ends between the pads (the palm pushes it ahead
    of itself) and the open fingers pass on both sides. Returns bool (G, H)."""
    r = prim.half[0]
    approach, closing, base = _frames(yaw, centre, advance, plan, scale)
    c = prim.centre_world(np.asarray(poses, dtype=np.float64).reshape(-1, 3))  # (H, 2)
    rel = c[None, :, :] - base[:, None, :]
    depth = np.maximum(np.sum(rel * approach[:, None, :], axis=-1), PAD_FROM_BASE[0] + r)
    lateral = np.abs(np.sum(rel * closing[:, None, :], axis=-1))
    return (depth >= PAD_FROM_BASE[0]) & (depth <= PAD_FROM_BASE[1]) & (lateral <= OPEN - r - 0.003)


def holds(scene, prim: Primitive, yaw: np.ndarray, centre: np.ndarray, advance: np.ndarray, poses: np.ndarray,
          params: GraspParams = GraspParams()) -> np.ndarray:
    """Whether each grasp (yaw (G,), centre (G, 2), advance (G,) actions) holds the target at each COM pose (H, 3),
    by the rule of its shape. Returns bool (G, H)."""
    plan = plan_for(scene)
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    if prim.kind == "cylinder":
        return can_success(prim, poses, yaw, centre, advance, plan, scene.action_scale)
    return box_success(prim, poses, yaw, centre, advance, plan, scene.action_scale, params)


def own_grasp_shares(scene, prim: Primitive, poses: np.ndarray, weights: np.ndarray,
                     params: GraspParams = GraspParams()) -> tuple[np.ndarray, np.ndarray]:
    """The paper's grasp script aimed at each hypothesis of a set (COM poses (H, 3), weights (H,) >= 0, not all
    0): its yaw, centred on it, the plan's advance (as :func:`pipeline.grasp.pregrasp`). Returns (share (H,) in
    [0, 1]: the weighted share of the set each one holds, held (H, H) bool: grasp i holds hypothesis j)."""
    plan = plan_for(scene)
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    w = np.asarray(weights, dtype=np.float64)
    w = w / np.sum(w)
    yaw = grasp_yaw(plan, prim, poses)
    centre = prim.centre_world(poses)
    held = holds(scene, prim, yaw, centre, np.full(len(poses), float(params.approach_steps)), poses, params)
    return np.sum(held * w[None, :], axis=1), held
