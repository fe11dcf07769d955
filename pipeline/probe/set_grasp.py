"""A grasp for the whole plausible set (docs/active.md): the grasp yaw, centre and advance
that succeed for the largest likelihood-weighted share of the hypotheses, judged by a fast geometric form of the
success rule of :mod:`pipeline.grasp` per hypothesis, then simulated with that rule unchanged.

The geometric rule is :mod:`pipeline.grasp_rule`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.geometry import Primitive, rot2
from pipeline.grasp import GraspParams, GraspResult, grasp_with, grasp_yaw, plan_for
from pipeline.grasp_judge import GRASP_STEP_M
from pipeline.grasp_rule import holds
from pipeline.probe.planning import gripper_outline
from pipeline.probe.transit import Keepout, grasp_via
from pipeline.robot import load_robot

__all__ = ["SetGrasp", "choose_grasp", "simulate_set_grasp", "grasp_keepout",
           "grasp_for_set"]

#: Advances (actions of the action scale) tried besides the plan's own.
ADVANCES = (3, 4, 5)
#: Share of the set another grasp must hold beyond the estimate's own to replace it: 0 (0.25 was tried on the
#: training seeds and grasped one run fewer; docs/experiments/active-set-grasp.md).
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
    yaws = grasp_yaw(plan, prim, poses)
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
    ok = holds(scene, prim, g_yaw, g_centre, g_adv, poses, params)
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
    via = None if keepout is None else grasp_via(final_ee, grasp.pregrasp, keepout, GRASP_STEP_M, params=params)
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
