"""Linear algebra on stacks of small symmetric positive-definite matrices (the GM-PHD filter's covariances).

Batched over leading axes with numpy (no Python loop over the stack; the loops run over the matrix dimension D,
2 here). Used by :mod:`pipeline.track.gmphd`; never forms an explicit inverse.
"""
from __future__ import annotations

import numpy as np

__all__ = ["symmetrise", "cholesky", "solve_lower", "solve_upper_t", "cho_solve_matrix"]


def symmetrise(a: np.ndarray) -> np.ndarray:
    """(A + A^T) / 2 over the last two axes."""
    return 0.5 * (a + np.swapaxes(a, -1, -2))


def cholesky(covs: np.ndarray) -> np.ndarray:
    """Lower Cholesky factors of a stack (..., D, D) of symmetric matrices, flooring eigenvalues if needed.

    numpy's batched Cholesky is used because scipy's batched ``cholesky``/``solve_triangular`` loop over the stack
    in Python-level calls.
    """
    covs = symmetrise(covs)
    try:
        return np.linalg.cholesky(covs)
    except np.linalg.LinAlgError:
        # Round-off made some matrix indefinite: floor its spectrum relative to its largest eigenvalue.
        vals, vecs = np.linalg.eigh(covs)
        top = np.maximum(vals[..., -1:], np.finfo(float).tiny)
        vals = np.maximum(vals, top * 1e-12)
        fixed = symmetrise((vecs * vals[..., None, :]) @ np.swapaxes(vecs, -1, -2))
        return np.linalg.cholesky(fixed)


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
