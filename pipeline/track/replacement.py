"""Alg. 2 of the soft tracker (ReplaceInconsistentPoints, paper §IV-B) as a compiled kernel on whole particle
arrays, with the penetration bookkeeping of :mod:`pipeline.track.kernels` (``colpen``, ``npen``, ``order``; see
there for their shapes and units) kept exact.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from pipeline.track.kernels import contribution
from pipeline.track.ordering import reinsert


@njit(cache=True)
def _config_terms(P, C, n, configs, skip, m, sign, colpen, npen, zero, values, shape, strides, origin, inv_res,
                  lo, hi, tol):
    """Add (sign=+1) or remove (sign=-1) the terms of the given configs of particle n to the sums of every point
    j < m not flagged in ``skip``."""
    for b in range(configs.size):
        i = configs[b]
        for j in range(m):
            if skip[j]:
                continue
            c = contribution(P, C, n, j, i, zero, 0, 0, values, shape, strides, origin, inv_res, lo, hi, tol)
            if c < 0.0:
                colpen[n, j] += sign * c
                npen[n, j] += sign
                if npen[n, j] == 0:
                    colpen[n, j] = 0.0


@njit(cache=True, parallel=True)
def replace_inconsistent(P, C, order, rows, m, colpen, npen, values, shape, strides, origin, inv_res, lo, hi, tol):
    """Alg. 2 on the particles ``rows``: each inconsistent point (and its config) becomes a copy of the nearest
    consistent point of the same particle. A point is inconsistent when it penetrates at least one of its
    particle's configs deeper than the tolerance (``npen > 0``). Particles whose points are all consistent or
    all inconsistent are left alone. Updates ``colpen``/``npen`` exactly.

    ``order`` (N, capacity): each particle's points by first coordinate, kept up to date (see
    :func:`predict_and_update`). ``rows`` (R,) int64: the particles to process (the others are left alone).

    Returns
    -------
    n_replaced : ndarray, shape (N,), int64
        Points replaced in each particle (0 outside ``rows``).
    """
    N = P.shape[0]
    D = P.shape[2]
    zero = np.zeros((1, D))
    n_replaced = np.zeros(N, np.int64)
    for r in prange(rows.size):
        n = rows[r]
        n_bad = 0
        for j in range(m):
            if npen[n, j] > 0:
                n_bad += 1
        if n_bad == 0 or n_bad == m:
            continue
        bad = np.empty(n_bad, np.int64)
        is_bad = np.zeros(m, np.bool_)
        b = 0
        for j in range(m):
            if npen[n, j] > 0:
                bad[b] = j
                is_bad[j] = True
                b += 1
        # nearest consistent point of each inconsistent one (positions before any replacement)
        source = np.empty(n_bad, np.int64)
        for b in range(n_bad):
            j = bad[b]
            best = -1
            best_d2 = np.inf
            for k in range(m):
                if is_bad[k]:
                    continue
                d2 = 0.0
                for d in range(D):
                    t = P[n, k, d] - P[n, j, d]
                    d2 += t * t
                if d2 < best_d2:
                    best_d2 = d2
                    best = k
            source[b] = best
        # remove the old terms of configs being replaced from the consistent points' sums
        _config_terms(P, C, n, bad, is_bad, m, -1, colpen, npen, zero, values, shape, strides, origin, inv_res,
                      lo, hi, tol)
        for b in range(n_bad):
            j = bad[b]
            k = source[b]
            for d in range(D):
                P[n, j, d] = P[n, k, d]
                C[n, j, d] = C[n, k, d]
        # add the new configs' terms to the consistent points, and recompute the replaced points fully
        _config_terms(P, C, n, bad, is_bad, m, 1, colpen, npen, zero, values, shape, strides, origin, inv_res,
                      lo, hi, tol)
        for b in range(n_bad):
            j = bad[b]
            acc = 0.0
            cnt = 0
            for i in range(m):
                c = contribution(P, C, n, j, i, zero, 0, 0, values, shape, strides, origin, inv_res, lo, hi, tol)
                if c < 0.0:
                    acc += c
                    cnt += 1
            colpen[n, j] = acc
            npen[n, j] = cnt
        reinsert(P, n, order, m, is_bad, bad)
        n_replaced[n] = n_bad
    return n_replaced
