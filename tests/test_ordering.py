"""The soft tracker's ordering helpers (pipeline/track/ordering.py) decide which pairs are evaluated and in what
order, never a value: each must give exactly what the plain computation it replaces gives."""
from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

from pipeline.track import ordering


def test_exp_table_decides_every_draw_as_exp_does():
    rng = np.random.default_rng(0)
    t = -rng.exponential(3.0, 20_000)
    u = rng.random(20_000)
    # hard cases: u exactly at exp(t) and one ulp either side, t on the table's grid, t = 0 and beyond its span
    grid_t = -np.arange(0, ordering.EXP_STEPS * 3) / ordering.EXP_STEPS
    edge_t = np.concatenate([grid_t, [0.0, -0.0, -ordering.EXP_SPAN - 1.0, -745.0, -800.0]])
    e = np.array([math.exp(x) for x in edge_t])
    t = np.concatenate([t, edge_t, edge_t, edge_t])
    u = np.concatenate([u, e, np.nextafter(e, 0.0), np.nextafter(e, 1.0)])
    got = [ordering.below_exp(a, b) for a, b in zip(u, t)]
    assert got == [a < math.exp(b) for a, b in zip(u, t)]


@pytest.mark.parametrize("n", [0, 1, 2, 7, 64, 200])
def test_bisections_equal_searchsorted(n):
    rng = np.random.default_rng(n)
    xs = np.sort(rng.integers(0, 20, n).astype(float))  # many ties
    for v in np.concatenate([xs, xs + 0.5, [-1.0, 25.0]]):
        for start, stop in ((0, n), (n // 3, n - n // 4)):
            want = start + np.searchsorted(xs[start:stop], v)
            assert ordering.first_at_least(xs, start, stop, v) == want
            assert ordering.first_above(xs, start, stop, v) == start + np.searchsorted(xs[start:stop], v,
                                                                                          side="right")


def test_take_rows_in_place_equals_a_gather():
    rng = np.random.default_rng(3)
    n, cap, m = 9, 6, 4
    arrays = [rng.random((n, cap, 2)), rng.random((n, cap, 2)), rng.random((n, cap)),
              rng.integers(0, 5, (n, cap)).astype(np.int32), rng.integers(0, m, (n, cap)).astype(np.int32)]
    for ancestors in (np.array([0, 0, 0, 3, 3, 5, 8, 8, 8]), np.array([4] * 9), np.arange(9),
                      np.array([1, 2, 3, 4, 5, 6, 7, 8, 8]), np.array([0, 0, 1, 2, 3, 4, 5, 6, 7])):
        before = [a.copy() for a in arrays]
        ordering.take_rows(ancestors.astype(np.int64), m, *arrays)
        for a, b in zip(arrays, before):
            np.testing.assert_array_equal(a[:, :m], b[ancestors, :m])
            np.testing.assert_array_equal(a[:, m:], b[:, m:])  # slots past m untouched


@pytest.mark.parametrize("seed", range(6))
def test_groups_visit_configs_in_the_order_of_the_argsort_they_replace(seed):
    # coarse integer coordinates: many ties on x, some between copies (same config), some not
    rng = np.random.default_rng(seed)
    m, K = 40, 2
    base = rng.integers(0, 6, (m, 2)).astype(float)
    copies = rng.integers(0, m, m // 2)
    P = base.copy()
    C = base + rng.integers(0, 3, (m, 2))
    P[m // 2:], C[m // 2:] = P[copies], C[copies]  # exact copies, as resampling and Alg. 2 make
    P, C = P[None], C[None]
    group = rng.integers(0, K + 1, m)
    # the kept order: sorted by x, ties in an arbitrary order (not argsort's)
    order = np.lexsort((rng.random(m), P[0, :, 0])).astype(np.int32)[None]
    counts, gorder, xs, ys, dup = ordering.groups_by_first_coordinate(P, C, 0, group, order, m, K)
    for a in range(K + 1):
        seg = np.flatnonzero(group == a)
        want = seg[_numba_argsort(P[0, seg, 0])]  # what the kernels did before (numba's quicksort, its own ties)
        got = gorder[counts[a]:counts[a + 1]]
        np.testing.assert_array_equal(xs[counts[a]:counts[a + 1]], P[0, want, 0])
        np.testing.assert_array_equal(ys[counts[a]:counts[a + 1]], P[0, got, 1])
        # the configs come in exactly the same sequence (a tie between equal configs may be in either order)
        np.testing.assert_array_equal(C[0, got], C[0, want])
        np.testing.assert_array_equal(dup[counts[a] + 1:counts[a + 1]], np.all(P[0, got[1:]] == P[0, got[:-1]], axis=1))


@njit
def _numba_argsort(keys):
    return np.argsort(keys)


def test_take_rows_refuses_unsorted_ancestors_before_copying():
    P = np.arange(12.0).reshape(3, 2, 2)
    arrays = [P, P.copy(), np.zeros((3, 2)), np.zeros((3, 2), np.int32), np.zeros((3, 2), np.int32)]
    with pytest.raises(ValueError, match="sorted"):
        ordering.take_rows(np.array([2, 0, 1]), 2, *arrays)
    np.testing.assert_array_equal(P, np.arange(12.0).reshape(3, 2, 2))
