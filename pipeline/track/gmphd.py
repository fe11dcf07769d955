"""Gaussian-mixture PHD filter baseline (Vo & Ma 2006) for static planar contact points.

Written from the equations of B.-N. Vo and W.-K. Ma, "The Gaussian mixture probability hypothesis density
filter", IEEE Trans. Signal Processing 54(11), 2006 (Table 1: prediction and update; Table 2: pruning), with the
model and the target extraction of the authors' baseline (paper §V-A):

* state = a 2-D point, F = I (static targets), Q = q·I, H = I, R = r·I, survival p_S, no spawning;
* birth intensity = a ``birth_grid`` × ``birth_grid`` grid of N(grid point, birth_variance·I) over ``bounds``,
  total weight ``birth``;
* clutter intensity κ = ``clutter`` / area of ``bounds``;
* pruning after every update (truncate, merge, cap), keeping the pre-prune total weight;
* targets by the integral of the weights: n = round(bias · Σ w), repeatedly take the heaviest component and
  subtract 1 from its weight.

The mixture is held as arrays (log-weights (J,), means (J, D), covariances (J, D, D)); the numeric kernels are pure
functions of those arrays and :class:`GMPHDFilter` is a thin holder. Weights are logs throughout; Gaussian
likelihoods come from Cholesky factors (log-determinant from the diagonal), never from explicit inverses.

As tracking baseline the filter sits inside the hard-tracking wrapper of :mod:`pipeline.track.cluster`:
:class:`GMPHDLabeller` feeds each step's new contact points (at their pre-motion locations) as the measurement
set and labels every stored point by its nearest extracted target. As in the authors' wrapper, the mixture itself
is never translated by the pushes: targets are static (F = I) and only the stored points move.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import logsumexp

from pipeline.track.spd import cho_solve_matrix, cholesky, solve_lower, symmetrise

__all__ = [
    "GMPHDParams",
    "GMPHDFilter",
    "GMPHDLabeller",
    "birth_components",
    "predict",
    "update",
    "prune",
    "extract_targets",
    "nearest_labels",
]

_LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass(frozen=True)
class GMPHDParams:
    """GM-PHD model and pruning parameters (defaults: the authors', tuned for BOR in simulation).

    Attributes
    ----------
    birth : float
        Total weight of the birth intensity (expected number of new targets per update).
    detection : float
        Detection probability p_D, in (0, 1].
    q, r : float
        Process and measurement noise variances, m² (Q = q·I, R = r·I).
    bias : float
        Target-count bias of the extraction: n = round(bias · Σ w).
    survival : float
        Survival probability p_S, in (0, 1].
    bounds : tuple of 4 floats
        (x_min, y_min, x_max, y_max) of the workspace, metres: birth grid and clutter density.
    birth_grid : int
        Birth components per axis (birth_grid² in all).
    birth_variance : float
        Variance of each birth component, m².
    clutter : float
        Expected number of clutter measurements over ``bounds``; clutter intensity = clutter / area.
    truncation : float
        Components with weight <= truncation are dropped when pruning.
    merge_threshold : float
        Squared Mahalanobis distance (in the candidate's covariance) under which components are merged.
    max_components : int
        At most this many components are kept after pruning.

    The training-set tuning of the authors is :meth:`training_set` (q = r = 0.1, bias 1).
    """

    birth: float = 0.001
    detection: float = 0.3
    q: float = 5e-5
    r: float = 5e-5
    bias: float = 4.0
    survival: float = 0.95
    bounds: tuple[float, float, float, float] = (-1.0, -1.0, 1.0, 1.0)
    birth_grid: int = 20
    birth_variance: float = 1e-3
    clutter: float = 3.0
    truncation: float = 1e-6
    merge_threshold: float = 0.005
    max_components: int = 10

    def __post_init__(self) -> None:
        object.__setattr__(self, "bounds", tuple(float(b) for b in self.bounds))
        checks = [
            ("birth", self.birth > 0),
            ("detection", 0 < self.detection <= 1),
            ("q", self.q >= 0),
            ("r", self.r > 0),
            ("bias", self.bias > 0),
            ("survival", 0 < self.survival <= 1),
            ("bounds", len(self.bounds) == 4 and self.bounds[0] < self.bounds[2] and self.bounds[1] < self.bounds[3]),
            ("birth_grid", int(self.birth_grid) == self.birth_grid and self.birth_grid >= 1),
            ("birth_variance", self.birth_variance > 0),
            ("clutter", self.clutter >= 0),
            ("truncation", self.truncation >= 0),
            ("merge_threshold", self.merge_threshold >= 0),
            ("max_components", int(self.max_components) == self.max_components and self.max_components >= 1),
        ]
        for name, ok in checks:
            if not ok:
                raise ValueError(f"GMPHDParams.{name} out of range: {getattr(self, name)!r}")

    @classmethod
    def training_set(cls) -> "GMPHDParams":
        """The authors' tuning on the training set (birth 0.001, detection 0.3, q = r = 0.1, bias 1)."""
        return cls(q=0.1, r=0.1, bias=1.0)

    @property
    def clutter_intensity(self) -> float:
        """κ, clutter measurements per m²."""
        x0, y0, x1, y1 = self.bounds
        return self.clutter / ((x1 - x0) * (y1 - y0))


# ---------------------------------------------------------------------------------------------------------------
# kernels (Vo & Ma 2006, Tables 1 and 2)
# ---------------------------------------------------------------------------------------------------------------
def birth_components(params: GMPHDParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Birth intensity: a grid over ``params.bounds``.

    Returns
    -------
    log_w : ndarray, shape (B,)   each log(birth / B), B = birth_grid²
    means : ndarray, shape (B, 2), metres
    covs : ndarray, shape (B, 2, 2), m²
    """
    x0, y0, x1, y1 = params.bounds
    n = int(params.birth_grid)
    gx, gy = np.meshgrid(np.linspace(x0, x1, n), np.linspace(y0, y1, n), indexing="xy")
    means = np.column_stack([gx.ravel(), gy.ravel()])
    b = len(means)
    log_w = np.full(b, np.log(params.birth / b))
    covs = np.broadcast_to(params.birth_variance * np.eye(2), (b, 2, 2)).copy()
    return log_w, means, covs


def predict(log_w: np.ndarray, means: np.ndarray, covs: np.ndarray, survival: float,
            q: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Prediction of surviving components with F = I, Q = q·I (Vo-Ma Table 1, step 2; no spawning).

    log_w (J,), means (J, D), covs (J, D, D) -> same shapes.
    """
    d = means.shape[1]
    return log_w + np.log(survival), means.copy(), covs + q * np.eye(d)


def update(log_w: np.ndarray, means: np.ndarray, covs: np.ndarray, z: np.ndarray, detection: float, r: float,
           clutter_intensity: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PHD update with H = I, R = r·I (Vo-Ma Table 1, steps 3-4).

    Parameters
    ----------
    log_w : ndarray, shape (J,)
    means : ndarray, shape (J, D), metres
    covs : ndarray, shape (J, D, D), m²
    z : ndarray, shape (K, D), metres
        Measurement set.
    detection : float
        p_D.
    r : float
        Measurement noise variance, m².
    clutter_intensity : float
        κ(z), uniform, per m².

    Returns
    -------
    log_w : (J (K + 1),), means : (J (K + 1), D), covs : (J (K + 1), D, D)
        The J missed-detection components (weights · (1 - p_D)) followed, per measurement in order, by the J
        Kalman-updated components with weights p_D w N(z; m, S) / (κ + Σ_l p_D w_l N(z; m_l, S_l)).
    """
    j, d = means.shape
    z = np.asarray(z, dtype=float).reshape(-1, d)
    k = len(z)
    eye = np.eye(d)
    missed_lw = log_w + (np.log1p(-detection) if detection < 1 else -np.inf)
    if j == 0 or k == 0:
        keep = np.isfinite(missed_lw)
        return missed_lw[keep], means[keep], covs[keep]

    s = symmetrise(covs + r * eye)
    chol_s = cholesky(s)
    # Gain K = P S^-1 = (S^-1 P)^T, both symmetric.
    gain = np.swapaxes(cho_solve_matrix(chol_s, covs), -1, -2)  # (J, D, D)
    ikh = eye - gain
    # Joseph form keeps the updated covariance symmetric positive definite under round-off.
    cov_upd = symmetrise(ikh @ covs @ np.swapaxes(ikh, -1, -2) + r * gain @ np.swapaxes(gain, -1, -2))

    innov = z[None, :, :] - means[:, None, :]  # (J, K, D)
    white = solve_lower(chol_s[:, None], innov)  # (J, K, D)
    log_det = 2.0 * np.log(np.diagonal(chol_s, axis1=-2, axis2=-1)).sum(-1)  # (J,)
    log_lik = -0.5 * (d * _LOG_2PI + log_det[:, None] + (white ** 2).sum(-1))  # (J, K)
    det_lw = np.log(detection) + log_w[:, None] + log_lik  # (J, K)
    log_kappa = np.log(clutter_intensity) if clutter_intensity > 0 else -np.inf
    log_norm = logsumexp(np.vstack([np.full((1, k), log_kappa), det_lw]), axis=0)  # (K,)
    # κ > 0 keeps the normaliser finite; with κ = 0 and no finite term a measurement simply adds nothing.
    safe_norm = np.where(np.isfinite(log_norm), log_norm, 0.0)
    det_lw = np.where(np.isfinite(log_norm)[None, :], det_lw - safe_norm[None, :], -np.inf)

    det_means = means[:, None, :] + np.einsum("jab,jkb->jka", gain, innov)  # (J, K, D)
    out_lw = np.concatenate([missed_lw, det_lw.T.ravel()])
    out_means = np.concatenate([means, det_means.transpose(1, 0, 2).reshape(-1, d)])
    out_covs = np.concatenate([covs, np.broadcast_to(cov_upd, (k, j, d, d)).reshape(-1, d, d)])
    keep = np.isfinite(out_lw)
    return out_lw[keep], out_means[keep], out_covs[keep]


def _group_logsumexp(values: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """logsumexp over contiguous groups beginning at ``starts`` of a 1-D array."""
    peak = np.maximum.reduceat(values, starts)
    counts = np.diff(np.append(starts, len(values)))
    return peak + np.log(np.add.reduceat(np.exp(values - np.repeat(peak, counts)), starts))


def prune(log_w: np.ndarray, means: np.ndarray, covs: np.ndarray, truncation: float, merge_threshold: float,
          max_components: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vo-Ma Table 2: truncate, merge, cap; the result keeps the total weight of the input.

    Parameters
    ----------
    log_w : ndarray, shape (J,)
    means : ndarray, shape (J, D)
    covs : ndarray, shape (J, D, D)
    truncation : float
        Components with weight <= truncation are dropped (the heaviest one is always kept).
    merge_threshold : float
        U: starting from the heaviest remaining component j, every remaining i with
        (m_i - m_j)^T P_i^-1 (m_i - m_j) <= U is merged into one moment-matched component.
    max_components : int
        Cap on the number of components (heaviest kept).

    Returns
    -------
    log_w (J',), means (J', D), covs (J', D, D), J' <= min(J, max_components).
    """
    n, d = means.shape
    if n == 0:
        return log_w.copy(), means.copy(), covs.copy()
    total = logsumexp(log_w)
    if not np.isfinite(total):  # every weight zero: nothing to keep
        return np.empty(0), np.empty((0, d)), np.empty((0, d, d))

    keep = log_w > (np.log(truncation) if truncation > 0 else -np.inf)
    if not keep.any():
        keep[np.argmax(log_w)] = True
    lw, m, p = log_w[keep], means[keep], symmetrise(covs[keep])
    j = len(lw)
    chol = cholesky(p)

    # Candidate pairs through a Euclidean gate: d_M(i, j) >= |m_i - m_j|^2 / lambda_max(P_i), so no pair farther
    # than sqrt(U max lambda_max) can merge. Exact Mahalanobis distances are then computed on the pairs only.
    lam_max = np.linalg.eigvalsh(p)[:, -1]
    radius = float(np.sqrt(merge_threshold * lam_max.max()))
    pairs = cKDTree(m).query_pairs(radius, output_type="ndarray")
    cand = np.concatenate([pairs[:, 0], pairs[:, 1]]).astype(np.intp)
    seed = np.concatenate([pairs[:, 1], pairs[:, 0]]).astype(np.intp)
    white = solve_lower(chol[cand], m[cand] - m[seed])
    close = (white ** 2).sum(-1) <= merge_threshold
    cand, seed = cand[close], seed[close]

    # Greedy merging in decreasing weight, only over components with at least one close neighbour; the others
    # are untouched singletons whatever the order.
    group = np.arange(j)
    if len(cand):
        by_seed = np.lexsort((cand, seed))
        cand_s, seed_s = cand[by_seed], seed[by_seed]
        ptr = np.searchsorted(seed_s, np.arange(j + 1))
        linked = np.zeros(j, bool)
        linked[cand] = True
        linked[seed] = True
        linked_idx = np.flatnonzero(linked)
        order = linked_idx[np.argsort(-lw[linked_idx], kind="stable")]
        assigned = np.zeros(j, bool)
        for s_idx in order:
            if assigned[s_idx]:
                continue
            members = cand_s[ptr[s_idx]:ptr[s_idx + 1]]
            members = members[~assigned[members]]
            group[members] = s_idx
            assigned[members] = True
            assigned[s_idx] = True

    # Moment matching per group (groups made contiguous by sorting).
    srt = np.argsort(group, kind="stable")
    g_sorted = group[srt]
    starts = np.flatnonzero(np.r_[True, g_sorted[1:] != g_sorted[:-1]])
    lw_s, m_s, p_s = lw[srt], m[srt], p[srt]
    g_lw = _group_logsumexp(lw_s, starts)
    counts = np.diff(np.append(starts, j))
    frac = np.exp(lw_s - np.repeat(g_lw, counts))  # normalised within group
    g_m = np.add.reduceat(frac[:, None] * m_s, starts, axis=0)
    dev = np.repeat(g_m, counts, axis=0) - m_s
    spread = p_s + dev[:, :, None] * dev[:, None, :]
    g_p = symmetrise(np.add.reduceat(frac[:, None, None] * spread, starts, axis=0))

    if len(g_lw) > max_components:
        top = np.argsort(-g_lw, kind="stable")[:max_components]
        g_lw, g_m, g_p = g_lw[top], g_m[top], g_p[top]
    g_lw = g_lw + (total - logsumexp(g_lw))
    return g_lw, g_m, g_p


def extract_targets(log_w: np.ndarray, bias: float, max_doublings: int = 64) -> np.ndarray:
    """Target extraction by the integral of the weights (as in the authors' baseline).

    n = round(bias · Σ w) (round half to even, as Python's ``round``); while n == 0 the bias is doubled (at most
    ``max_doublings`` times, then n = 1). Then n times: take the heaviest component, subtract 1 from its weight.

    Parameters
    ----------
    log_w : ndarray, shape (J,)

    Returns
    -------
    ndarray, shape (T,), int
        Indices of the extracted components, distinct, in the order first taken; T >= 1 whenever J >= 1.
    """
    if len(log_w) == 0:
        return np.empty(0, dtype=np.intp)
    w = np.exp(log_w)
    total = float(w.sum())
    n = int(np.rint(bias * total))
    b = bias
    for _ in range(max_doublings):
        if n >= 1:
            break
        b *= 2.0
        n = int(np.rint(b * total))
    n = max(n, 1)
    picks = np.empty(n, dtype=np.intp)
    for t in range(n):
        picks[t] = np.argmax(w)
        w[picks[t]] -= 1.0
    _, first = np.unique(picks, return_index=True)
    return picks[np.sort(first)]


def nearest_labels(points: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Label of each point = index of its nearest target. points (M, D), targets (T, D), T >= 1 -> (M,) int64."""
    if len(points) == 0:
        return np.empty(0, dtype=np.int64)
    _, idx = cKDTree(targets).query(points, k=1)
    return np.asarray(idx, dtype=np.int64)


# ---------------------------------------------------------------------------------------------------------------
# thin state
# ---------------------------------------------------------------------------------------------------------------
class GMPHDFilter:
    """Holds the Gaussian mixture and applies predict + birth, update and prune per measurement set.

    Attributes
    ----------
    log_weights_ : ndarray, shape (J,)
    means_ : ndarray, shape (J, 2), metres
    covariances_ : ndarray, shape (J, 2, 2), m²
    """

    def __init__(self, params: GMPHDParams | None = None) -> None:
        self.params = params if params is not None else GMPHDParams()
        self._birth = birth_components(self.params)
        self.log_weights_ = np.empty(0)
        self.means_ = np.empty((0, 2))
        self.covariances_ = np.empty((0, 2, 2))

    def step(self, z: np.ndarray) -> None:
        """One filter cycle with measurement set z, shape (K, 2), metres."""
        prm = self.params
        z = np.asarray(z, dtype=float).reshape(-1, 2)
        lw, m, p = predict(self.log_weights_, self.means_, self.covariances_, prm.survival, prm.q)
        blw, bm, bp = self._birth
        lw, m, p = np.concatenate([lw, blw]), np.concatenate([m, bm]), np.concatenate([p, bp])
        lw, m, p = update(lw, m, p, z, prm.detection, prm.r, prm.clutter_intensity)
        self.log_weights_, self.means_, self.covariances_ = prune(
            lw, m, p, prm.truncation, prm.merge_threshold, prm.max_components)

    def targets(self) -> np.ndarray:
        """ndarray, shape (T, 2): extracted target positions (T >= 1 once the mixture is non-empty)."""
        return self.means_[extract_targets(self.log_weights_, self.params.bias)]


class GMPHDLabeller:
    """Point labeller for :class:`pipeline.track.cluster.HardTrackingWrapper` backed by a GM-PHD filter.

    At each contact step the new points (last ``n_new`` rows, at their pre-motion locations) are the measurement
    set; every stored point is then labelled by its nearest extracted target.
    """

    def __init__(self, params: GMPHDParams | None = None) -> None:
        self.params = params if params is not None else GMPHDParams()
        self.filter_ = GMPHDFilter(self.params)

    def fit_labels(self, points: np.ndarray, n_new: int) -> np.ndarray:
        """points (M, 2) with the n_new newest last -> labels (M,) int64 (never -1)."""
        if points.shape[1] != 2:
            raise ValueError(f"GM-PHD baseline is planar: points must have 2 columns, got {points.shape[1]}")
        self.filter_.step(points[len(points) - n_new:])
        return self.final_labels(points)

    def final_labels(self, points: np.ndarray) -> np.ndarray:
        """points (M, 2) -> labels (M,) int64 by nearest extracted target of the current mixture."""
        if len(points) == 0 or len(self.filter_.log_weights_) == 0:
            return np.zeros(len(points), dtype=np.int64)
        return nearest_labels(points, self.filter_.targets())
