"""The plausible estimator's compiled cost terms (pipeline/estimators/plausible/kernel.py) give the numpy form's bits.

``refine`` runs on :func:`~pipeline.estimators.plausible.cost.compiled_terms`;
:func:`~pipeline.estimators.plausible.cost.evaluate_terms` is the numpy reference. Equality is exact
(``assert_array_equal``), not approximate: a last-bit difference in a cost could flip which hypothesis wins a near-tie
and so change a reported pose.
"""
from __future__ import annotations

import numpy as np
import pytest

from pipeline.estimators.plausible import cost as plausible
from pipeline.estimators.plausible import kernel as plausible_kernel
from pipeline.estimators.plausible.cost import compiled_terms, evaluate_terms
from pipeline.estimators.plausible.params import PlausibleParams
from pipeline.geometry import Primitive

BOX = Primitive(kind="box", half=(0.08, 0.11), centre=np.array([0.004, -0.002]), yaw=0.0, name="box")
CAN = Primitive(kind="cylinder", half=(0.034,), centre=np.array([0.011, 0.0]), yaw=0.0, name="can")


def _data(rng, n_points, n_free, n_others):
    pts = rng.normal(0.0, 0.1, (n_points, 2))
    sigma = 0.003 * 2.0 ** rng.integers(0, 4, n_points)
    free = rng.normal(0.0, 0.1, (n_free, 2))
    others = rng.normal(0.0, 0.1, (n_others, 2))
    return pts, sigma, free, others


def _assert_same(prim, pose, pts, sigma, free, others, params=PlausibleParams()):
    ref, H, g = evaluate_terms(prim, pose, pts, sigma, free, others, params, jacobian=True)
    got, H2, g2 = compiled_terms(prim, pose, pts, sigma, free, others, params, jacobian=True)
    for name in ("contact", "free", "others"):
        np.testing.assert_array_equal(getattr(got, name), getattr(ref, name), err_msg=name)
    np.testing.assert_array_equal(H2, H)
    np.testing.assert_array_equal(g2, g)
    plain = compiled_terms(prim, pose, pts, sigma, free, others, params)
    np.testing.assert_array_equal(plain.total, ref.total)


@pytest.mark.parametrize("prim", [BOX, CAN], ids=["box", "can"])
# point counts across numpy's pairwise-summation branches: < 8, one block of 8 partial sums, > 128 (halved)
@pytest.mark.parametrize("sizes", [(1, 0, 0), (7, 8, 0), (9, 129, 3), (40, 1000, 17), (300, 0, 130)])
def test_compiled_terms_are_the_numpy_terms_bit_for_bit(prim, sizes):
    rng = np.random.default_rng(sum(sizes))
    pts, sigma, free, others = _data(rng, *sizes)
    pose = np.column_stack([rng.normal(0, 0.05, (37, 2)), rng.uniform(-4.0, 4.0, 37)])
    _assert_same(prim, pose, pts, sigma, free, others)


def test_degenerate_points_the_subgradient_cases():
    """A can's centre (r = 0: the fixed gradient), a box's diagonal (|x| - hx = |y| - hy: the first axis wins, as
    np.argmax), points exactly on a face, and negative zeros."""
    pose = np.array([[0.0, 0.0, 0.0], [0.1, -0.2, np.pi / 2], [0.0, 0.0, -np.pi]])
    pts = np.array([[0.0, 0.0], [-0.0, 0.0], [0.08, 0.0], [0.0, -0.11], [0.03, 0.06], [-0.03, -0.06],
                    [0.12, 0.15], [0.1, -0.2], [0.034, 0.0]])
    sigma = np.full(len(pts), 0.003)
    for prim in (BOX, CAN):
        _assert_same(prim, pose, pts, sigma, pts, pts[::-1].copy())


def test_pairwise_sum_is_numpys_order():
    rng = np.random.default_rng(3)
    for n in [0, 1, 7, 8, 9, 15, 16, 127, 128, 129, 255, 256, 1000, 4097]:
        a = rng.standard_normal(n) * np.exp(rng.standard_normal(n) * 6)
        assert plausible_kernel.pairwise_sum(a, 0, n) == np.add.reduce(a), n


