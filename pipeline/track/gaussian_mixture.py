"""Gaussian-mixture PHD filter maths on arrays: prediction, update, pruning and target extraction.

Written from the equations of B.-N. Vo and W.-K. Ma, "The Gaussian mixture probability hypothesis density
filter", IEEE Trans. Signal Processing 54(11), 2006 (Table 1: prediction and update; Table 2: pruning), for the
model of the GM-PHD baseline (paper §V-A; the model itself is in :mod:`pipeline.track.gmphd`): F = I (static
targets), Q = q·I, H = I, R = r·I, no spawning.

A mixture is held as arrays (log-weights (J,), means (J, D), covariances (J, D, D)) and every function here is a
pure function of those arrays and scalar parameters. Weights are logs throughout; Gaussian likelihoods come from
Cholesky factors (log-determinant from the diagonal, :mod:`pipeline.spd`), never from explicit inverses.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from pipeline.portable import exp, log, logsumexp
from pipeline.spd import cho_solve_matrix, cholesky, largest_eigenvalue_bound, matmul, solve_lower, symmetrise

__all__ = ["predict", "update", "prune", "extract_targets"]

_LOG_2PI = math.log(2.0 * math.pi)


# ---------------------------------------------------------------------------------------------------------------
# the recursion (Vo & Ma 2006, Tables 1 and 2) and the target extraction
# ---------------------------------------------------------------------------------------------------------------
def predict(log_w: np.ndarray, means: np.ndarray, covs: np.ndarray, survival: float,
            q: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Prediction of surviving components with F = I, Q = q·I (Vo-Ma Table 1, step 2; no spawning).

    log_w (J,), means (J, D), covs (J, D, D) -> same shapes.
    """
    d = means.shape[1]
    return log_w + math.log(survival), means.copy(), covs + q * np.eye(d)


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
    missed_lw = log_w + (math.log1p(-detection) if detection < 1 else -np.inf)
    if j == 0 or k == 0:
        keep = np.isfinite(missed_lw)
        return missed_lw[keep], means[keep], covs[keep]

    s = symmetrise(covs + r * eye)
    chol_s = cholesky(s)
    # Gain K = P S^-1 = (S^-1 P)^T, both symmetric.
    gain = np.swapaxes(cho_solve_matrix(chol_s, covs), -1, -2)  # (J, D, D)
    ikh = eye - gain
    # Joseph form keeps the updated covariance symmetric positive definite under round-off.
    cov_upd = symmetrise(matmul(matmul(ikh, covs), np.swapaxes(ikh, -1, -2))
                         + r * matmul(gain, np.swapaxes(gain, -1, -2)))

    innov = z[None, :, :] - means[:, None, :]  # (J, K, D)
    white = solve_lower(chol_s[:, None], innov)  # (J, K, D)
    log_det = 2.0 * log(np.diagonal(chol_s, axis1=-2, axis2=-1)).sum(-1)  # (J,)
    log_lik = -0.5 * (d * _LOG_2PI + log_det[:, None] + (white ** 2).sum(-1))  # (J, K)
    det_lw = math.log(detection) + log_w[:, None] + log_lik  # (J, K)
    log_kappa = math.log(clutter_intensity) if clutter_intensity > 0 else -np.inf
    log_norm = logsumexp(np.vstack([np.full((1, k), log_kappa), det_lw]), axis=0)  # (K,)
    # κ > 0 keeps the normaliser finite; with κ = 0 and no finite term a measurement simply adds nothing.
    safe_norm = np.where(np.isfinite(log_norm), log_norm, 0.0)
    det_lw = np.where(np.isfinite(log_norm)[None, :], det_lw - safe_norm[None, :], -np.inf)

    det_means = means[:, None, :] + np.sum(gain[:, None, :, :] * innov[:, :, None, :], axis=-1)  # (J, K, D)
    out_lw = np.concatenate([missed_lw, det_lw.T.ravel()])
    out_means = np.concatenate([means, det_means.transpose(1, 0, 2).reshape(-1, d)])
    out_covs = np.concatenate([covs, np.broadcast_to(cov_upd, (k, j, d, d)).reshape(-1, d, d)])
    keep = np.isfinite(out_lw)
    return out_lw[keep], out_means[keep], out_covs[keep]


def _group_logsumexp(values: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """logsumexp over contiguous groups beginning at ``starts`` of a 1-D array."""
    peak = np.maximum.reduceat(values, starts)
    counts = np.diff(np.append(starts, len(values)))
    return peak + log(np.add.reduceat(exp(values - np.repeat(peak, counts)), starts))


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

    keep = log_w > (math.log(truncation) if truncation > 0 else -np.inf)
    if not keep.any():
        keep[np.argmax(log_w)] = True
    lw, m, p = log_w[keep], means[keep], symmetrise(covs[keep])
    j = len(lw)
    chol = cholesky(p)

    # Candidate pairs through a Euclidean gate: d_M(i, j) >= |m_i - m_j|^2 / lambda_max(P_i), so no pair farther
    # than sqrt(U max lambda_max) can merge (lambda_max bounded above by Gershgorin's row sums, which only widens
    # the gate). Exact Mahalanobis distances are then computed on the pairs only.
    lam_max = largest_eigenvalue_bound(p)
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
    frac = exp(lw_s - np.repeat(g_lw, counts))  # normalised within group
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
    w = exp(log_w)
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
