"""The grasp's success rule in geometry: whether the paper's grasp script, aimed at one pose, holds the target at
another (docs/active.md, "A grasp for the set" and "Choosing the estimate the grasp needs").

The rule follows the script (:mod:`pipeline.grasp`): the hand advances along the approach until its palm (the
finger bases, ``PAD_FROM_BASE[0]`` ahead of the base) would meet the object, the pads span ``PAD_FROM_BASE`` ahead
of the base, and each closing finger touches the object where it reaches farthest across the closing axis within
the pads' span (every outline point within ``CONTACT_BAND`` of that extreme: the pads are compliant). A box grasp
holds when both fingers touch the two long faces (relative yaw within ``face_angle_deg``) with the centre of their
contacts at least ``corner_margin`` from the face's ends; a can grasp when its centre is within the pads' span and
the fingers can close around it. The simulated rule (:func:`pipeline.grasp.judge_box`, :func:`~pipeline.grasp.
judge_can`) is the judge; this form is what a planner can afford per hypothesis: arrays (grasps, hypotheses), the
box's finger rule compiled (numba), summing in numpy's order so that it gives the bits of the array form it
replaced (tests/test_grasp_rule.py keeps that form as the reference). It models the script's fixed advance, not a
plan's guarded extension (:attr:`pipeline.grasp.GraspPlan.guarded_steps`), which only reaches further.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from pipeline.geometry import Primitive, outline_point, primitive_pose, rotate
from pipeline.grasp import OPEN, PAD_FROM_BASE, GraspParams, GraspPlan, grasp_yaw, plan_for
from pipeline.grasp_judge import GRASP_STEP_M
from pipeline.pairwise_sum import pairwise_sum

__all__ = ["CONTACT_BAND", "box_success", "can_success", "holds", "own_grasp_shares", "warm_up"]

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
    ok = np.abs(delta) <= math.radians(params.face_angle_deg)
    _box_faces(np.ascontiguousarray(world), np.ascontiguousarray(base), np.ascontiguousarray(approach),
               np.ascontiguousarray(closing), np.ascontiguousarray(local), float(hx), float(hy),
               float(params.corner_margin), ok)
    return ok


@njit(cache=True)
def _box_faces(world, base, approach, closing, local, hx, hy, corner_margin, ok):
    """The finger rule of :func:`box_success` for every grasp g and hypothesis h with ``ok[g, h]`` (G, H) still
    true, in place. ``world`` (H, K, 2) the outline points, ``base``, ``approach``, ``closing`` (G, 2), ``local``
    (K, 2) the outline points in the box frame. The palm stops at the object (its nearest point shifted to the
    finger bases); each finger touches the band's points within ``CONTACT_BAND`` of its farthest reach; the
    touches' centre must be on a long face and ``corner_margin`` from its ends, the two fingers on opposite faces.
    Sums run in numpy's pairwise order (:func:`pipeline.pairwise_sum.pairwise_sum`): the same bits as the array
    form it replaces."""
    G, H, K = ok.shape[0], ok.shape[1], local.shape[0]
    depth = np.empty(K)
    lateral = np.empty(K)
    band = np.empty(K, dtype=np.bool_)
    ys = np.empty(K)
    xs = np.empty(K)
    lo, hi = PAD_FROM_BASE[0], PAD_FROM_BASE[1]
    for g in range(G):
        ax, ay, cx, cy = approach[g, 0], approach[g, 1], closing[g, 0], closing[g, 1]
        for h in range(H):
            if not ok[g, h]:
                continue
            nearest = np.inf
            for k in range(K):
                rx = world[h, k, 0] - base[g, 0]
                ry = world[h, k, 1] - base[g, 1]
                depth[k] = -0.0 + rx * ax + ry * ay
                lateral[k] = -0.0 + rx * cx + ry * cy
                nearest = min(nearest, depth[k])
            shift = max(lo - nearest, 0.0)
            any_band = False
            reach0 = reach1 = -np.inf  # each finger's farthest reach in the band (in one pass, in k's order)
            for k in range(K):
                d = depth[k] + shift
                band[k] = d >= lo and d <= hi
                any_band = any_band or band[k]
                if band[k]:
                    reach0 = max(reach0, 1.0 * lateral[k])
                    reach1 = max(reach1, -1.0 * lateral[k])
            good = any_band
            face0 = face1 = 0.0
            for f in range(2):
                if not good:
                    break  # (the verdict is false whatever the other finger touches)
                sign = 1.0 if f == 0 else -1.0
                reach = reach0 if f == 0 else reach1
                if not reach <= OPEN:
                    good = False
                    break
                n = 0
                for k in range(K):
                    touch = band[k] and sign * lateral[k] >= reach - CONTACT_BAND
                    n += touch
                    ys[k] = local[k, 1] if touch else 0.0
                    xs[k] = local[k, 0] if touch else 0.0
                n = max(n, 1)
                y_mean = pairwise_sum(ys, 0, K) / n
                x_mean = pairwise_sum(xs, 0, K) / n
                good = good and reach <= OPEN and abs(y_mean) <= hy - corner_margin and abs(x_mean) >= hx - 0.002
                if f == 0:
                    face0 = np.sign(x_mean)
                else:
                    face1 = np.sign(x_mean)
            ok[g, h] = good and face0 != face1


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
        return can_success(prim, poses, yaw, centre, advance, plan, GRASP_STEP_M)
    return box_success(prim, poses, yaw, centre, advance, plan, GRASP_STEP_M, params)


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


def warm_up() -> None:
    """Compile the box rule's kernel (numba caches it on disk), as ``make setup`` does."""
    _box_faces(np.zeros((1, 1, 2)), np.zeros((1, 2)), np.zeros((1, 2)), np.zeros((1, 2)), np.zeros((1, 2)), 0.01,
               0.01, 0.0, np.ones((1, 1), dtype=bool))
