"""Sorted-order bookkeeping of the soft tracker's kernels (:mod:`pipeline.track.kernels`): each particle's points
by first coordinate, split into displacement groups, merged back, repaired after Alg. 2; searches in sorted runs;
the adjacency draw ``u < exp(t)`` decided without exp where a table settles it; and resampling's row copies.

Everything here only decides *which* pairs the kernels evaluate and in what order, never a value: a group is
visited in exactly the order the kernels always used (``np.argsort`` of the group's first coordinates by point
index) whenever the order could matter, so results keep their bits (README.md, "Benchmarks").
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

#: exp(-k / EXP_STEPS) for k = 0 .. EXP_STEPS * EXP_SPAN, bounds of exp(t) on each step of t (see below_exp).
EXP_STEPS = 64
EXP_SPAN = 40
EXP_TABLE = np.array([math.exp(-k / EXP_STEPS) for k in range(EXP_STEPS * EXP_SPAN + 2)])
#: Relative slack of those bounds: far above the error of any exp implementation (a few ulps, 1e-15).
EXP_SLACK = 1e-13


@njit(cache=True)
def below_exp(u, t):
    """``u < math.exp(t)`` for t <= 0, the same decision, with exp computed only when u falls within the table's
    bounds of exp(t): t lies in [-(k + 1), -k] / EXP_STEPS, where exp is between two tabulated values (to within
    EXP_SLACK), so a u outside that band is decided by the table (about 98 % of the draws)."""
    s = -t * EXP_STEPS  # exact: a power of two
    if s < EXP_STEPS * EXP_SPAN:
        k = int(s)
        if u < EXP_TABLE[k + 1] * (1.0 - EXP_SLACK):
            return True
        if u >= EXP_TABLE[k] * (1.0 + EXP_SLACK):
            return False
    return u < math.exp(t)


@njit(cache=True)
def first_at_least(xs, start, stop, v):
    """First index in [start, stop) with xs[index] >= v (stop if none), xs sorted there: ``start +
    np.searchsorted(xs[start:stop], v)``, by a branch-free bisection."""
    n = stop - start
    if n <= 0:
        return start
    base = start
    while n > 1:
        half = n >> 1
        base = base + half if xs[base + half] < v else base
        n -= half
    return base + 1 if xs[base] < v else base


@njit(cache=True)
def first_above(xs, start, stop, v):
    """First index in [start, stop) with xs[index] > v (stop if none): ``side="right"`` of searchsorted."""
    n = stop - start
    if n <= 0:
        return start
    base = start
    while n > 1:
        half = n >> 1
        base = base + half if xs[base + half] <= v else base
        n -= half
    return base + 1 if xs[base] <= v else base


@njit(cache=True)
def groups_by_first_coordinate(P, C, n, group, order, m_old, K):
    """Particle n's old points by displacement group, each group sorted by its points' first coordinate, so that
    each config only scans the window of points that can lie inside the robot's interior box.

    ``order[n, :m_old]`` lists the points by first coordinate before the motion; a group moved by one shift keeps
    that order, so a stable split gives each group sorted. Where the split is not sorted (an order not kept up to
    date) or two points of a group tie on the coordinate with different configs, the group is sorted as it
    always was (``np.argsort`` of its coordinates by point index), so configs reach every point in the same
    order as ever and its sums keep their bits: the order of a group matters only as the order in which its
    configs add their terms, and equal configs add equal terms in either order.

    Returns (counts (K + 2,): group a is ``gorder[counts[a]:counts[a + 1]]``, gorder (m_old,), xs (m_old,): first
    coordinates in that order, ys (m_old,): second coordinates in that order (zeros when D = 1), dup (m_old,):
    the point is at the same position as the one before it in its group).
    """
    D = P.shape[2]
    counts = np.zeros(K + 2, np.int64)
    for j in range(m_old):
        counts[group[j] + 1] += 1
    for a in range(K + 1):
        counts[a + 1] += counts[a]
    gorder = np.empty(m_old, np.int64)
    xs = np.empty(m_old)
    ys = np.zeros(m_old)
    dup = np.zeros(m_old, np.bool_)
    resort = np.zeros(K + 1, np.bool_)
    fill = counts[: K + 1].copy()
    for t in range(m_old):
        j = order[n, t]
        a = group[j]
        f = fill[a]
        fill[a] = f + 1
        gorder[f] = j
        x0 = P[n, j, 0]
        xs[f] = x0
        if D > 1:
            ys[f] = P[n, j, 1]
        if f > counts[a] and x0 <= xs[f - 1]:
            k = gorder[f - 1]
            if x0 < xs[f - 1] or not same_config(C, n, j, k):
                resort[a] = True
            else:
                dup[f] = _same_position(P, n, j, k)
    for a in range(K + 1):
        if resort[a]:
            _sort_group(P, n, group, a, counts, gorder, xs)
            for f in range(counts[a], counts[a + 1]):
                if D > 1:
                    ys[f] = P[n, gorder[f], 1]
                dup[f] = f > counts[a] and xs[f] == xs[f - 1] and _same_position(P, n, gorder[f], gorder[f - 1])
    return counts, gorder, xs, ys, dup


@njit(cache=True)
def _same_position(P, n, i, j):
    for d in range(P.shape[2]):
        if P[n, i, d] != P[n, j, d]:
            return False
    return True


@njit(cache=True)
def same_config(C, n, i, k):
    """Configs i and k of particle n are equal: they add equal terms to any point."""
    for d in range(C.shape[2]):
        if C[n, i, d] != C[n, k, d]:
            return False
    return True


@njit(cache=True)
def _sort_group(P, n, group, a, counts, gorder, xs):
    """Group a sorted by first coordinate with ``np.argsort`` of the coordinates of its points taken by index."""
    c0 = counts[a]
    seg = np.empty(counts[a + 1] - c0, np.int64)
    key = np.empty(seg.size)
    t = 0
    for j in range(group.size):
        if group[j] == a:
            seg[t] = j
            key[t] = P[n, j, 0]
            t += 1
    srt = np.argsort(key)
    for t in range(seg.size):
        gorder[c0 + t] = seg[srt[t]]
        xs[c0 + t] = key[srt[t]]


@njit(cache=True)
def merge_order(P, n, counts, gorder, xs, order, m_old, K):
    """``order[n, :m_old + K]``: every point of particle n by first coordinate after the step, merged from the
    sorted groups, the K new points inserted (ties in any order: see :func:`groups_by_first_coordinate`)."""
    pos = counts[: K + 1].copy()
    for t in range(m_old):
        best = -1
        for a in range(K + 1):
            if pos[a] < counts[a + 1] and (best < 0 or xs[pos[a]] < xs[pos[best]]):
                best = a
        order[n, t] = gorder[pos[best]]
        pos[best] += 1
    for k in range(K):
        j = m_old + k
        v = P[n, j, 0]
        t = m_old + k
        while t > 0 and P[n, order[n, t - 1], 0] > v:
            order[n, t] = order[n, t - 1]
            t -= 1
        order[n, t] = j


@njit(cache=True)
def reinsert(P, n, order, m, is_bad, bad):
    """Bring ``order[n, :m]`` (points by first coordinate) up to date after the points ``bad`` moved: drop them,
    then insert each at its new place."""
    t = 0
    for s in range(m):
        if not is_bad[order[n, s]]:
            order[n, t] = order[n, s]
            t += 1
    for b in range(bad.size):
        j = bad[b]
        v = P[n, j, 0]
        s = t
        while s > 0 and P[n, order[n, s - 1], 0] > v:
            order[n, s] = order[n, s - 1]
            s -= 1
        order[n, s] = j
        t += 1


@njit(cache=True)
def take_rows(ancestors, m, P, C, colpen, npen, order):
    """Resampling in place: particle i becomes a copy of particle ``ancestors[i]`` (its first m points and their
    bookkeeping). ``ancestors`` must be sorted (systematic resampling's are): then the rows that pull from a later
    row, done first in increasing order, and those that pull from an earlier one, done second in decreasing
    order, always read a row that has not been overwritten yet."""
    N = ancestors.size
    for i in range(1, N):
        if ancestors[i] < ancestors[i - 1]:
            raise ValueError("take_rows: ancestors must be sorted")
    for i in range(N):
        if ancestors[i] > i:
            _copy_row(ancestors[i], i, m, P, C, colpen, npen, order)
    for i in range(N - 1, -1, -1):
        if ancestors[i] < i:
            _copy_row(ancestors[i], i, m, P, C, colpen, npen, order)


@njit(cache=True)
def _copy_row(src, dst, m, P, C, colpen, npen, order):
    """Row ``src`` of each array onto row ``dst`` (first m points), one flat loop per array: points and configs
    as (N, capacity * D) views, which numba turns into plain block copies (a third faster than a loop over
    points and coordinates)."""
    D = P.shape[2]
    Pf = P.reshape(P.shape[0], P.shape[1] * D)
    Cf = C.reshape(C.shape[0], C.shape[1] * D)
    for j in range(m * D):
        Pf[dst, j] = Pf[src, j]
    for j in range(m * D):
        Cf[dst, j] = Cf[src, j]
    for j in range(m):
        colpen[dst, j] = colpen[src, j]
    for j in range(m):
        npen[dst, j] = npen[src, j]
    for j in range(m):
        order[dst, j] = order[src, j]
