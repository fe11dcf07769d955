"""Pose estimation from the target's shape, its contact points and the gripper's free space: a plausible set.

The idea follows CHSEL (Zhong et al., RSS 2023), written here for a planar task with numpy only: register the
known shape of the target against the contact points (they lie on its surface, signed distance 0) and against
the space the gripper occupied after the target last moved (the target cannot be there, signed distance >= 0),
from many starts in SE(2), and keep every pose that explains the data about as well as the best one (the
plausible set) instead of a single answer. The grasp goes to the yaw that most of the set agrees on.

Three terms, all in units of a contact point's squared standard deviation (docs/retrieval.md, "The plausible
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

from dataclasses import dataclass
from typing import Callable, ClassVar

import numpy as np

from pipeline.constraints import Constraint, Params, integer, number, one_of
from pipeline.geometry import (Primitive, com_pose, outline_point, primitive_pose, primitive_sdf, rotate, wrap_angle,
                               wrap_symmetric)
from pipeline.portable import argmin_tolerant, exp, tie_key
from pipeline.spd import solve_spd
from pipeline.estimators.plausible.kernel import CONTACT, FREE, piece_terms, piece_terms_each

__all__ = ["PlausibleParams", "Terms", "evaluate_terms", "refine", "initial_poses", "SegmentFit",
           "fit_segment", "consensus"]

#: Costs (squared contact sigmas) closer than this are tied (then the lower index wins): far above the last-bit
#: differences between CPUs, far below any difference between two poses worth choosing between.
COST_TIE = 1e-9


#: Most hypotheses (or iterations) per segment of the plausible estimator.
MAX_HYPOTHESES = 4096


@dataclass(frozen=True)
class PlausibleParams(Params):
    """Parameters of the plausible-set estimator; serialised into the retrieval metadata.

    Attributes
    ----------
    n_hypotheses : int
        SE(2) starts per segment (32): stratified yaw, the points' centroid on a random point of the outline.
    iterations : int
        Levenberg-Marquardt iterations per start (30).
    contact_sigma : float, metres
        Standard deviation of a contact point observed at the segment's last contact (0.003).
    recency_growth : float
        Factor on sigma per later contact of the same segment (2.0; 1.0 = every point alike).
    max_sigma : float, metres
        Cap on a point's sigma (1.0: none).
    outlier_sigmas : float
        Geman-McClure scale in sigmas: a point farther than this from the surface costs at most c^2 / 2 (3.0).
    free_resolution : float, metres
        Lattice spacing of the gripper points of the free-space term (0.005).
    free_tolerance : float, metres
        Penetration of the gripper's free space up to this depth costs nothing (0.003): objects tilt, the
        recorded poses are planar.
    free_weight : float
        Weight of the free-space and other-segment terms (1.0).
    sweep_spacing : float, metres
        Spacing of the gripper poses sampled along each free action (0.01).
    other_tolerance : float, metres
        Depth of another segment's point inside the target that costs nothing (0.005).
    margin : float
        Plausible set: hypotheses whose cost is within this of the best (2.0, in squared sigmas).
    yaw_agreement : float, radians
        Hypotheses agree on a grasp when their yaws differ by less than this (0.05, the grasp's tolerance).
    min_share : float
        Below this share of the plausible set agreeing on the grasp yaw -> ``ambiguous_yaw`` (0.5).
    max_spread : float, metres
        Above this spread (RMS distance from their mean) of the agreeing poses' positions -> ``wide_set`` (0.02).
    pose_rule : {"uniform", "best", "vote"}
        "best" (default): the set's lowest-cost pose. "uniform": the plausible pose whose cost with one sigma for
        every point (``uniform_sigma``) is lowest: recency decides what is plausible, every contact picks within
        it. "vote": the yaw most of the set agrees on (each pose voting with its likelihood relative to the
        best), then that group's lowest-cost pose. Measured on the training seeds in docs/retrieval.md.
    uniform_sigma : float, metres
        The one sigma of the "uniform" rule (0.005).
    icp_seeds : bool
        Also start from the paper's ICP results on the segment (True): ICP's local minima are starts the random
        ones can miss.
    """

    n_hypotheses: int = 32
    iterations: int = 30
    contact_sigma: float = 0.003
    recency_growth: float = 2.0
    max_sigma: float = 1.0
    outlier_sigmas: float = 3.0
    free_resolution: float = 0.005
    free_tolerance: float = 0.003
    free_weight: float = 1.0
    sweep_spacing: float = 0.01
    other_tolerance: float = 0.005
    margin: float = 2.0
    yaw_agreement: float = 0.05
    min_share: float = 0.5
    max_spread: float = 0.02
    pose_rule: str = "best"
    uniform_sigma: float = 0.005
    icp_seeds: bool = True
    constraints: ClassVar[dict[str, Constraint]] = {
        # MAX_HYPOTHESES: (hypotheses, points) residual arrays per start and segment.
        **{name: integer(1, MAX_HYPOTHESES) for name in ("n_hypotheses", "iterations")},
        **{name: number(0, lo_open=True) for name in ("contact_sigma", "max_sigma", "outlier_sigmas",
                                                      "free_resolution", "sweep_spacing", "yaw_agreement",
                                                      "max_spread", "uniform_sigma")},
        **{name: number(0) for name in ("free_tolerance", "free_weight", "other_tolerance", "margin")},
        "recency_growth": number(1), "min_share": number(0, 1), "pose_rule": one_of("best", "vote", "uniform")}


# ---------------------------------------------------------------------------------------------------------------
# Data: per-point sigma, gripper lattice, free space
# ---------------------------------------------------------------------------------------------------------------


# ---------------------------------------------------------------------------------------------------------------
# Cost and its Gauss-Newton terms
# ---------------------------------------------------------------------------------------------------------------


def _to_local(world: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points (P, 2) in each primitive pose's frame (B, P, 2), and their offsets from the centre."""
    d = world[None, :, :] - pose[:, None, :2]
    return rotate(d, pose[:, 2, None], inverse=True), d


@dataclass
class Terms:
    """Costs (B,) of B poses, in squared contact sigmas."""

    contact: np.ndarray
    free: np.ndarray
    others: np.ndarray

    @property
    def total(self) -> np.ndarray:
        return self.contact + self.free + self.others


def evaluate_terms(prim: Primitive, pose: np.ndarray, points: np.ndarray, sigma: np.ndarray, free: np.ndarray,
                   others: np.ndarray, params: PlausibleParams, jacobian: bool = False):
    """Terms of primitive poses (B, 3) = (centre x, centre y, yaw of the primitive axes); with ``jacobian``
    also the Gauss-Newton normal matrix (B, 3, 3) and gradient (B, 3) (IRLS weights for the robust term)."""
    B = len(pose)
    costs, pieces = [], []
    c2 = params.outlier_sigmas ** 2
    s0 = params.contact_sigma
    for pts, kind in ((points, "contact"), (free, "free"), (others, "others")):
        if len(pts) == 0:
            costs.append(np.zeros(B))
            continue
        q, d = _to_local(pts, pose)
        sd, g_local = primitive_sdf(prim, q)
        if kind == "contact":
            u = sd / sigma
            costs.append((0.5 * c2 * u * u / (c2 + u * u)).sum(axis=1))
            weight, resid, scale = (c2 / (c2 + u * u)) ** 2, u, 1.0 / sigma[None, :]
        else:
            tol = params.free_tolerance if kind == "free" else params.other_tolerance
            r = np.minimum(sd + tol, 0.0) / s0
            costs.append(params.free_weight * 0.5 * (r * r).sum(axis=1))
            weight, resid, scale = np.where(r < 0.0, params.free_weight, 0.0), r, np.full((1, 1), 1.0 / s0)
        if jacobian:
            g = rotate(g_local, pose[:, 2, None])
            gx, gy = g[..., 0], g[..., 1]
            # d sd / d centre = -g ; d sd / d yaw = -g . (-dy, dx) for the offset d of the point from the centre
            J = np.stack([-gx, -gy, gx * d[..., 1] - gy * d[..., 0]], axis=-1) * scale[..., None]
            pieces.append((resid, weight, J))
    terms = Terms(*costs)
    if not jacobian:
        return terms
    H = np.zeros((B, 3, 3))
    grad = np.zeros((B, 3))
    for resid, weight, J in pieces:
        wJ = J * weight[..., None]
        # Written out and summed over the points in a fixed order (no einsum/BLAS: docs/evaluation.md).
        H += np.sum(wJ[..., :, None] * J[..., None, :], axis=1)
        grad += np.sum(wJ * resid[..., None], axis=1)
    return terms, H, grad


def compiled_terms(prim: Primitive, pose: np.ndarray, points: np.ndarray, sigma: np.ndarray, free: np.ndarray,
                   others: np.ndarray, params: PlausibleParams, jacobian: bool = False):
    """:func:`evaluate_terms` through the compiled kernel (:mod:`pipeline.estimators.plausible.kernel`): the same
    bits, without the (B, P, 3, 3) temporaries. ``points`` may also be (B, P, 2), each pose with its own contact
    points (the pushtrack estimator's particles): row b then has the bits of pose b with ``points[b]`` alone."""
    pose = np.ascontiguousarray(pose, dtype=np.float64)
    B = len(pose)
    yaw = pose[:, 2, None]  # the view rotate() takes its cosines from in evaluate_terms: the same numpy call
    cos_t, sin_t = np.cos(yaw)[:, 0].copy(), np.sin(yaw)[:, 0].copy()
    c2 = params.outlier_sigmas ** 2
    s0 = params.contact_sigma
    hy = prim.half[1] if len(prim.half) > 1 else 0.0
    costs, H, grad = [], np.zeros((B, 3, 3)), np.zeros((B, 3))
    for pts, kind in ((points, "contact"), (free, "free"), (others, "others")):
        if len(pts) == 0 or np.shape(pts)[-2] == 0:
            costs.append(np.zeros(B))
            continue
        cost, h, g = np.empty(B), np.empty((B, 3, 3)), np.empty((B, 3))
        pts = np.ascontiguousarray(pts, dtype=np.float64)
        if pts.ndim == 3:
            piece_terms_each(prim.kind == "cylinder", prim.half[0], hy, pose, cos_t, sin_t, pts,
                             np.ascontiguousarray(sigma, dtype=np.float64), 0.5 * c2, c2, jacobian, cost, h, g,
                             np.empty(pts.shape[1]))
        else:
            tol = params.free_tolerance if kind == "free" else params.other_tolerance
            piece_terms(prim.kind == "cylinder", prim.half[0], hy, pose, cos_t, sin_t, pts,
                        np.ascontiguousarray(sigma if kind == "contact" else np.zeros(0), dtype=np.float64),
                        CONTACT if kind == "contact" else FREE, 0.5 * c2, c2, tol, s0, 1.0 / s0, params.free_weight,
                        jacobian, cost, h, g, np.empty(len(pts)))
        costs.append(cost if kind == "contact" else params.free_weight * 0.5 * cost)
        if jacobian:
            H += h
            grad += g
    terms = Terms(*costs)
    return (terms, H, grad) if jacobian else terms


def refine(prim: Primitive, init: np.ndarray, points: np.ndarray, sigma: np.ndarray, free: np.ndarray,
           others: np.ndarray, params: PlausibleParams) -> tuple[np.ndarray, Terms]:
    """Batched Levenberg-Marquardt from primitive poses (B, 3); steps capped at 2 cm and 0.2 rad.

    ``points`` (P, 2), or (B, P, 2) with each pose's own (:func:`compiled_terms`). Returns the refined poses (B, 3),
    yaw wrapped to [-pi, pi), and their :class:`Terms`.
    """
    pose = np.array(init, dtype=np.float64)
    lam = np.full(len(pose), 1e-3)
    terms, H, grad = compiled_terms(prim, pose, points, sigma, free, others, params, jacobian=True)
    cost = terms.total
    eye = np.eye(3)
    for _ in range(params.iterations):
        diag = np.maximum(np.diagonal(H, axis1=1, axis2=2), 1e-9)
        A = H + lam[:, None, None] * (eye * diag[:, None, :]) + 1e-12 * eye
        step = -solve_spd(A, grad)
        move = np.linalg.norm(step[:, :2], axis=1)
        shrink = np.minimum(1.0, np.minimum(0.02 / np.maximum(move, 1e-12), 0.2 / np.maximum(np.abs(step[:, 2]),
                                                                                            1e-12)))
        trial = pose + step * shrink[:, None]
        t2, H2, g2 = compiled_terms(prim, trial, points, sigma, free, others, params, jacobian=True)
        better = np.isfinite(t2.total) & (t2.total < cost)
        pose = np.where(better[:, None], trial, pose)
        cost = np.where(better, t2.total, cost)
        H = np.where(better[:, None, None], H2, H)
        grad = np.where(better[:, None], g2, grad)
        lam = np.clip(np.where(better, lam * 0.3, lam * 10.0), 1e-9, 1e9)
    pose[:, 2] = wrap_angle(pose[:, 2])
    return pose, compiled_terms(prim, pose, points, sigma, free, others, params)


def initial_poses(prim: Primitive, points: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """n primitive poses (n, 3): stratified yaw from a random offset, the points' centroid on a random point of
    the outline (a contact is on the surface, so the centroid of a few is near it, not at the centre)."""
    theta = (rng.uniform() + np.arange(n)) * (2.0 * np.pi / n)
    if prim.kind == "cylinder":
        ang = rng.uniform(0.0, 2.0 * np.pi, n)
        u = prim.half[0] * np.column_stack([np.cos(ang), np.sin(ang)])
    else:
        hx, hy = prim.half
        u = outline_point(rng.uniform(0.0, 4.0 * (hx + hy), n), hx, hy)
    return np.column_stack([points.mean(axis=0) - rotate(u, theta), theta])


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
    sd_all, _ = primitive_sdf(prim, _to_local(points, pose)[0])
    u2 = (sd_all / params.uniform_sigma) ** 2
    c2 = params.outlier_sigmas ** 2
    uniform = (0.5 * c2 * u2 / (c2 + u2)).sum(axis=1)
    chosen, agree, share = consensus(pose[:, 2], total, plausible, prim.symmetry, params, uniform)
    centres = pose[agree, :2]
    spread = float(np.sqrt(np.mean(np.sum((centres - centres.mean(axis=0)) ** 2, axis=1))))
    sd, _ = primitive_sdf(prim, _to_local(points, pose)[0])
    rms = np.sqrt(np.mean(sd * sd, axis=1))
    outliers = np.mean(np.abs(sd) > params.outlier_sigmas * sigma[None, :], axis=1)
    if len(free):
        fsd, _ = primitive_sdf(prim, _to_local(free, pose)[0])
        pen = np.maximum(-fsd.min(axis=1), 0.0)
    else:
        pen = np.zeros(len(pose))
    return SegmentFit(poses=com_pose(prim, pose), terms=terms, plausible=plausible, agree=agree, chosen=chosen,
                      share=share, spread=spread, rms=rms, penetration=pen, outlier_fraction=outliers, prior=extra)
