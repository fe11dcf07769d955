"""A grasp for the whole plausible set (docs/retrieval.md, "Active retrieval"): the grasp yaw, centre and advance
that succeed for the largest likelihood-weighted share of the hypotheses, judged by a fast geometric form of the
success rule of :mod:`pipeline.grasp` per hypothesis, then simulated with that rule unchanged.

The geometric rule (:func:`box_success`, :func:`can_success`) follows the script: the hand advances along the
approach until its palm (the finger bases, ``PAD_FROM_BASE[0]`` ahead of the base) would meet the object, the
pads span ``PAD_FROM_BASE`` ahead of the base, and each closing finger touches the object where it reaches
farthest across the closing axis within the pads' span (every outline point within ``contact_band`` of that
extreme: the pads are compliant). A box grasp holds when both fingers touch the two long faces (relative yaw
within ``face_angle_deg``) with the centre of their contacts at least ``corner_margin`` from the face's ends; a
can grasp when its centre is within the pads' span and the fingers can close around it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.geometry import Primitive, rot2, rotate
from pipeline.grasp import OPEN, PAD_FROM_BASE, GraspParams, GraspPlan, GraspResult, grasp_with, plan_for
from pipeline.probe.planning import gripper_outline
from pipeline.probe.transit import Keepout, grasp_via
from pipeline.retrieve.model import outline_point
from pipeline.retrieve.plausible import primitive_pose
from pipeline.robot import load_robot

__all__ = ["SetGrasp", "box_success", "can_success", "choose_grasp", "simulate_set_grasp", "grasp_keepout",
           "grasp_for_set"]

#: Outline points within this distance (m) of a finger's farthest reach touch it (compliant pads): calibrated so
#: that a box turned by 0.05 rad holds and one turned by 0.10 rad slips to the corner, as simulated
#: (docs/retrieval.md, "Where grasps are lost").
CONTACT_BAND = 0.0015
#: Advances (actions of the action scale) tried besides the plan's own.
ADVANCES = (3, 4, 5)
#: Share of the set another grasp must hold beyond the estimate's own to replace it: 0 (0.25 was tried on the
#: training seeds and grasped one run fewer; docs/retrieval.md).
MARGIN = 0.0


@dataclass
class SetGrasp:
    """The grasp chosen for a set.

    Attributes
    ----------
    yaw : float, radians
        Grasp yaw (the primitive-axes yaw the script would take from a pose estimate).
    centre : ndarray, shape (2,), metres
        The point the grasp is centred on.
    advance : int
        Approach actions.
    share : float
        Likelihood-weighted share of the set for which the geometric rule holds.
    pregrasp : ndarray, shape (2,)
    approach : ndarray, shape (2,), unit
    """

    yaw: float
    centre: np.ndarray
    advance: int
    share: float
    pregrasp: np.ndarray
    approach: np.ndarray


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


def _grasp_yaw(plan: GraspPlan, prim: Primitive, poses: np.ndarray) -> np.ndarray:
    """The yaw the script takes from each COM pose (H,): the plan's fixed yaw, or the primitive's yaw wrapped into
    the plan's range (as :func:`pipeline.grasp.pregrasp`)."""
    if plan.fixed_yaw is not None:
        return np.full(len(poses), float(plan.fixed_yaw))
    lo, hi = plan.yaw_range
    sym = prim.symmetry if prim.symmetry > 0 else 2 * math.pi
    y = (poses[:, 2] + prim.yaw - lo) % sym + lo
    return np.where(y > hi, lo, y)