def test_plain_python_kernel_gives_the_compiled_bits(monkeypatch):
    """What NUMBA_DISABLE_JIT=1 runs (each kernel's py_func) gives the compiled results."""
    rng = np.random.default_rng(9)
    pts, sigma, free, others = _data(rng, 12, 20, 9)
    pose = np.column_stack([rng.normal(0, 0.05, (5, 2)), rng.uniform(-4.0, 4.0, 5)])
    params = PlausibleParams()
    compiled = [compiled_terms(prim, pose, pts, sigma, free, others, params, jacobian=True) for prim in (BOX, CAN)]
    monkeypatch.setattr(plausible_kernel, "pairwise_sum", plausible_kernel.pairwise_sum.py_func)
    monkeypatch.setattr(plausible_kernel, "local_sdf", plausible_kernel.local_sdf.py_func)
    monkeypatch.setattr(plausible, "piece_terms", plausible_kernel.piece_terms.py_func)
    for prim, (t, H, g) in zip((BOX, CAN), compiled):
        t2, H2, g2 = compiled_terms(prim, pose, pts, sigma, free, others, params, jacobian=True)
        np.testing.assert_array_equal(t2.total, t.total)
        np.testing.assert_array_equal(H2, H)
        np.testing.assert_array_equal(g2, g)


def test_free_space_cells_keep_the_first_point_of_each_cell_as_the_row_unique_did():
    """free_space_points deduplicates on one int64 key per cell: the same points, in the same order, as
    np.unique over the rows of cell indices (negative cells and a sweep crossing itself included)."""
    from pipeline.estimators.plausible.evidence import free_space_points, gripper_lattice
    from pipeline.robot import disc_sdf

    params = PlausibleParams()
    lattice = gripper_lattice(disc_sdf(0.03), params.free_resolution)
    start = np.array([[-0.2, -0.1], [-0.1, -0.1], [0.1, 0.05], [-0.05, -0.12]])
    end = np.array([[-0.1, -0.1], [0.1, 0.05], [-0.05, -0.12], [0.02, 0.2]])
    got = free_space_points(lattice, start, end, np.arange(4), 0, params, np.array([-0.01, 0.0]), 0.25)
    # the reference: every candidate point in order, the first of each cell kept
    later = np.arange(4) > 0
    n = np.maximum(1, np.ceil(np.linalg.norm(end[later] - start[later], axis=1) / params.sweep_spacing).astype(int))
    sweep = np.vstack([a + np.linspace(0.0, 1.0, k + 1)[:, None] * (b - a)
                       for a, b, k in zip(start[later], end[later], n)])
    poses = np.vstack([end[:1], sweep])
    pts = (poses[:, None, :] + lattice[None, :, :]).reshape(-1, 2)
    pts = pts[np.linalg.norm(pts - np.array([-0.01, 0.0]), axis=1) <= 0.25]
    _, first = np.unique(np.rint(pts / params.free_resolution).astype(np.int64), axis=0, return_index=True)
    expected = pts[np.sort(first)]
    assert len(expected) < len(pts)  # there were duplicates to remove
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("prim", [BOX, CAN], ids=["box", "can"])
def test_far_free_points_and_a_yaw_that_is_not_finite(prim):
    """Free-space points far outside the target are skipped by the kernel (their terms are +-0): the numpy form's
    bits all the same, and with a NaN or infinite yaw every term stays NaN, as there."""
    free = np.array([[5.0, 5.0], [-3.0, 0.5], [0.0, 0.0], [0.2, 0.0], [np.nan, 0.0], [np.inf, 1.0]])
    pose = np.array([[0.0, 0.0, 0.3], [0.0, 0.0, np.nan], [0.1, 0.0, np.inf], [np.nan, 0.0, 0.0]])
    pts = np.array([[0.08, 0.0], [0.0, 0.11]])
    _assert_same(prim, pose, pts, np.full(2, 0.003), free, np.zeros((0, 2)))


def test_first_per_cell_takes_non_finite_and_huge_points_the_sorting_way():
    from pipeline.estimators.plausible.evidence import first_per_cell
    pts = np.array([[0.0, 0.0], [0.004, 0.001], [0.01, 0.01], [0.0, 0.01], [0.01, 0.0], [0.011, 0.009]])
    np.testing.assert_array_equal(first_per_cell(pts, 0.01), pts[[0, 2, 3, 4]])
    for bad in ([np.nan, np.nan], [np.inf, 0.0], [1e300, -1e300]):
        odd = np.vstack([[bad], pts])
        with np.errstate(invalid="ignore"):
            cell = np.rint(odd / 0.01).astype(np.int64)  # the sorting form's keys (garbage in, the same garbage out)
            cell -= cell.min(axis=0)
            _, first = np.unique(cell[:, 0] * (int(cell[:, 1].max()) + 1) + cell[:, 1], return_index=True)
            np.testing.assert_array_equal(first_per_cell(odd, 0.01), odd[np.sort(first)])  # and no crash
