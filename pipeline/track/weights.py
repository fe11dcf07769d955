"""The soft tracker's per-step weight arithmetic as compiled kernels: the same operations, in the same order, as
:mod:`pipeline.track.resampling` and ``SoftTracker._reweight_and_resample`` did with numpy, so every weight, ESS
and ancestor keeps its bits (docs/experiments/tracker-speed.md). What it saves is the Python and numpy call overhead of
about
twenty small array operations per step (tens of microseconds each), which was a sixth of a whole N=100 replay.

Bit-identity rests on three facts, each checked by ``tests/test_weights.py`` against numpy:

* ``np.sum`` of a contiguous float64 vector is numpy's pairwise summation (blocks of 8 accumulators up to 128
  elements, halves above), written out in :func:`pipeline.pairwise_sum.pairwise_sum`;
* ``np.cumsum``, ``max``, ``argmax``, ``maximum`` and ``searchsorted`` are sequential or exact;
* :func:`math.exp` and :func:`math.log` compiled by numba are the C library's scalar functions, as are
  :func:`pipeline.portable.exp` and :func:`pipeline.portable.log` that numpy ran.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from pipeline.pairwise_sum import pairwise_sum


@njit(cache=True)
def _max(a):
    """``np.max`` of a vector (nan if any)."""
    top = a[0]
    for i in range(1, a.size):
        if a[i] > top or a[i] != a[i]:
            top = a[i]
            if top != top:
                break
    return top


@njit(cache=True)
def logsumexp(a):
    """:func:`pipeline.portable.logsumexp` of a float64 vector (N,), as :func:`pipeline.track.resampling.normalise`
    computes it (the pushtrack filter's weights use it too)."""
    top = _max(a)
    if not np.isfinite(top):
        return top
    shifted = np.empty(a.size)
    for i in range(a.size):
        shifted[i] = math.exp(a[i] - top)
    return top + math.log(pairwise_sum(shifted, 0, a.size))


@njit(cache=True)
def _normalise(a):
    """:func:`pipeline.track.resampling.normalise`: log-weights (N,) that sum to one in linear space."""
    total = logsumexp(a)
    if not np.isfinite(total):
        raise ValueError("cannot normalise log-weights: no particle has a finite weight")
    return a - total


@njit(cache=True)
def _argmax(a):
    """``np.argmax``: the first index of the largest value (of the first nan if any)."""
    best = 0
    for i in range(1, a.size):
        if a[best] != a[best]:
            break
        if a[i] > a[best] or a[i] != a[i]:
            best = i
    return best


@njit(cache=True)
def reweight(log_weights, eps, may_skip, reference, penetration_length, floor, log_floor):
    """One step's weights from the particles' penetrations.

    Parameters
    ----------
    log_weights : ndarray, shape (N,)
        Normalised log-weights before the step.
    eps : ndarray, shape (N,)
        Summed penetration of each particle (<= 0, metres).
    may_skip : bool
        Whether an even step may leave the weights as they are (see ``SoftTracker._reweight_and_resample``).
    reference : bool
        Penetration relative to the least penetrating particle (the authors' weighting) instead of raw.
    penetration_length : float
        l_p (m^2).
    floor, log_floor : float
        Weight floor and its ``math.log`` (computed by the caller); no floor when ``floor`` is 0.

    Returns
    -------
    skipped : bool
        ``may_skip`` and every eps equal: nothing else was computed (``log_w`` is ``log_weights``, ess nan).
    log_w : ndarray, shape (N,)
        Normalised (and floored) log-weights after the step.
    ess : float
        Effective sample size as a fraction of N, in (0, 1].
    map_index : int
        Index of the largest weight (the first one on ties); of ``log_weights`` when skipped.
    """
    n = eps.size
    hi = eps[0]
    lo = eps[0]
    for i in range(1, n):
        hi = max(hi, eps[i])
        lo = min(lo, eps[i])
    if may_skip and hi - lo == 0.0:  # np.ptp(eps) == 0.0
        return True, log_weights, math.nan, _argmax(log_weights)
    shift = _max(eps) if reference else 0.0
    log_w = np.empty(n)
    for i in range(n):
        e = eps[i] - shift if reference else eps[i]
        log_w[i] = log_weights[i] + -(e * e) / penetration_length
    log_w = _normalise(log_w)
    if floor > 0:
        for i in range(n):
            log_w[i] = max(log_w[i], log_floor)
        log_w = _normalise(log_w)
    # Normalised once more, as resampling.effective_sample_size does with its input: the weights' bits, not their
    # meaning, can change on the second pass, and the ESS must keep numpy's bits.
    lw = _normalise(log_w)
    ess = math.exp(-logsumexp(2.0 * lw)) / n
    # Round-off puts a perfectly even set of weights a hair above or below 1: "all particles equal" reads 1.
    ess = 1.0 if abs(ess - 1.0) < 1e-12 else min(ess, 1.0)
    return False, log_w, ess, _argmax(log_w)


@njit(cache=True)
def systematic_ancestors(log_w, offset):
    """:func:`pipeline.track.resampling.systematic` given its uniform draw ``offset`` in [0, 1): sorted ancestors
    (N,) int64, and the distinct ones among them (sorted, int64)."""
    n = log_w.size
    lw = _normalise(log_w)
    cdf = np.empty(n)
    acc = 0.0
    for i in range(n):
        acc += math.exp(lw[i])  # np.cumsum: sequential
        cdf[i] = acc
    cdf[n - 1] = 1.0  # round-off must not leave the last positions without an ancestor
    ancestors = np.empty(n, np.int64)
    # np.searchsorted(cdf, positions, side="right"), numpy's own bisection (its bounds carried over from the
    # previous key), so a cdf made non-monotone by cdf[-1] = 1 gives the same index as ever
    lo_idx = 0
    hi_idx = n
    last = offset / n
    for i in range(n):
        pos = (offset + i) / n
        if last < pos:
            hi_idx = n
        else:
            lo_idx = 0
            hi_idx = hi_idx + 1 if hi_idx < n else n
        last = pos
        while lo_idx < hi_idx:
            mid = lo_idx + ((hi_idx - lo_idx) >> 1)
            if not pos < cdf[mid]:
                lo_idx = mid + 1
            else:
                hi_idx = mid
        ancestors[i] = min(lo_idx, n - 1)
    n_distinct = 1
    for i in range(1, n):
        n_distinct += ancestors[i] != ancestors[i - 1]
    distinct = np.empty(n_distinct, np.int64)
    distinct[0] = ancestors[0]
    t = 1
    for i in range(1, n):
        if ancestors[i] != ancestors[i - 1]:
            distinct[t] = ancestors[i]
            t += 1
    return ancestors, distinct
