"""Compiled kernels of the soft tracker (paper §IV-B): penetration bookkeeping on whole particle arrays.

All kernels work on the tracker's arrays in place:

* ``P`` and ``C``: float64, shape (N, capacity, D) -- contact points and the end-effector configuration at which
  each was observed, per particle (metres). Only the first ``m`` slots are live.
* ``colpen``: float64, shape (N, capacity) -- for each point j of each particle, the summed penetration it incurs
  against every config of the same particle: ``sum_i min(0, sdf(P[n, j] - C[n, i]) + tol)`` (<= 0, metres).
* ``npen``: int32, shape (N, capacity) -- how many of those terms are negative. It is the exact test of
  "inconsistent point" (Alg. 2) and lets ``colpen`` be reset to exactly 0 so that additions and subtractions never
  leave round-off residue that would look like a penetration.

The paper's per-particle penetration epsilon_n (Alg. 1 line 16) is ``colpen[n, :m].sum()``. Keeping it per point
is what makes the update incremental: a contact step only changes pairs whose relative position changed (one
side moved by a different displacement than the other), plus the pairs of the new points. Pairs that cannot
penetrate are skipped with a bounding-box test against the robot's interior (the region where sdf < -tol): a
window of each particle's points kept sorted by first coordinate, then a test of the second
(:mod:`pipeline.track.ordering`). Copies that resampling and Alg. 2 make reuse the terms of their original. None of
this changes a value or the order in which a point's terms are added: the results keep their bits
(docs/experiments/tracker-speed.md).

The grid lookup is nearest-cell, ``idx = rint((q - origin) / resolution)`` (ties to even), outside the grid = free,
exactly as :meth:`pipeline.robot.GridSDF.query` does.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from pipeline.pairwise_sum import pairwise_sum
from pipeline.track.ordering import (
    below_exp,
    first_above,
    first_at_least,
    groups_by_first_coordinate,
    merge_order,
    same_config,
)

#: A term counts as penetrating only when sdf + tol is below -PEN_EPS (metres): grid cells that sit exactly at
#: -tol give sdf + tol = -1e-17 in float64 (0 in float32), and such a tie must not mark a point inconsistent.
PEN_EPS = 1e-12

#: Slack (metres) of the box tests that skip a pair before evaluating it, far above the round-off of an offset
#: (about 1e-17 m) and far below a grid cell: a skipped pair's terms are 0 before and after the motion.
WINDOW_MARGIN = 1e-9


def set_threads(n: int) -> None:
    """Threads the particle loops use. One by default: numba's thread pool collapses when the cores are busy
    (README.md, Benchmarks, has the figures), and results do not depend on it."""
    import numba

    numba.set_num_threads(max(1, min(int(n), numba.config.NUMBA_NUM_THREADS)))


def _default_threads() -> int:
    import os

    try:
        return int(os.environ.get("STUCCO_THREADS", "1"))
    except ValueError:
        return 1


@njit(cache=True)
def contribution(P, C, n, j, i, disp, a, b, values, shape, strides, origin, inv_res, lo, hi, tol):
    """Penetration term of point j against config i of particle n, as it was before a motion.

    Returns min(0, sdf(P[n, j] - C[n, i] - (disp[b] - disp[a])) + tol): the point moved by ``disp[b]`` and the
    config by ``disp[a]``; pass a == b for the current term. Works for any D.
    """
    flat = 0
    D = P.shape[2]
    for d in range(D):
        q = P[n, j, d] - C[n, i, d] - (disp[b, d] - disp[a, d])
        if q < lo[d] or q > hi[d]:
            return 0.0  # outside the robot's interior box: cannot penetrate deeper than tol
        k = int(np.rint((q - origin[d]) * inv_res))
        if k < 0 or k >= shape[d]:
            return 0.0
        flat += k * strides[d]
    v = values[flat] + tol
    return v if v < -PEN_EPS else 0.0


@njit(cache=True, parallel=True)
def predict_and_update(P, C, order, u, prev_points, dx, x, p, m_old, length, colpen, npen,
                       values, shape, strides, origin, inv_res, lo, hi, tol):
    """Predict step of Alg. 1 on every particle, then bring ``colpen``/``npen`` up to date.

    Each old point j of particle n is connected to its nearest new (pre-motion) point k with probability
    exp(-d^2 / l) (connected when ``u[n, j]`` is below it) and, if connected, it and its config translate by
    ``dx[k]``. The K new points are appended at ``p`` with config ``x`` (their pre-motion location plus their own
    motion). Then only the pairs whose relative position changed are re-evaluated: a config and a point moved by
    different displacements, and every pair involving a new point.

    Parameters
    ----------
    P, C : ndarray, shape (N, capacity, D)
        Points and configs, updated in place; slots ``m_old .. m_old+K-1`` receive the new points.
    order : ndarray, shape (N, capacity), int32
        Each particle's points by first coordinate (an accelerator: any content gives the same results); kept up
        to date in place.
    u : ndarray, shape (N, m_old)
        Uniform draws in [0, 1) for the adjacency sampling.
    prev_points : ndarray, shape (K, D)
        New contact points at their pre-motion location (p - dx).
    dx : ndarray, shape (K, D)
        In-contact displacement of each new contact (metres).
    x : ndarray, shape (D,)
        End-effector position after the step.
    p : ndarray, shape (K, D)
        New contact points after the step.
    length : float
        Characteristic length l (m^2).
    colpen, npen : ndarray, shape (N, capacity)
        Updated in place.
    values, shape, strides, origin, inv_res : grid of the robot SDF (see ``GridSDF.kernel_arrays``).
    lo, hi : ndarray, shape (D,)
        Robot-frame box outside which no query can penetrate deeper than the tolerance.
    tol : float
        Intersection tolerance (metres).

    Returns
    -------
    eps : ndarray, shape (N,)
        Each particle's summed penetration after the step, ``colpen[:, :m_old + K].sum(axis=1)`` with numpy's
        summation order, taken while the particle's row is still in cache.
    """
    N = P.shape[0]
    D = P.shape[2]
    K = dx.shape[0]
    eps = np.empty(N)
    zero = np.zeros((1, D))
    disp = np.zeros((K + 1, D))  # row K: "did not move"
    for k in range(K):
        for d in range(D):
            disp[k, d] = dx[k, d]
    for n in prange(N):
        group = _predict_particle(P, C, n, u, prev_points, dx, x, p, m_old, length)
        counts, gorder, xs, ys, dup = groups_by_first_coordinate(P, C, n, group, order, m_old, K)
        _update_moved_pairs(P, C, n, counts, gorder, xs, ys, dup, disp, zero, colpen, npen, values, shape, strides,
                            origin, inv_res, lo, hi, tol)
        _add_new_pairs(P, C, n, m_old, m_old + K, counts, gorder, xs, ys, zero, colpen, npen, values, shape,
                       strides, origin, inv_res, lo, hi, tol)
        merge_order(P, n, counts, gorder, xs, order, m_old, K)
        eps[n] = 0.0 + pairwise_sum(colpen[n], 0, m_old + K)  # 0.0 +: np.sum's +0 for a sum of -0s
    return eps


@njit(cache=True)
def _predict_particle(P, C, n, u, prev_points, dx, x, p, m_old, length):
    """Alg. 1's prediction on particle n: each old point joins its nearest new point with probability
    exp(-d^2 / l) and moves with it; the K new points are appended. Returns each old point's displacement group
    (m_old,) int64: the new point it moved with, or K (did not move)."""
    D = P.shape[2]
    K = dx.shape[0]
    group = np.empty(m_old, np.int64)
    for j in range(m_old):
        best = 0
        best_d2 = np.inf
        for k in range(K):
            d2 = 0.0
            for d in range(D):
                t = P[n, j, d] - prev_points[k, d]
                d2 += t * t
            if d2 < best_d2:
                best_d2 = d2
                best = k
        joined = below_exp(u[n, j], -best_d2 / length)
        group[j] = best if joined else K
        for d in range(D):  # without a branch: whether a point joins is a coin flip
            v = P[n, j, d]
            w = C[n, j, d]
            P[n, j, d] = v + dx[best, d] if joined else v
            C[n, j, d] = w + dx[best, d] if joined else w
    for k in range(K):
        for d in range(D):
            P[n, m_old + k, d] = p[k, d]
            C[n, m_old + k, d] = x[d]
    return group


@njit(cache=True)
def _update_moved_pairs(P, C, n, counts, order, xs, ys, dup, disp, zero, colpen, npen, values, shape, strides, origin,
                        inv_res, lo, hi, tol):
    """Re-evaluate, on particle n, every (config, point) pair of old points whose groups moved by different
    displacements, updating ``colpen``/``npen`` by the change. Only pairs whose old or new offset can lie in the
    robot's box are evaluated: a window of the points sorted by the first coordinate, then a test of the second
    (with ``WINDOW_MARGIN`` against round-off). A point's terms are added in the same order as ever (config group,
    then configs by their point's first coordinate), so its sums keep the same bits. Resampling and Alg. 2 fill
    particles with exact copies of points: a config equal to the previous one reuses its terms, and so does a
    point equal to the previous one (``dup``)."""
    K = disp.shape[0] - 1
    D = P.shape[2]
    m_old = order.size
    hit_j = np.empty(m_old, np.int64)  # the terms that changed for the last config evaluated
    hit_new = np.empty(m_old)
    hit_old = np.empty(m_old)
    for a in range(K + 1):  # group of the config
        for b in range(K + 1):  # group of the point
            if a == b or counts[a] == counts[a + 1] or counts[b] == counts[b + 1]:
                continue
            s0 = disp[b, 0] - disp[a, 0]  # how far the points moved relative to the configs (axis 0)
            win_lo = lo[0] + min(0.0, s0)
            win_hi = hi[0] + max(0.0, s0)
            y_lo = -np.inf
            y_hi = np.inf
            if D > 1:
                s1 = disp[b, 1] - disp[a, 1]
                y_lo = lo[1] + min(0.0, s1) - WINDOW_MARGIN
                y_hi = hi[1] + max(0.0, s1) + WINDOW_MARGIN
            n_hit = 0
            for ii in range(counts[a], counts[a + 1]):
                i = order[ii]
                if ii > counts[a] and same_config(C, n, i, order[ii - 1]):
                    # the same config as the previous one: the same window and terms, added again to each point
                    for h in range(n_hit):
                        _add_change(colpen, npen, n, hit_j[h], hit_new[h], hit_old[h])
                    continue
                n_hit = 0
                c0 = C[n, i, 0]
                c1 = C[n, i, 1] if D > 1 else 0.0
                j0 = first_at_least(xs, counts[b], counts[b + 1], c0 + win_lo)
                j1 = first_above(xs, j0, counts[b + 1], c0 + win_hi)
                new = 0.0
                old = 0.0
                for jj in range(j0, j1):
                    q1 = ys[jj] - c1
                    if q1 < y_lo or q1 > y_hi:
                        continue  # neither the old nor the new offset is in the box: both terms are 0
                    j = order[jj]
                    if jj == j0 or not dup[jj]:  # else the same point as the previous one: the same terms
                        new = contribution(P, C, n, j, i, zero, 0, 0, values, shape, strides, origin, inv_res,
                                            lo, hi, tol)
                        old = contribution(P, C, n, j, i, disp, a, b, values, shape, strides, origin, inv_res,
                                            lo, hi, tol)
                    if new != old:
                        _add_change(colpen, npen, n, j, new, old)
                        hit_j[n_hit] = j
                        hit_new[n_hit] = new
                        hit_old[n_hit] = old
                        n_hit += 1


@njit(cache=True)
def _add_change(colpen, npen, n, j, new, old):
    """Point j's term against one config changed from ``old`` to ``new``."""
    colpen[n, j] += new - old
    # ints: bool - bool fails in pure Python (NUMBA_DISABLE_JIT=1)
    npen[n, j] += int(new < 0.0) - int(old < 0.0)
    if npen[n, j] == 0:
        colpen[n, j] = 0.0


