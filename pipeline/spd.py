"""Linear algebra on stacks of small symmetric positive-definite matrices (GM-PHD covariances, Gauss-Newton steps).

Batched over leading axes with numpy (no Python loop over the stack; the loops run over the matrix dimension D,
2 or 3 here). Used by :mod:`pipeline.track.gaussian_mixture` and :mod:`pipeline.estimators.plausible.cost`; never forms
an explicit inverse. Everything is written out
element-wise with sums in a fixed order, never through LAPACK/BLAS (``numpy.linalg``, ``@``), whose kernels and
so whose last bits change with the CPU (docs/evaluation.md, "Same numbers on every machine").
"""
from __future__ import annotations

import numpy as np

__all__ = ["symmetrise", "matmul", "cholesky", "largest_eigenvalue_bound", "solve_lower", "solve_upper_t",
           "cho_solve_matrix", "solve_spd"]


def symmetrise(a: np.ndarray) -> np.ndarray:
    """(A + A^T) / 2 over the last two axes."""
    return 0.5 * (a + np.swapaxes(a, -1, -2))


def matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Stacked matrix product (..., D, E) x (..., E, F) -> (..., D, F), broadcast over leading axes."""
    return np.sum(a[..., :, :, None] * b[..., None, :, :], axis=-2)


def cholesky(covs: np.ndarray) -> np.ndarray:
    """Lower Cholesky factors of a stack (..., D, D) of symmetric matrices (Cholesky-Banachiewicz over D).

    A pivot that round-off made non-positive is floored at 1e-12 times the matrix's largest diagonal entry (the
    matrix is then factored as if that much were added to its diagonal), so the factor is always finite.
    """
    a = symmetrise(np.asarray(covs, dtype=np.float64))
    d = a.shape[-1]
    floor = np.maximum(np.max(np.diagonal(a, axis1=-2, axis2=-1), axis=-1), np.finfo(float).tiny) * 1e-12
    chol = np.zeros_like(a)
    for i in range(d):
        for j in range(i + 1):
            acc = a[..., i, j] - (chol[..., i, :j] * chol[..., j, :j]).sum(-1)
            if i == j:
                chol[..., i, i] = np.sqrt(np.maximum(acc, floor))
            else:
                chol[..., i, j] = acc / chol[..., j, j]
    return chol


def largest_eigenvalue_bound(a: np.ndarray) -> np.ndarray:
    """An upper bound (...) of the largest eigenvalue of symmetric matrices (..., D, D): the largest absolute
    row sum (Gershgorin), exact for diagonal matrices."""
    return np.max(np.sum(np.abs(a), axis=-1), axis=-1)


def solve_lower(chol: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Forward substitution L y = b, broadcast over leading axes. chol (..., D, D), b (..., D) -> (..., D)."""
    d = chol.shape[-1]
    shape = np.broadcast_shapes(chol.shape[:-1], b.shape)
    y = np.empty(shape)
    for i in range(d):
        acc = b[..., i] - (chol[..., i, :i] * y[..., :i]).sum(-1)
        y[..., i] = acc / chol[..., i, i]
    return y


def solve_upper_t(chol: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Back substitution L^T x = b, broadcast over leading axes. chol (..., D, D), b (..., D) -> (..., D)."""
    d = chol.shape[-1]
    shape = np.broadcast_shapes(chol.shape[:-1], b.shape)
    x = np.empty(shape)
    for i in range(d - 1, -1, -1):
        acc = b[..., i] - (chol[..., i + 1:, i] * x[..., i + 1:]).sum(-1)
        x[..., i] = acc / chol[..., i, i]
    return x


def cho_solve_matrix(chol: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve (L L^T) X = B for a stack of matrices B. chol (J, D, D), rhs (J, D, n) -> (J, D, n)."""
    cols = np.swapaxes(rhs, -1, -2)  # (J, n, D): one right-hand side per row
    y = solve_lower(chol[:, None], cols)
    x = solve_upper_t(chol[:, None], y)
    return np.swapaxes(x, -1, -2)


def solve_spd(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve A x = b for a stack of symmetric positive-definite A (..., D, D) and b (..., D) -> (..., D)."""
    chol = cholesky(a)
    return solve_upper_t(chol, solve_lower(chol, b))
