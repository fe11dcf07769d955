"""Compiled cost terms of the plausible estimator: :func:`pipeline.estimators.plausible.cost.evaluate_terms` in one
pass.

The numpy form builds (hypotheses, points, 3, 3) temporaries for every term of every Levenberg-Marquardt iteration;
this kernel walks the points once per hypothesis and keeps only running sums. It computes the **same bits** as the
numpy form (tests/test_plausible_kernel.py), because it repeats numpy's arithmetic operation by operation:

* the element-wise expressions in the same order (no fused multiply-add: numba does not contract without
  ``fastmath``), the yaw's cosine and sine taken from numpy on the same array view as the numpy form;
* a cost, ``(B, P).sum(axis=1)`` over the contiguous last axis, with numpy's pairwise summation
  (:func:`pairwise_sum`: blocks of 8 partial sums up to 128 values, halves above);
* the normal matrix and gradient, ``np.sum(..., axis=1)`` over a non-last axis, as numpy does it: one running sum
  per entry, point after point.

It runs as plain Python with ``NUMBA_DISABLE_JIT=1`` with the same results (only slower). Measured in
docs/experiments/reproduce-time.md.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from pipeline.pairwise_sum import pairwise_sum

__all__ = ["pairwise_sum", "piece_terms", "piece_terms_each", "local_sdf", "first_of_cells", "warm_up", "CONTACT",
           "FREE"]

#: Kinds of a term (the ``kind`` argument of :func:`piece_terms`).
CONTACT, FREE = 0, 1


@njit(cache=True)
def local_sdf(cylinder, hx, hy, qx, qy):
    """Signed distance (m) of a point (qx, qy) in the primitive's frame and its gradient there, as
    :func:`pipeline.geometry.primitive_sdf` computes them (a cylinder's centre and a box's medial axis included)."""
    if cylinder:
        r = math.sqrt(qx * qx + qy * qy)
        if r > 1e-12:
            return r - hx, qx / r, qy / r
        return r - hx, 1.0, 0.0
    ax = abs(qx) - hx
    ay = abs(qy) - hy
    sx = 1.0 if qx >= 0.0 else -1.0
    sy = 1.0 if qy >= 0.0 else -1.0
    ox = max(ax, 0.0)
    oy = max(ay, 0.0)
    out = math.sqrt(ox * ox + oy * oy)
    first = not (ay > ax)  # np.argmax: the first of equal values
    sd = out + min(ax if first else ay, 0.0)
    if out > 0.0:
        return sd, ox * sx / out, oy * sy / out
    if first:
        return sd, sx, 0.0
    return sd, 0.0, sy


@njit(cache=True)
def piece_terms(cylinder, hx, hy, pose, cos_t, sin_t, pts, sigma, kind, half_c2, c2, tol, s0, inv_s0, weight_in,
                jacobian, cost, H, grad, scratch):
    """One term (contact points, or free-space / other-segment points) of B primitive poses, into ``cost`` (B,)
    (the plain sum over the points; the caller applies the term's factor), and with ``jacobian`` into ``H``
    (B, 3, 3) and ``grad`` (B, 3) (this term's sums only).

    Parameters
    ----------
    cylinder : bool
        The primitive is a cylinder of radius ``hx``; else a box of half sides (hx, hy), metres.
    pose : ndarray, shape (B, 3)
        Primitive poses (centre x, centre y, yaw); ``cos_t``, ``sin_t`` (B,) the cosines and sines of the yaws.
    pts : ndarray, shape (P, 2), metres
    sigma : ndarray, shape (P,), metres
        Contact sigmas (``kind == CONTACT`` only).
    kind : int
        CONTACT: Geman-McClure of sd / sigma with ``half_c2`` = c^2 / 2 and ``c2`` = c^2; FREE: squared depth
        min(sd + tol, 0) / s0 (``inv_s0`` = 1 / s0, the Jacobian's scale) with weight ``weight_in`` where it is
        below zero.
    scratch : ndarray, shape (P,)
        Work space for the per-point costs.
    """
    B = pose.shape[0]
    P = pts.shape[0]
    # A free-space point outside the primitive's circumscribed circle (plus a margin) is outside it, sd + tol > 0
    # for tol >= 0: its cost is +0.0 and its Jacobian terms +-0.0, which leave the running sums as they are
    # (skipped, as kernel.free_depth_sums of the pushtrack estimator skips them).
    skip = kind == FREE and tol >= 0.0
    r2 = (math.sqrt(hx * hx + hy * hy) + 1e-6) ** 2
    for b in range(B):
        c = cos_t[b]
        s = sin_t[b]
        px = pose[b, 0]
        py = pose[b, 1]
        h00 = h01 = h02 = h10 = h11 = h12 = h20 = h21 = h22 = 0.0
        g0 = g1 = g2 = 0.0
        # (a NaN or infinite yaw gives NaN terms at every point, as the array form does: nothing skipped then)
        turned = math.isfinite(c) and math.isfinite(s)
        for p in range(P):
            dx = pts[p, 0] - px
            dy = pts[p, 1] - py
            if skip and turned and r2 < dx * dx + dy * dy < math.inf:
                scratch[p] = 0.0
                continue
            sd, lx, ly = local_sdf(cylinder, hx, hy, c * dx + s * dy, -s * dx + c * dy)
            if kind == CONTACT:
                u = sd / sigma[p]
                scratch[p] = half_c2 * u * u / (c2 + u * u)
                v = c2 / (c2 + u * u)
                w = v * v
                resid = u
                scale = 1.0 / sigma[p]
            else:
                resid = min(sd + tol, 0.0) / s0
                scratch[p] = resid * resid
                w = weight_in if resid < 0.0 else 0.0
                scale = inv_s0
            if jacobian:
                gx = c * lx - s * ly
                gy = s * lx + c * ly
                j0 = -gx * scale
                j1 = -gy * scale
                j2 = (gx * dy - gy * dx) * scale
                w0 = j0 * w
                w1 = j1 * w
                w2 = j2 * w
                h00 += w0 * j0
                h01 += w0 * j1
                h02 += w0 * j2
                h10 += w1 * j0
                h11 += w1 * j1
                h12 += w1 * j2
                h20 += w2 * j0
                h21 += w2 * j1
                h22 += w2 * j2
                g0 += w0 * resid
                g1 += w1 * resid
                g2 += w2 * resid
        cost[b] = pairwise_sum(scratch, 0, P)
        if jacobian:
            H[b, 0, 0] = h00
            H[b, 0, 1] = h01
            H[b, 0, 2] = h02
            H[b, 1, 0] = h10
            H[b, 1, 1] = h11
            H[b, 1, 2] = h12
            H[b, 2, 0] = h20
            H[b, 2, 1] = h21
            H[b, 2, 2] = h22
            grad[b, 0] = g0
            grad[b, 1] = g1
            grad[b, 2] = g2


@njit(cache=True)
def piece_terms_each(cylinder, hx, hy, pose, cos_t, sin_t, pts, sigma, half_c2, c2, jacobian, cost, H, grad,
                       scratch):
    """The plausible estimator's contact term (Geman-McClure of sd / sigma) of B primitive poses, pose b with its
    own points ``pts[b]``: the plain sum over the points into ``cost`` (B,), and with ``jacobian`` its
    Gauss-Newton normal matrix into ``H`` (B, 3, 3) and gradient into ``grad`` (B, 3): the contact branch of
    :func:`piece_terms`, called once per pose (the pushtrack estimator's particles, each with the contacts it
    carried, :func:`pipeline.estimators.pushtrack.estimator.refine_final`).

    Parameters
    ----------
    pose : ndarray, shape (B, 3)
        Primitive poses (centre x, centre y, yaw); ``cos_t``, ``sin_t`` (B,) the cosines and sines of the yaws.
    pts : ndarray, shape (B, P, 2), metres
    sigma : ndarray, shape (P,), metres
    half_c2, c2 : float
        c^2 / 2 and c^2 for the outlier scale c in sigmas.
    scratch : ndarray, shape (P,)
    """
    for b in range(pose.shape[0]):
        piece_terms(cylinder, hx, hy, pose[b:b + 1], cos_t[b:b + 1], sin_t[b:b + 1], pts[b], sigma, CONTACT,
                    half_c2, c2, 0.0, 1.0, 1.0, 0.0, jacobian, cost[b:b + 1], H[b:b + 1], grad[b:b + 1], scratch)


@njit(cache=True)
def first_of_cells(cell, max_cells):
    """Indices (ascending) of the first of the points in each grid cell: ``cell`` (P, 2) int64 the points' cell
    indices, P >= 1. A flag per cell of the cells' bounding box replaces numpy's sort of the cells' keys (the
    same indices, in order); an empty result (shape (0,)) when that box has more than ``max_cells`` cells (the
    caller sorts then)."""
    P = cell.shape[0]
    x0 = x1 = cell[0, 0]
    y0 = y1 = cell[0, 1]
    for p in range(1, P):
        x0 = min(x0, cell[p, 0])
        x1 = max(x1, cell[p, 0])
        y0 = min(y0, cell[p, 1])
        y1 = max(y1, cell[p, 1])
    ny = y1 - y0 + 1
    if (x1 - x0 + 1) > max_cells // ny:
        return np.empty(0, np.int64)
    seen = np.zeros((x1 - x0 + 1) * ny, dtype=np.bool_)
    keep = np.empty(P, np.int64)
    k = 0
    for p in range(P):
        key = (cell[p, 0] - x0) * ny + (cell[p, 1] - y0)
        if not seen[key]:
            seen[key] = True
            keep[k] = p
            k += 1
    return keep[:k]


def warm_up() -> None:
    """Compile the kernels (once per machine: numba caches them on disk), as ``make setup`` does, so
    that no evaluation job pays for it."""
    pose = np.zeros((1, 3))
    pts = np.zeros((1, 2))
    out = np.empty(1), np.empty((1, 3, 3)), np.empty((1, 3))
    piece_terms(False, 0.1, 0.1, pose, np.ones(1), np.zeros(1), pts, np.ones(1), CONTACT, 4.5, 9.0, 0.0, 0.003,
                1.0 / 0.003, 1.0, True, *out, np.empty(1))
    piece_terms_each(False, 0.1, 0.1, pose, np.ones(1), np.zeros(1), pts[None], np.ones(1), 4.5, 9.0, True, *out,
                     np.empty(1))
    first_of_cells(np.zeros((1, 2), dtype=np.int64), 1)