@njit(cache=True)
def _add_new_pairs(P, C, n, m_old, m_new, counts, order, xs, ys, zero, colpen, npen, values, shape, strides, origin,
                   inv_res, lo, hi, tol):
    """On particle n: the new points against every config, and the new configs against the old points (only
    those in the box's window, as in :func:`_update_moved_pairs`; one term per point and new config, in the
    order of the configs)."""
    D = P.shape[2]
    for j in range(m_old, m_new):
        colpen[n, j] = 0.0
        npen[n, j] = 0
        for i in range(m_new):
            c = contribution(P, C, n, j, i, zero, 0, 0, values, shape, strides, origin, inv_res, lo, hi, tol)
            if c < 0.0:
                colpen[n, j] += c
                npen[n, j] += 1
    for i in range(m_old, m_new):
        c0 = C[n, i, 0]
        c1 = C[n, i, 1] if D > 1 else 0.0
        for b in range(counts.size - 1):
            j0 = first_at_least(xs, counts[b], counts[b + 1], c0 + lo[0])
            j1 = first_above(xs, j0, counts[b + 1], c0 + hi[0])
            for jj in range(j0, j1):
                if D > 1:
                    q1 = ys[jj] - c1
                    if q1 < lo[1] - WINDOW_MARGIN or q1 > hi[1] + WINDOW_MARGIN:
                        continue
                j = order[jj]
                c = contribution(P, C, n, j, i, zero, 0, 0, values, shape, strides, origin, inv_res, lo, hi, tol)
                if c < 0.0:
                    colpen[n, j] += c
                    npen[n, j] += 1


