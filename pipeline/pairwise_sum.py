"""numpy's pairwise summation as a numba kernel, for compiled code that must give numpy's bits.

``np.add.reduce`` over a contiguous float64 axis sums blocks of at most 128 values with eight partial sums (combined as
a tree, then the tail) and splits longer runs into two halves, the first a multiple of 8. The compiled kernels of the
estimators (:mod:`pipeline.estimators.plausible.kernel`, :mod:`pipeline.estimators.paper.icp_kernel`) repeat that order
so that they compute the same bits as the numpy forms they replace (docs/evaluation.md, "Same numbers on every
machine"); ``NUMBA_DISABLE_JIT=1`` runs the same arithmetic in Python.
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["pairwise_sum"]


@njit(cache=True)
def _block_sum(a, lo, n):
    """numpy's pairwise sum of a[lo:lo + n] for n <= 128: 8 partial sums, combined as a tree, then the tail."""
    if n < 8:
        res = -0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    stop = n - n % 8
    while i < stop:
        k = lo + i
        r0 += a[k]
        r1 += a[k + 1]
        r2 += a[k + 2]
        r3 += a[k + 3]
        r4 += a[k + 4]
        r5 += a[k + 5]
        r6 += a[k + 6]
        r7 += a[k + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(cache=True)
def _left_half(n):
    """Length of the first half numpy splits a sum of n > 128 values into (a multiple of 8)."""
    n2 = n // 2
    return n2 - n2 % 8


@njit(cache=True)
def _stack_sum(a, lo, n):
    """:func:`pairwise_sum` of any length, the tree walked with an explicit stack of halves (it allocates its
    stack: used beyond the sizes the per-depth functions cover)."""
    if n <= 128:
        return _block_sum(a, lo, n)
    los = np.empty(64, np.int64)
    ns = np.empty(64, np.int64)
    stage = np.zeros(64, np.int64)  # 0: not split yet, 1: summing the left half, 2: the right half
    left = np.empty(64)
    top = 0
    los[0] = lo
    ns[0] = n
    val = 0.0
    have = False  # val holds the sum of the half that just finished
    while True:
        if have:
            if top < 0:
                return val
            if stage[top] == 1:
                left[top] = val
                stage[top] = 2
                n2 = _left_half(ns[top])
                top += 1
                los[top] = los[top - 1] + n2
                ns[top] = ns[top - 1] - n2
                stage[top] = 0
                have = False
            else:
                val = left[top] + val
                top -= 1
            continue
        m = ns[top]
        if m <= 128:
            val = _block_sum(a, los[top], m)
            top -= 1
            have = True
        else:
            stage[top] = 1
            top += 1
            los[top] = los[top - 1]
            ns[top] = _left_half(m)
            stage[top] = 0


# numpy recurses, but a recursive function in numba's on-disk cache crashed the process: each depth of the tree has
# a function of its own instead, so sums of up to 7688 values allocate nothing. _pw{k} sums at most
# _PW_SIZES[k] values (the halves of n values are at most n / 2 + 8 long).
_PW_SIZES = (128, 248, 488, 968, 1928, 3848, 7688)


@njit(cache=True)
def _pw1(a, lo, n):
    if n <= 128:
        return _block_sum(a, lo, n)
    half = _left_half(n)
    return _block_sum(a, lo, half) + _block_sum(a, lo + half, n - half)


@njit(cache=True)
def _pw2(a, lo, n):
    if n <= 128:
        return _block_sum(a, lo, n)
    half = _left_half(n)
    return _pw1(a, lo, half) + _pw1(a, lo + half, n - half)


@njit(cache=True)
def _pw3(a, lo, n):
    if n <= 128:
        return _block_sum(a, lo, n)
    half = _left_half(n)
    return _pw2(a, lo, half) + _pw2(a, lo + half, n - half)


@njit(cache=True)
def _pw4(a, lo, n):
    if n <= 128:
        return _block_sum(a, lo, n)
    half = _left_half(n)
    return _pw3(a, lo, half) + _pw3(a, lo + half, n - half)


@njit(cache=True)
def _pw5(a, lo, n):
    if n <= 128:
        return _block_sum(a, lo, n)
    half = _left_half(n)
    return _pw4(a, lo, half) + _pw4(a, lo + half, n - half)


@njit(cache=True)
def _pw6(a, lo, n):
    if n <= 128:
        return _block_sum(a, lo, n)
    half = _left_half(n)
    return _pw5(a, lo, half) + _pw5(a, lo + half, n - half)


@njit(cache=True)
def pairwise_sum(a, lo, n):
    """Sum of ``a[lo:lo + n]`` (a contiguous float64 vector) in numpy's pairwise order (``np.add.reduce`` over a
    contiguous axis): blocks of at most 128 values (:func:`_block_sum`), halves summed above."""
    if n <= _PW_SIZES[1]:
        return _pw1(a, lo, n)
    if n <= _PW_SIZES[3]:
        return _pw3(a, lo, n)
    if n <= _PW_SIZES[6]:
        return _pw6(a, lo, n)
    return _stack_sum(a, lo, n)
