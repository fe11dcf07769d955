"""Compiled ICP iterations in SE(2), one restart at a time: the arithmetic of the batched numpy form, bit for bit.

The online estimator (docs/estimators.md, "Online, as the authors ran it") runs ICP from 30 restarts on a handful
of points at every in-contact step; written with numpy over the restarts, nearly all of its time went into
per-call overhead of small arrays. This kernel runs the same iterations per restart in compiled code and gives
the same bits, because it repeats numpy's order of every operation:

* a sum over the points of a (restarts, points) array is numpy's pairwise summation
  (:func:`pipeline.pairwise_sum.pairwise_sum`, eight accumulators per block of at most 128, halves above), started
  from 0.0 as numpy's ``add.reduce`` is;
* a sum over the points of a (restarts, points, k) array runs point by point from 0.0 (numpy's strided
  reduction);
* nearest model points by brute force (the model has ~50 points), distances sqrt(dx^2 + dy^2) as scipy's cKDTree
  computes them, the first of equidistant points (exact ties of distances do not occur on measured data);
* ``math.cos``/``math.sin``/``math.sqrt`` (what numpy's float64 loops call here) and ``math.atan2`` (as
  :func:`pipeline.portable.atan2`), no fastmath, so ``NUMBA_DISABLE_JIT=1`` gives the same bits
  (``tests/test_icp_kernel.py`` compares both with the numpy form).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from pipeline.pairwise_sum import pairwise_sum

__all__ = ["icp_kernel", "nearest_model", "clearance_kernel", "warm_up"]


@njit(cache=True)
def _npsum(a):
    """``numpy.sum`` of a contiguous 1-D float64 array (0.0 plus the pairwise sum)."""
    return 0.0 + pairwise_sum(a, 0, a.shape[0])


@njit(cache=True)
def _npmax(a, b):
    """``numpy.maximum`` of two floats (nan propagates)."""
    if a != a:
        return a
    if b != b:
        return b
    return a if a >= b else b


@njit(cache=True)
def _state(points, model, tx, ty, th, radius, moved, idx, matched, r2):
    """Move the points by (tx, ty, th), find their nearest model points; fills ``moved``, ``idx``, ``matched``
    and returns (fitness, inlier RMSE, any matched) as ``_fit_stats`` computes them."""
    c, s = math.cos(th), math.sin(th)
    M, N = points.shape[0], model.shape[0]
    n = 0
    for m in range(M):
        x, y = points[m, 0], points[m, 1]
        mx = (c * x - s * y) + tx
        my = (s * x + c * y) + ty
        moved[m, 0], moved[m, 1] = mx, my
        best, k = math.inf, N - 1
        for j in range(N):
            dx, dy = mx - model[j, 0], my - model[j, 1]
            d2 = dx * dx + dy * dy
            if d2 < best:
                best, k = d2, j
        idx[m] = k
        ok = math.sqrt(best) <= radius
        matched[m] = ok
        if ok:
            n += 1
            ex, ey = mx - model[k, 0], my - model[k, 1]
            r2[m] = ex * ex + ey * ey
        else:
            r2[m] = 0.0
    fit = n / M
    rmse = math.sqrt(_npsum(r2) / max(n, 1))
    return fit, rmse, n > 0


@njit(cache=True)
def _point_to_point(points, model, idx, matched, w, tmp):
    """The closed-form rigid transform (tx, ty, theta) of the matched pairs (``_point_to_point`` of icp.py)."""
    M = points.shape[0]
    for m in range(M):
        w[m] = 1.0 if matched[m] else 0.0
    n = _npmax(_npsum(w), 1.0)
    px = py = qx = qy = 0.0
    for m in range(M):
        px += w[m] * points[m, 0]
        py += w[m] * points[m, 1]
    for m in range(M):
        qx += w[m] * model[idx[m], 0]
        qy += w[m] * model[idx[m], 1]
    px, py, qx, qy = px / n, py / n, qx / n, qy / n
    for m in range(M):
        p0, p1 = points[m, 0] - px, points[m, 1] - py
        q0, q1 = model[idx[m], 0] - qx, model[idx[m], 1] - qy
        tmp[m] = w[m] * (p0 * q1 - p1 * q0)
    cross = _npsum(tmp)
    for m in range(M):
        p0, p1 = points[m, 0] - px, points[m, 1] - py
        q0, q1 = model[idx[m], 0] - qx, model[idx[m], 1] - qy
        tmp[m] = w[m] * (p0 * q0 + p1 * q1)
    dot = _npsum(tmp)
    theta = math.atan2(cross, dot)
    c, s = math.cos(theta), math.sin(theta)
    return qx - (c * px - s * py), qy - (s * px + c * py), theta


@njit(cache=True)
def _point_to_plane(moved, model, normals, idx, matched, tx, ty, th):
    """One linearised point-to-plane step composed with (tx, ty, th) (``_point_to_plane_step`` then
    ``_compose`` of icp.py, with :func:`pipeline.spd.solve_spd`'s Cholesky solve of the 3x3 system)."""
    H = np.zeros((3, 3))
    g = np.zeros(3)
    J = np.empty(3)
    for m in range(moved.shape[0]):
        w = 1.0 if matched[m] else 0.0
        k = idx[m]
        nx, ny = normals[k, 0], normals[k, 1]
        r = (moved[m, 0] - model[k, 0]) * nx + (moved[m, 1] - model[k, 1]) * ny
        J[0], J[1], J[2] = nx, ny, moved[m, 0] * ny - moved[m, 1] * nx
        for i in range(3):
            wj = J[i] * w
            for j in range(3):
                H[i, j] += wj * J[j]
            g[i] += wj * r
    for i in range(3):
        H[i, i] += 1e-12
    for i in range(3):
        for j in range(3):
            if i != j:
                H[i, j] += 0.0
    a = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            a[i, j] = 0.5 * (H[i, j] + H[j, i])
    top = _npmax(_npmax(a[0, 0], a[1, 1]), a[2, 2])
    floor = _npmax(top, 2.2250738585072014e-308) * 1e-12
    L = np.zeros((3, 3))
    for i in range(3):
        for j in range(i + 1):
            s = 0.0
            for k in range(j):
                s += L[i, k] * L[j, k]
            acc = a[i, j] - s
            if i == j:
                L[i, i] = math.sqrt(_npmax(acc, floor))
            else:
                L[i, j] = acc / L[j, j]
    y = np.empty(3)
    for i in range(3):
        s = 0.0
        for k in range(i):
            s += L[i, k] * y[k]
        y[i] = (g[i] - s) / L[i, i]
    x = np.empty(3)
    for i in range(2, -1, -1):
        s = 0.0
        for k in range(i + 1, 3):
            s += L[k, i] * x[k]
        x[i] = (y[i] - s) / L[i, i]
    dx, dy, dth = -x[0], -x[1], -x[2]
    c, s_ = math.cos(dth), math.sin(dth)
    return (c * tx - s_ * ty) + dx, (s_ * tx + c * ty) + dy, th + dth


@njit(cache=True)
def icp_kernel(points, model, normals, inits, radius, max_iteration, plane):
    """ICP iterations (``_icp`` of :mod:`pipeline.estimators.paper.icp`) from each initial transform.

    Parameters
    ----------
    points : ndarray, shape (M, 2), float64, C-contiguous
    model : ndarray, shape (N, 2), float64
    normals : ndarray, shape (N, 2), float64
        Model normals (used only with ``plane``).
    inits : ndarray, shape (B, 3)
        Initial world -> model transforms (tx, ty, theta).
    radius : float, metres
        Correspondence radius.
    max_iteration : int
    plane : bool
        Point-to-plane steps instead of point-to-point.

    Returns
    -------
    ndarray, shape (B, 3)
        The final transforms; each restart stops when its fitness and inlier RMSE change by < 1e-9.
    """
    M = points.shape[0]
    out = np.empty((inits.shape[0], 3))
    moved = np.empty((M, 2))
    idx = np.empty(M, dtype=np.int64)
    matched = np.empty(M, dtype=np.bool_)
    r2 = np.empty(M)
    w = np.empty(M)
    tmp = np.empty(M)
    for b in range(inits.shape[0]):
        tx, ty, th = inits[b, 0], inits[b, 1], inits[b, 2]
        fit, rmse, anym = _state(points, model, tx, ty, th, radius, moved, idx, matched, r2)
        for _ in range(max_iteration):
            # A restart without any correspondence does not move (Open3D's update is then the identity).
            if anym:
                if plane:
                    tx, ty, th = _point_to_plane(moved, model, normals, idx, matched, tx, ty, th)
                else:
                    tx, ty, th = _point_to_point(points, model, idx, matched, w, tmp)
            fit2, rmse2, anym = _state(points, model, tx, ty, th, radius, moved, idx, matched, r2)
            done = abs(fit2 - fit) < 1e-9 and abs(rmse2 - rmse) < 1e-9
            fit, rmse = fit2, rmse2
            if done:
                break
        out[b, 0], out[b, 1], out[b, 2] = tx, ty, th
    return out


@njit(cache=True)
def nearest_model(moved, model):
    """Nearest model point (N, 2) of every point of ``moved`` (B, M, 2): index (B, M) and squared distance
    dx^2 + dy^2 (B, M), the first of equal distances (``numpy.argmin`` of the summed squares; a nan distance
    wins, as in ``argmin``)."""
    B, M, N = moved.shape[0], moved.shape[1], model.shape[0]
    idx = np.zeros((B, M), dtype=np.int64)
    dist2 = np.empty((B, M))
    for b in range(B):
        for m in range(M):
            best, k = math.inf, 0
            for j in range(N):
                dx, dy = moved[b, m, 0] - model[j, 0], moved[b, m, 1] - model[j, 1]
                d2 = dx * dx + dy * dy
                if j == 0 or d2 < best or d2 != d2:
                    best, k = d2, j
                    if d2 != d2:
                        break
            idx[b, m], dist2[b, m] = k, best
    return idx, dist2


@njit(cache=True)
def clearance_kernel(world, ee, near, values, shape, strides, origin, resolution, outside):
    """Smallest grid value over the posed model points ``world`` (B, N, 2) against the gripper positions ``ee``
    (K, 2) of the pairs (b, k) with ``near[b, k]`` (the rest give ``outside``), the nearest-cell lookup of
    :meth:`pipeline.robot.GridSDF.query` (``rint((q - origin) / resolution)``, ``outside`` off the grid);
    returns (B,) (``min_clearance`` of :mod:`pipeline.estimators.paper.choice`)."""
    B, N, D = world.shape[0], world.shape[1], world.shape[2]
    out = np.full(B, outside)
    for b in range(B):
        cur = out[b]
        for k in range(ee.shape[0]):
            if not near[b, k]:
                continue
            for n in range(N):
                flat, inside = 0, True
                for d in range(D):
                    i = np.rint(((world[b, n, d] - ee[k, d]) - origin[d]) / resolution)
                    # Written as a positive test so that nan lands outside, as in GridSDF.query.
                    if not (i >= 0.0 and i <= shape[d] - 1.0):
                        inside = False
                        break
                    flat += int(i) * strides[d]
                v = values[flat] if inside else outside
                if v < cur or v != v:
                    cur = v
                if cur != cur:
                    break
        out[b] = cur
    return out


def warm_up() -> None:
    """Compile (or load from numba's on-disk cache) every kernel here on a tiny input: ``make setup`` calls it
    once per machine, so the first retrieval of a clean checkout does not compile (docs/estimators.md)."""
    model = np.array([[0.0, 0.0], [0.1, 0.0], [0.0, 0.1]])
    pts = model[:2] + 0.01
    inits = np.zeros((2, 3))
    for plane in (False, True):
        icp_kernel(pts, model, model, inits, 1.0, 2, plane)
    nearest_model(pts[None], model)
    values = np.zeros(4)
    values.setflags(write=False)  # as GridSDF.kernel_arrays gives it (a read-only array is its own numba type)
    clearance_kernel(model[None], pts, np.ones((1, 2), dtype=np.bool_), values, np.array([2, 2]),
                     np.array([2, 1]), np.zeros(2), 0.1, 1.0)