@njit(cache=True, parallel=True)
def free_space_penetration(P, m, x, values, shape, strides, origin, inv_res, lo, hi, tol):
    """Summed penetration of every live point against the current config only (Alg. 1 line 20).

    Parameters
    ----------
    P : ndarray, shape (N, capacity, D)
    m : int
        Live points.
    x : ndarray, shape (D,)
        Current end-effector position (metres).

    Returns
    -------
    eps : ndarray, shape (N,)
        sum_j min(0, sdf(P[n, j] - x) + tol) (<= 0, metres).
    """
    N = P.shape[0]
    D = P.shape[2]
    eps = np.zeros(N)
    for n in prange(N):
        acc = 0.0
        for j in range(m):
            flat = 0
            inside = True
            for d in range(D):
                q = P[n, j, d] - x[d]
                if q < lo[d] or q > hi[d]:
                    inside = False
                    break
                k = int(np.rint((q - origin[d]) * inv_res))
                if k < 0 or k >= shape[d]:
                    inside = False
                    break
                flat += k * strides[d]
            if inside:
                v = values[flat] + tol
                if v < -PEN_EPS:
                    acc += v
        eps[n] = acc
    return eps


def penetration_bruteforce(P: np.ndarray, C: np.ndarray, m: int, query, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Reference (non-incremental) computation of ``colpen`` and ``npen`` with plain numpy.

    Parameters
    ----------
    P, C : ndarray, shape (N, >= m, D)
    query : callable
        Signed distance of robot-frame offsets, shape (..., D) -> (...), e.g. ``GridSDF.query``.

    Returns
    -------
    colpen : ndarray, shape (N, m)
    npen : ndarray, shape (N, m), int32
    """
    rel = P[:, None, :m, :] - C[:, :m, None, :]  # (N, i config, j point, D)
    s = query(rel) + tol
    pen = np.where(s < -PEN_EPS, s, 0.0)
    return pen.sum(axis=1), (s < -PEN_EPS).sum(axis=1).astype(np.int32)


set_threads(_default_threads())
