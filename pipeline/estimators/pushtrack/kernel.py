"""Compiled loops of the pushtrack estimator: the free-space likelihood of every particle and the contact term of
the final refinement, each computing the **same bits** as the numpy form it replaces (tests/test_pushtrack_kernel.py).

* :func:`free_depth_sums`: :func:`pipeline.estimators.pushtrack.filter.free_loglik`'s sums of squared depths, which in
  numpy build (particles, free points) temporaries for every action of the filter;
* the contact term with each pose's own contact points, for the refinement of
  :func:`pipeline.estimators.pushtrack.estimator.refine_final`, is
  :func:`pipeline.estimators.plausible.kernel.piece_terms_each`.

As :mod:`pipeline.estimators.plausible.kernel` does, they repeat numpy's arithmetic operation by operation (the same
element-wise expressions, no fused multiply-add, the cosines and sines taken from numpy by the caller, numpy's
pairwise summation over a contiguous axis: :func:`pipeline.pairwise_sum.pairwise_sum`). ``NUMBA_DISABLE_JIT=1``
runs them as plain Python with the same results. Measured in docs/estimators.md, "The pushtrack estimator".
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from pipeline.estimators.plausible.kernel import local_sdf
from pipeline.pairwise_sum import pairwise_sum
from pipeline.track.weights import logsumexp

__all__ = ["free_depth_sums", "reweigh", "near_points", "warm_up"]


@njit(cache=True)
def free_depth_sums(cylinder, hx, hy, centre, cos_t, sin_t, pts, tol, sigma, reach, out, scratch):
    """Sum over the points of (min(sd + tol, 0) / sigma)^2, for every pose, into ``out`` (N,).

    Parameters
    ----------
    cylinder : bool
        The primitive is a cylinder of radius ``hx``; else a box of half sides (hx, hy), metres.
    centre : ndarray, shape (N, 2), metres
        World position of the primitive's centre at each pose; ``cos_t``, ``sin_t`` (N,) the cosines and sines
        of its axes' yaw (numpy's, as the caller's numpy form takes them).
    pts : ndarray, shape (F, 2), metres
        World points.
    tol, sigma : float, metres
        Depth that costs nothing and the depth's scale.
    reach : float, metres
        A point farther than this from the centre lies outside the primitive, sd + tol > 0, and its term is
        exactly 0.0: the caller gives the primitive's circumradius plus a margin, so the sdf is skipped there
        without changing a bit.
    scratch : ndarray, shape (F,)
        Work space for the per-point terms (summed in numpy's pairwise order).
    """
    N = centre.shape[0]
    F = pts.shape[0]
    r2 = reach * reach
    for n in range(N):
        c = cos_t[n]
        s = sin_t[n]
        px = centre[n, 0]
        py = centre[n, 1]
        terms = 0  # the points of a nonzero (or NaN) term
        for p in range(F):
            dx = pts[p, 0] - px
            dy = pts[p, 1] - py
            d2 = dx * dx + dy * dy
            if r2 < d2 < math.inf:  # (an infinite offset takes numpy's path: its NaNs)
                scratch[p] = 0.0
                continue
            sd, _, _ = local_sdf(cylinder, hx, hy, c * dx + s * dy, -s * dx + c * dy)
            r = min(sd + tol, 0.0) / sigma
            scratch[p] = r * r
            if scratch[p] != 0.0:
                terms += 1
        # Every term is +0.0 or a square: the pairwise sum of F > 0 terms all +0.0 is +0.0, exactly
        out[n] = pairwise_sum(scratch, 0, F) if terms or F == 0 else 0.0


@njit(cache=True)
def reweigh(log_w, ll, out):
    """One update of the filter's log-weights, into ``out`` (N,): log_w + ll normalised (NaN read as -inf;
    uniform when none is finite), as :func:`pipeline.estimators.pushtrack.filter.run_filter` wrote it in numpy,
    bit for bit (:func:`pipeline.track.weights.logsumexp`). Returns (the log of the updated weights' total before
    normalising, -inf when none is finite; the log of ``log_w``'s total): their difference is the step's evidence."""
    n = log_w.shape[0]
    finite = False
    for i in range(n):
        v = log_w[i] + ll[i]
        if math.isnan(v):
            v = -math.inf
        out[i] = v
        if math.isfinite(v):
            finite = True
    prev = logsumexp(log_w)
    if not finite:
        u = -math.log(n)
        for i in range(n):
            out[i] = u
        return -math.inf, prev
    total = logsumexp(out)
    for i in range(n):
        out[i] = out[i] - total
    return total, prev


@njit(cache=True)
def near_points(poses, pts, cx, cy, reach, radius):
    """The points ``pts`` (P, G, 2) of the poses (P, 2) within ``reach`` of (cx, cy), then those of them within
    ``radius``, in their order: (M, 2). The same selection as numpy's ``np.hypot`` masks (the C library's hypot)."""
    P, G = pts.shape[0], pts.shape[1]
    out = np.empty((P * G, 2))
    m = 0
    for p in range(P):
        if not math.hypot(poses[p, 0] - cx, poses[p, 1] - cy) <= reach:
            continue
        for g in range(G):
            x = pts[p, g, 0]
            y = pts[p, g, 1]
            if math.hypot(x - cx, y - cy) <= radius:
                out[m, 0] = x
                out[m, 1] = y
                m += 1
    return out[:m]


def warm_up() -> None:
    """Compile the kernels (once per machine: numba caches them on disk), as ``make setup`` does, so that no
    evaluation job pays for it."""
    one = np.ones(1)
    for cylinder in (False, True):
        free_depth_sums(cylinder, 0.1, 0.1, np.zeros((1, 2)), one, np.zeros(1), np.zeros((1, 2)), 0.004, 0.003,
                        0.2, np.empty(1), np.empty(1))
    reweigh(np.zeros(2), np.zeros(2), np.empty(2))
    near_points(np.zeros((1, 2)), np.zeros((1, 1, 2)), 0.0, 0.0, 1.0, 1.0)
