"""The soft tracker's per-step weight arithmetic as compiled kernels: the same operations, in the same order, as
:mod:`pipeline.track.resampling` and ``SoftTracker._reweight_and_resample`` did with numpy, so every weight, ESS
and ancestor keeps its bits (docs/tracker_speed.md). What it saves is the Python and numpy call overhead of about
twenty small array operations per step (tens of microseconds each), which was a sixth of a whole N=100 replay.

Bit-identity rests on three facts, each checked by ``tests/test_weights.py`` against numpy:

* ``np.sum`` of a contiguous float64 vector is numpy's pairwise summation (blocks of 8 accumulators up to 128
  elements, halves above), written out in :func:`_pairwise_sum`;
* ``np.cumsum``, ``max``, ``argmax``, ``maximum`` and ``searchsorted`` are sequential or exact;
* :func:`math.exp` and :func:`math.log` compiled by numba are the C library's scalar functions, as are
  :func:`pipeline.portable.exp` and :func:`pipeline.portable.log` that numpy ran.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

#: numpy's pairwise summation block (``PW_BLOCKSIZE`` in numpy's loops_utils.h).
_PW_BLOCK = 128


@njit(cache=True)
def _block_sum(a, start, n):
    """numpy's pairwise sum of at most ``_PW_BLOCK`` elements: sequential below 8, else 8 accumulators combined
    as a tree, then the remainder."""
    if n < 8:
        res = 0.0
        for i in range(start, start + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[start], a[start + 1], a[start + 2], a[start + 3]
    r4, r5, r6, r7 = a[start + 4], a[start + 5], a[start + 6], a[start + 7]
    stop = n - n % 8
    i = 8
    while i < stop:
        b = start + i
        r0 += a[b]
        r1 += a[b + 1]
        r2 += a[b + 2]
        r3 += a[b + 3]
        r4 += a[b + 4]
        r5 += a[b + 5]
        r6 += a[b + 6]
        r7 += a[b + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[start + i]
        i += 1
    return res


@njit(cache=True)
def _pairwise_sum_stack(a, start, n):
    """:func:`_pairwise_sum` of any length: the same tree walked with an explicit stack."""
    if n <= _PW_BLOCK:
        return _block_sum(a, start, n)
    depth = 64  # the tree is about log2(n / 128) deep
    starts = np.empty(depth, np.int64)
    sizes = np.empty(depth, np.int64)
    phase = np.empty(depth, np.int64)
    sums = np.empty(depth + 1)
    top = 1
    starts[0], sizes[0], phase[0] = start, n, 0
    n_sums = 0
    while top > 0:
        s, m = starts[top - 1], sizes[top - 1]
        if m <= _PW_BLOCK:
            sums[n_sums] = _block_sum(a, s, m)
            n_sums += 1
            top -= 1
            continue
        half = m // 2
        half -= half % 8
        if phase[top - 1] == 0:  # the first half next
            phase[top - 1] = 1
            starts[top], sizes[top], phase[top] = s, half, 0
            top += 1
        elif phase[top - 1] == 1:  # then the second
            phase[top - 1] = 2
            starts[top], sizes[top], phase[top] = s + half, m - half, 0
            top += 1
        else:  # both halves summed: first + second
            sums[n_sums - 2] = sums[n_sums - 2] + sums[n_sums - 1]
            n_sums -= 1
            top -= 1
    return sums[0]


# numpy recurses; numba cannot cache a recursive function, so each depth of the tree has a function of its own:
# _pw{k} sums up to _PW_SIZES[k] elements (the halves of n elements are at most n / 2 + 8 long).
_PW_SIZES = (128, 248, 488, 968, 1928, 3848, 7688)


@njit(cache=True)
def _pw1(a, start, n):
    """Pairwise sum of at most 248 elements: a block, or two halves by :func:`_block_sum`."""
    if n <= _PW_BLOCK:
        return _block_sum(a, start, n)
    half = n // 2 - (n // 2) % 8
    return _block_sum(a, start, half) + _block_sum(a, start + half, n - half)


@njit(cache=True)
def _pw2(a, start, n):
    """Pairwise sum of at most 488 elements: a block, or two halves by :func:`_pw1`."""
    if n <= _PW_BLOCK:
        return _block_sum(a, start, n)
    half = n // 2 - (n // 2) % 8
    return _pw1(a, start, half) + _pw1(a, start + half, n - half)


@njit(cache=True)
def _pw3(a, start, n):
    """Pairwise sum of at most 968 elements: a block, or two halves by :func:`_pw2`."""
    if n <= _PW_BLOCK:
        return _block_sum(a, start, n)
    half = n // 2 - (n // 2) % 8
    return _pw2(a, start, half) + _pw2(a, start + half, n - half)


@njit(cache=True)
def _pw4(a, start, n):
    """Pairwise sum of at most 1928 elements: a block, or two halves by :func:`_pw3`."""
    if n <= _PW_BLOCK:
        return _block_sum(a, start, n)
    half = n // 2 - (n // 2) % 8
    return _pw3(a, start, half) + _pw3(a, start + half, n - half)


@njit(cache=True)
def _pw5(a, start, n):
    """Pairwise sum of at most 3848 elements: a block, or two halves by :func:`_pw4`."""
    if n <= _PW_BLOCK:
        return _block_sum(a, start, n)
    half = n // 2 - (n // 2) % 8
    return _pw4(a, start, half) + _pw4(a, start + half, n - half)


@njit(cache=True)
def _pw6(a, start, n):
    """Pairwise sum of at most 7688 elements: a block, or two halves by :func:`_pw5`."""
    if n <= _PW_BLOCK:
        return _block_sum(a, start, n)
    half = n // 2 - (n // 2) % 8
    return _pw5(a, start, half) + _pw5(a, start + half, n - half)


@njit(cache=True)
def _pairwise_sum(a, start, n):
    """``np.sum(a[start:start + n])`` for a contiguous float64 vector, in numpy's order: blocks of at most
    ``_PW_BLOCK`` elements (:func:`_block_sum`), above that the sum of the two halves, recursively. Up to 7688
    elements without allocating (per-depth functions), beyond with an explicit stack."""
    if n <= _PW_SIZES[1]:
        return _pw1(a, start, n)
    if n <= _PW_SIZES[3]:
        return _pw3(a, start, n)
    if n <= _PW_SIZES[6]:
        return _pw6(a, start, n)
    return _pairwise_sum_stack(a, start, n)


@njit(cache=True)
def _logsumexp(a):
    """:func:`pipeline.track.resampling.logsumexp` of a float64 vector (N,)."""
    top = a[0]
    for i in range(1, a.size):
        v = a[i]
        if v > top or v != v:  # np.max propagates nan
            top = v
            if v != v:
                break
    if not np.isfinite(top):
        return top
    shifted = np.empty(a.size)
    for i in range(a.size):
        shifted[i] = math.exp(a[i] - top)
    return top + math.log(_pairwise_sum(shifted, 0, a.size))


@njit(cache=True)
def _normalise(a):
    """:func:`pipeline.track.resampling.normalise`: log-weights (N,) that sum to one in linear space."""
    total = _logsumexp(a)
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
    lw = _normalise(log_w)
    ess = math.exp(-_logsumexp(2.0 * lw)) / n
    # Round-off puts a perfectly even set of weights a hair above or below 1: "all particles equal" reads 1.
    ess = 1.0 if abs(ess - 1.0) < 1e-12 else min(ess, 1.0)
    return False, log_w, ess, _argmax(log_w)


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
