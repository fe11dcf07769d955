"""Pose estimation from the target's shape, its contact points and the gripper's free space: a plausible set.

The idea follows CHSEL (Zhong et al., RSS 2023), written here for a planar task with numpy only: register the
known shape of the target against the contact points (they lie on its surface, signed distance 0) and against
the space the gripper occupied after the target last moved (the target cannot be there, signed distance >= 0),
from many starts in SE(2), and keep every pose that explains the data about as well as the best one (the
plausible set) instead of a single answer. The grasp goes to the yaw that most of the set agrees on.

Three terms, all in units of a contact point's squared standard deviation (docs/estimators.md, "The plausible
estimator"):

* **contact**: Geman-McClure robust cost of each point's signed distance to the target surface over its own
  standard deviation. A point observed before later contacts with the same segment has been carried through
  those pushes by the tracker, which moves points but does not turn them with the object, so its position is
  less certain: sigma = contact_sigma * recency_growth ** (later contacts), capped at max_sigma.
* **free space**: squared depth (beyond free_tolerance) of gripper points inside the target, for the gripper
  poses from the segment's last contact on (the end of that action and the sweep of every later action), on a
  lattice of the gripper's slice (the robot's SDF grid, :mod:`pipeline.robot`), built in
  :mod:`pipeline.estimators.plausible.evidence`.
* **others**: the same for the other segments' points, which lie on other objects' surfaces, not inside the
  target.

Poses are refined by a batched Levenberg-Marquardt on (centre x, centre y, yaw) of the primitive, every
hypothesis at once: arrays (hypotheses, points, 2), no loop over points or hypotheses.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from pipeline.estimators.plausible.cost import Terms, evaluate_terms, initial_poses, refine, to_local
from pipeline.estimators.plausible.params import PlausibleParams
from pipeline.geometry import Primitive, com_pose, primitive_pose, primitive_sdf, wrap_symmetric
from pipeline.portable import argmin_tolerant, exp, tie_key

__all__ = ["PlausibleParams", "Terms", "evaluate_terms", "refine", "initial_poses", "SegmentFit",
           "fit_segment", "consensus", "COST_TIE"]

#: Costs (squared contact sigmas) closer than this are tied (then the lower index wins): far above the last-bit
#: differences between CPUs, far below any difference between two poses worth choosing between.
COST_TIE = 1e-9


# ---------------------------------------------------------------------------------------------------------------
# One segment: hypotheses, plausible set, consensus
# ---------------------------------------------------------------------------------------------------------------


@dataclass
class SegmentFit:
    """Hypotheses of one segment and what the plausible set says.

    Attributes
    ----------
    poses : ndarray, shape (B, 3)
        Refined COM poses (x, y, yaw in [-pi, pi)).
    terms : Terms
        Costs of each hypothesis.
    plausible : ndarray, shape (B,), bool
        Within ``margin`` of the best cost.
    agree : ndarray, shape (B,), bool
        Plausible hypotheses agreeing (yaw within ``yaw_agreement``) with the estimate's yaw.
    chosen : int
        Index of the estimate (:func:`consensus`).
    share : float
        Likelihood-weighted share of the plausible set that agrees.
    spread : float, metres
        RMS distance of the agreeing hypotheses' centres from their mean.
    rms : ndarray, shape (B,), metres
        Root mean square signed distance of the points to the surface at each hypothesis.
    penetration : ndarray, shape (B,), metres
        Deepest free-space point inside the target at each hypothesis (0: none).
    outlier_fraction : ndarray, shape (B,)
        Share of the points farther from the surface than ``outlier_sigmas`` of their sigma.
    prior : ndarray, shape (B,)
        A prior cost added to each hypothesis's ``terms.total`` before the plausible set and the estimate were drawn
        (:func:`fit_segment`'s ``prior``; zeros without one).
    """

    poses: np.ndarray
    terms: Terms
    plausible: np.ndarray
    agree: np.ndarray
    chosen: int
    share: float
    spread: float
    rms: np.ndarray
    penetration: np.ndarray
    outlier_fraction: np.ndarray
    prior: np.ndarray | None = None

    @property
    def best_cost(self) -> float:
        return float(self.terms.total[self.chosen])


def consensus(yaw: np.ndarray, cost: np.ndarray, plausible: np.ndarray, symmetry: float, params: PlausibleParams,
              uniform: np.ndarray | None = None) -> tuple[int, np.ndarray, float]:
    """The pose the plausible set supports, by ``params.pose_rule``.

    Each plausible hypothesis has the weight exp(-(cost - best)), its likelihood relative to the best; two
    hypotheses agree when their yaws differ by less than ``yaw_agreement`` modulo the shape's ``symmetry``
    (0: any yaw, a can, where all agree). "best": the lowest-cost hypothesis; "uniform": the one with the lowest
    ``uniform`` cost (B,) (every point with one sigma); "vote": the hypothesis whose yaw gathers the most weight
    (ties to the lower cost, then the lower index). Returns (index of the estimate: for "uniform" that
    hypothesis, otherwise the lowest-cost hypothesis agreeing with its yaw; mask of the hypotheses agreeing;
    their share of the weight of the set).
    """
    idx = np.flatnonzero(plausible)
    w = exp(-(cost[idx] - cost[idx].min()))
    key = tie_key(cost[idx], COST_TIE)
    if symmetry == 0.0:
        near = np.ones((len(idx), len(idx)), dtype=bool)
    else:
        dyaw = wrap_symmetric(yaw[idx][:, None] - yaw[idx][None, :], symmetry)
        near = np.abs(dyaw) < params.yaw_agreement
    if params.pose_rule == "vote":
        votes = np.sum(near * w[None, :], axis=1)
        anchor = int(np.lexsort((np.arange(len(idx)), key, -tie_key(votes, COST_TIE)))[0])
    elif params.pose_rule == "uniform" and uniform is not None:
        anchor = int(np.lexsort((np.arange(len(idx)), key, tie_key(uniform[idx], COST_TIE)))[0])
    else:
        anchor = int(np.lexsort((np.arange(len(idx)), key))[0])
    agree = np.zeros_like(plausible)
    agree[idx[near[anchor]]] = True
    chosen = (idx[anchor] if params.pose_rule == "uniform"
              else int(np.flatnonzero(agree)[argmin_tolerant(cost[agree], COST_TIE)]))
    return int(chosen), agree, float(w[near[anchor]].sum() / w.sum())


def fit_segment(prim: Primitive, points: np.ndarray, sigma: np.ndarray, free: np.ndarray, others: np.ndarray,
                params: PlausibleParams, rng: np.random.Generator, seeds: np.ndarray | None = None,
                prior: Callable[[np.ndarray], np.ndarray] | None = None) -> SegmentFit:
    """Hypotheses, plausible set and consensus for one segment's points (M, 2) with sigmas (M,).

    ``seeds``: further starting COM poses (S, 3), e.g. ICP results, refined with the random starts. ``prior``: COM
    poses (B, 3) -> a prior cost (B,) added to each refined hypothesis's cost before the set and the estimate are
    drawn (the active protocol's prior from the pushes, :mod:`pipeline.probe.history`).
    """
    init = initial_poses(prim, points, params.n_hypotheses, rng)
    if seeds is not None and len(seeds):
        init = np.vstack([init, primitive_pose(prim, np.asarray(seeds, dtype=np.float64).reshape(-1, 3))])
    pose, terms = refine(prim, init, points, sigma, free, others, params)
    extra = np.zeros(len(pose)) if prior is None else np.asarray(prior(com_pose(prim, pose)), dtype=np.float64)
    total = terms.total + extra
    plausible = total <= total.min() + params.margin
    sd_all, _ = primitive_sdf(prim, to_local(points, pose)[0])
    u2 = (sd_all / params.uniform_sigma) ** 2
    c2 = params.outlier_sigmas ** 2
    uniform = (0.5 * c2 * u2 / (c2 + u2)).sum(axis=1)
    chosen, agree, share = consensus(pose[:, 2], total, plausible, prim.symmetry, params, uniform)
    centres = pose[agree, :2]
    spread = float(np.sqrt(np.mean(np.sum((centres - centres.mean(axis=0)) ** 2, axis=1))))
    sd, _ = primitive_sdf(prim, to_local(points, pose)[0])
    rms = np.sqrt(np.mean(sd * sd, axis=1))
    outliers = np.mean(np.abs(sd) > params.outlier_sigmas * sigma[None, :], axis=1)
    if len(free):
        fsd, _ = primitive_sdf(prim, to_local(free, pose)[0])
        pen = np.maximum(-fsd.min(axis=1), 0.0)
    else:
        pen = np.zeros(len(pose))
    return SegmentFit(poses=com_pose(prim, pose), terms=terms, plausible=plausible, agree=agree, chosen=chosen,
                      share=share, spread=spread, rms=rms, penetration=pen, outlier_fraction=outliers, prior=extra)
