"""Arithmetic and choices with the same result on every x86-64 CPU: exp, log, log1p, atan2, logsumexp, argmin.

numpy picks its float64 ``exp``, ``log``, ``log1p``, ``arctan2`` (and others) at run time by the CPU's SIMD width:
an AVX-512 machine runs its own implementations (SVML, AVX512F), an AVX2 machine glibc's, and they differ in the
last bit (docs/evaluation.md, "Same numbers on every machine"). The functions here are numba ufuncs calling the C
library's scalar functions (glibc), whatever the CPU's vector width, so a decision or a stored value that depends
on them is the same on every machine running the locked environment. ``sin``, ``cos`` and ``sqrt`` need no
replacement (numpy's are correctly rounded or scalar on every dispatch level of the locked numpy), and neither do
``+ - * /``, comparisons and numpy's ``sum``/``cumsum`` (fixed summation order). Matrix products and
``numpy.linalg`` go through OpenBLAS/LAPACK, whose kernels also change by CPU: the pipeline writes its small
algebra out element-wise instead (:func:`pipeline.geometry.rotate`, the closed forms where it is needed).
"""
from __future__ import annotations

import math

import numpy as np
from numba import vectorize

__all__ = ["exp", "log", "log1p", "atan2", "logsumexp", "argmin_tolerant", "tie_key"]


@vectorize(["float64(float64)"], cache=True)
def exp(x):
    """e**x, element-wise (float64 ufunc)."""
    return math.exp(x)


@vectorize(["float64(float64)"], cache=True)
def log(x):
    """Natural logarithm, element-wise: -inf at 0 and nan below, like numpy (without its warnings)."""
    if x < 0.0:
        return math.nan
    if x == 0.0:
        return -math.inf
    return math.log(x)


@vectorize(["float64(float64)"], cache=True)
def log1p(x):
    """log(1 + x), element-wise: -inf at -1 and nan below."""
    if x < -1.0:
        return math.nan
    if x == -1.0:
        return -math.inf
    return math.log1p(x)


@vectorize(["float64(float64, float64)"], cache=True)
def atan2(y, x):
    """The angle (radians, in [-pi, pi]) of (x, y), element-wise (float64 ufunc, numpy's ``arctan2`` order)."""
    return math.atan2(y, x)


def logsumexp(a, axis=None):
    """log(sum(exp(a))) along ``axis`` (all elements when None), max-shifted; -inf for all -inf (or empty)
    input, never nan from -inf - -inf. The arithmetic of ``scipy.special.logsumexp`` with :func:`exp` and
    :func:`log`."""
    a = np.asarray(a, dtype=np.float64)
    if a.size == 0:
        return np.float64(-np.inf) if axis is None else np.full(np.delete(a.shape, axis), -np.inf)
    top = np.max(a, axis=axis, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    s = np.sum(exp(a - top), axis=axis, keepdims=True)
    out = log(s) + top
    return out.reshape(()) if axis is None else np.squeeze(out, axis=axis)


def argmin_tolerant(values, tol: float) -> int:
    """Index of the smallest of ``values`` (1-D), where values within ``tol`` of the smallest count as tied and
    the lowest index wins; nan never wins. -1 when every value is nan or inf (none is finite).

    A plain ``argmin`` between two costs a few ulps apart follows the last bits of the arithmetic, which change
    with the CPU; with ``tol`` far above those bits (and far below any difference that matters) the choice is
    the same on every machine, unless a cost lands within a few ulps of ``min + tol`` itself.
    """
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    finite = np.isfinite(v)
    if not finite.any():
        return -1
    best = np.min(v[finite])
    return int(np.flatnonzero(finite & (v <= best + tol))[0])


def tie_key(values, tol: float) -> np.ndarray:
    """Sort keys of ``values`` that make values in one bin of width ``tol`` equal (nan sorts last), for
    ``np.lexsort`` with an index as the last resort: the same order on every CPU unless a value lands within a
    few ulps of a bin edge (far rarer than two values a few ulps apart)."""
    v = np.asarray(values, dtype=np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        key = np.floor(v / tol)
    return np.where(np.isnan(key), np.inf, key)
