"""Isolation surface points: candidate contact points on the robot's surface and their outward normals.

Computed on the robot's grid SDF (:class:`pipeline.robot.grid.GridSDF`), the same grid the tracker uses as pxpen,
so isolation and tracking agree on where the surface is (docs/simulation.md, "`stucco isolate`"). Units are
metres.
"""
from __future__ import annotations

import numpy as np

from pipeline.robot.grid import GridSDF

__all__ = ["surface_points"]


# Cells of linear extrapolation added around the grid for surface work: the pybullet margin puts the surface up
# to 1 mm beyond the mesh-bounded grid (the authors' isolation points reach y = -0.105 m while the grid stops at
# -0.104 m; docs/simulation.md, "The gripper's signed distance grid").
_SURFACE_PAD = 4


def _padded(sdf: GridSDF, pad: int = _SURFACE_PAD) -> tuple[np.ndarray, np.ndarray]:
    """Grid values extended by ``pad`` cells of linear extrapolation on every side.

    Returns
    -------
    values : ndarray, shape (n_0 + 2 pad, ..., n_{D-1} + 2 pad), metres
    origin : ndarray, shape (D,), metres
    """
    v = np.array(sdf.values)
    for axis in range(v.ndim):
        # A single-cell axis has no slope: extend it with constants.
        inner = 1 if v.shape[axis] > 1 else 0
        first = np.take(v, [0], axis=axis)
        second = np.take(v, [inner], axis=axis)
        last = np.take(v, [-1], axis=axis)
        before = np.take(v, [-1 - inner], axis=axis)
        k = np.arange(1, pad + 1).reshape([-1 if a == axis else 1 for a in range(v.ndim)])
        lo_part = np.flip(first + k * (first - second), axis=axis)
        hi_part = last + k * (last - before)
        v = np.concatenate([lo_part, v, hi_part], axis=axis)
    return v, sdf.origin - pad * sdf.resolution


def _bilinear(sdf: GridSDF, pad: int = _SURFACE_PAD):
    """Piecewise-(bi)linear interpolant of the padded grid, itself linearly extrapolated beyond the padding.

    Returns
    -------
    callable
        ``f(q (..., D)) -> (...)`` signed distance in metres.
    """
    # Imported here, not at the top: scipy.interpolate takes 0.17 s to import (measured, -X importtime) and only
    # isolation needs it, while every tracker process imports this package.
    from scipy.interpolate import RegularGridInterpolator

    values, origin = _padded(sdf, pad)
    axes = tuple(origin[k] + sdf.resolution * np.arange(n) for k, n in enumerate(values.shape))
    return RegularGridInterpolator(axes, values, method="linear", bounds_error=False, fill_value=None)


def _zero_crossings_2d(values: np.ndarray, origin: np.ndarray, resolution: float) -> np.ndarray:
    """Points where the piecewise-linear grid function crosses zero along grid edges.

    Returns
    -------
    ndarray, shape (C, 2), metres
        At most one cell apart along the zero level set, so the nearest one to a query is within about half a
        cell (along the curve) of the true closest surface point.
    """
    out = []
    for axis in (0, 1):
        a = values[:-1, :] if axis == 0 else values[:, :-1]
        b = values[1:, :] if axis == 0 else values[:, 1:]
        hit = (a < 0) != (b < 0)
        i, j = np.nonzero(hit)
        t = a[hit] / (a[hit] - b[hit])  # a and b differ in sign, so the denominator is non-zero
        idx = np.stack([i, j], axis=-1).astype(np.float64)
        idx[:, axis] += t
        out.append(origin + resolution * idx)
    return np.concatenate(out, axis=0)


def surface_points(
    sdf: GridSDF,
    n_query: int = 100,
    radius: float = 0.115,
    min_separation: float = 0.005,
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate contact points on the robot's surface and their outward normals, for isolation.

    The isolation of docs/simulation.md ("`stucco isolate`") picks the contact among these points.

    ``n_query`` points on a circle of ``radius`` around the robot origin, at angles ``linspace(0.01,
    2 pi - 0.01, n_query)``, are each projected onto the closest point of the zero level set of the grid SDF,
    as the authors' ``getClosestPoints`` does: first the nearest zero crossing along the grid edges, then a few
    Newton steps ``q <- q - f(q) g / |g|^2`` on the bilinear interpolant ``f`` (``g`` its central-difference
    gradient, step one cell) to land on the level set. Starting Newton from the circle itself is unreliable: the
    circle lies outside the grid, where the extrapolated bilinear cross term bends the steps and bunches the
    points. The grid is linearly extrapolated by a few cells so surface beyond the grid bounds (the collision
    margin) is found. Points within ``min_separation`` of an already kept point are dropped, in angle order.

    Parameters
    ----------
    sdf : GridSDF
        A 2-D robot grid.
    n_query : int
        Number of query points on the circle.
    radius : float, metres
        Query circle radius; should enclose the robot.
    min_separation : float, metres
        Minimum distance between kept points.

    Returns
    -------
    points : ndarray, shape (P, 2), metres, robot frame
        Surface points, ``|f| < 1e-6`` m on the interpolant.
    normals : ndarray, shape (P, 2)
        Outward unit normals (normalised SDF gradient).
    """
    if sdf.ndim != 2:
        raise ValueError(f"surface_points: needs a 2-D grid, got {sdf.ndim}-D")
    values, origin = _padded(sdf)
    crossings = _zero_crossings_2d(values, origin, sdf.resolution)
    if len(crossings) == 0:
        return np.empty((0, 2)), np.empty((0, 2))
    interp = _bilinear(sdf)
    h = sdf.resolution

    def grad(q: np.ndarray) -> np.ndarray:
        ex = np.array([h, 0.0])
        ey = np.array([0.0, h])
        gx = (interp(q + ex) - interp(q - ex)) / (2 * h)
        gy = (interp(q + ey) - interp(q - ey)) / (2 * h)
        return np.stack([gx, gy], axis=-1)

    angles = np.linspace(0.01, 2 * np.pi - 0.01, n_query)
    circle = radius * np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    d2 = np.sum((circle[:, None, :] - crossings[None, :, :]) ** 2, axis=-1)  # (n_query, C): small
    q = crossings[np.argmin(d2, axis=1)]
    for _ in range(10):
        f = interp(q)
        if np.all(np.abs(f) < 1e-9):
            break
        g = grad(q)
        g2 = np.sum(g * g, axis=-1)
        ok = g2 > 1e-8  # flat spots (medial axis) would send the step to infinity
        step = np.where(ok, f / np.where(ok, g2, 1.0), 0.0)
        q = q - step[:, None] * g
    f = interp(q)
    g = grad(q)
    gn = np.linalg.norm(g, axis=-1)
    good = (np.abs(f) < 1e-6) & (gn > 1e-4)

    kept: list[int] = []
    for i in np.flatnonzero(good):
        if all(np.hypot(*(q[i] - q[j])) >= min_separation for j in kept):
            kept.append(int(i))
    idx = np.asarray(kept, dtype=np.int64)
    points = q[idx].reshape(-1, 2)
    normals = (g[idx] / gn[idx, None]).reshape(-1, 2)
    return points, normals