def choose_grasp(scene, prim: Primitive, poses: np.ndarray, weights: np.ndarray, best: int,
                 params: GraspParams = GraspParams(), margin: float = MARGIN) -> SetGrasp:
    """The grasp that holds the largest weighted share of the set.

    Candidates: each hypothesis's own grasp (its yaw, its centre) and, for each, the weighted mean centre of the
    hypotheses agreeing with its yaw within 0.05 rad, at each advance of :data:`ADVANCES`. The estimate's own
    grasp at the plan's advance is kept unless another holds a share larger by ``margin`` (default 0: the largest
    share wins, the estimate's grasp first among equals).
    """
    plan = plan_for(scene)
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    w = np.asarray(weights, dtype=np.float64) / np.sum(weights)
    yaws = _grasp_yaw(plan, prim, poses)
    centres = prim.centre_world(poses)
    dy = (yaws[:, None] - yaws[None, :] + np.pi / 2) % np.pi - np.pi / 2
    near = np.abs(dy) < 0.05
    nw = near * w[None, :]
    pooled = np.sum(nw[:, :, None] * centres[None, :, :], axis=1) / np.maximum(np.sum(nw, axis=1), 1e-12)[:, None]
    order = np.r_[best, np.delete(np.arange(len(poses)), best)]
    cy = np.r_[yaws[order], yaws[order]]
    cc = np.vstack([centres[order], pooled[order]])
    adv = np.array([params.approach_steps] + [a for a in ADVANCES if a != params.approach_steps])
    g_yaw = np.tile(cy, len(adv))
    g_centre = np.tile(cc, (len(adv), 1))
    g_adv = np.repeat(adv, len(cy)).astype(np.float64)
    scale = scene.action_scale
    if prim.kind == "cylinder":
        ok = can_success(prim, poses, g_yaw, g_centre, g_adv, plan, scale)
    else:
        ok = box_success(prim, poses, g_yaw, g_centre, g_adv, plan, scale, params)
    share = np.sum(ok * w[None, :], axis=1)
    j = int(np.argmax(share))
    if share[j] < share[0] + margin:
        # With a margin, the estimate's own grasp unless another holds clearly more of the set (a wide set's
        # likelihoods are not calibrated).
        j = 0
    approach = rot2(g_yaw[j])[:, 1]
    return SetGrasp(yaw=float(g_yaw[j]), centre=g_centre[j], advance=int(g_adv[j]), share=float(share[j]),
                    pregrasp=g_centre[j] - plan.offset * approach, approach=approach)


def simulate_set_grasp(scene, final_poses: np.ndarray, final_ee: np.ndarray, grasp: SetGrasp,
                       params: GraspParams = GraspParams(), keepout: Keepout | None = None) -> GraspResult:
    """Simulate the chosen grasp in the run's restored final state (:func:`pipeline.grasp.grasp_with`). With
    ``keepout`` (the target at the set's estimate, :func:`grasp_keepout`), the move to the pre-grasp point goes
    through a waypoint when the straight move would cross it (:func:`pipeline.probe.transit.grasp_via`)."""
    via = None if keepout is None else grasp_via(final_ee, grasp.pregrasp, keepout, scene.action_scale, params=params)
    return grasp_with(scene, final_poses, final_ee, grasp.yaw, grasp.pregrasp, grasp.approach, params,
                      grasp.advance, via)


def grasp_keepout(prim: Primitive, estimate: np.ndarray, sdf, plan) -> Keepout:
    """The region the grasp's move to its pre-grasp point keeps out of: the target at the set's estimate (COM pose
    (3,)) with the return's clearance, ``plan.transit_clearance`` (``plan``: a
    :class:`pipeline.probe.planning.PlanParams`), for the gripper's outline of the robot's SDF ``sdf``."""
    return Keepout(prim, np.asarray(estimate, dtype=np.float64).reshape(3),
                   gripper_outline(sdf, plan.outline_resolution), plan.transit_clearance)


def grasp_for_set(scene, prim: Primitive, poses: np.ndarray, weights: np.ndarray, best: int, final_poses: np.ndarray,
                  final_ee: np.ndarray, plan, params: GraspParams = GraspParams(), simulate: bool = True
                  ) -> tuple[SetGrasp, GraspResult | None]:
    """The grasp chosen for a set (COM poses (K, 3), weights (K,), ``best`` its estimate; :func:`choose_grasp`)
    and, with ``simulate``, its simulation from the gripper at ``final_ee`` (2,) in the state ``final_poses``
    (objects, 3), its move to the pre-grasp point kept out of the target at the estimate
    (:func:`grasp_keepout`; ``plan`` a :class:`pipeline.probe.planning.PlanParams`)."""
    g = choose_grasp(scene, prim, poses, weights, best, params)
    if not simulate:
        return g, None
    keepout = grasp_keepout(prim, poses[best], load_robot("panda"), plan)
    return g, simulate_set_grasp(scene, final_poses, final_ee, g, params, keepout)
