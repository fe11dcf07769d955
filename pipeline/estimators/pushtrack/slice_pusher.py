"""The gripper's slice as the pusher: the ``sweep`` motion of the pushtrack estimator (docs/estimators.md, "Pushing
models").

The point pusher of :func:`pipeline.estimators.pushtrack.quasistatic.push_step` starts at the contact minus the
in-contact displacement and treats the gripper as a point. The gripper is a hand about 14 x 20 cm at contact height with
flat faces: a flat face pushing a box's face aligns it (a line contact), and the contact moves along the gripper
as the box turns. Here the gripper's slice moves in ``substeps`` straight steps over its in-contact displacement
(the filter passes the action's end position less that displacement, and the end position). At each step the
deepest penetration between the slice and the target (a gripper point inside the target, or a target point
inside the gripper) is the contact: its normal is the push direction, and the pusher's step, cut to the part
that closes that penetration, drives the same quasi-static limit-surface model (Lynch, Mason) as the point
pusher.

Everything runs in one compiled loop over the poses (:func:`sweep_kernel`); its arithmetic is scalar, with the
C library's sin and cos, so it gives the same bits on every x86-64 CPU.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from pipeline.estimators.plausible.kernel import local_sdf
from pipeline.geometry import Primitive

__all__ = ["GripperSlice", "gripper_slice", "cached_gripper_slice", "target_outline", "sweep_push", "sweep_kernel",
           "warm_up"]

#: How far (m) the simplified outline of the gripper's slice may lie from its zero contour.
SLICE_TOLERANCE = 0.001
#: Spacing (m) of a cylinder's outline points (a box's are its corners).
OUTLINE_SPACING = 0.004


@dataclass(frozen=True)
class GripperSlice:
    """The gripper's slice at contact height, for :func:`sweep_push`.

    Attributes
    ----------
    points : ndarray, shape (G, 2), metres
        Robot-frame vertices of the slice's outline (where a contact with a box's face can be deepest).
    normals : ndarray, shape (G, 2)
        The slice's outward unit normal at each point (the grid's gradient; 0 where it has none).
    values, shape, strides, origin, resolution
        The signed distance grid's arrays (:meth:`pipeline.robot.GridSDF.kernel_arrays`).
    outside : float, metres
        The grid's value outside it.
    """

    points: np.ndarray
    normals: np.ndarray
    values: np.ndarray
    shape: np.ndarray
    strides: np.ndarray
    origin: np.ndarray
    resolution: float
    outside: float


def _simplify(line: np.ndarray, tol: float) -> np.ndarray:
    """Douglas-Peucker: the vertices (M, 2) of a polyline (L, 2) kept so that no dropped one lies farther than
    ``tol`` from the simplified line."""
    keep = np.zeros(len(line), dtype=bool)
    keep[0] = keep[-1] = True
    stack = [(0, len(line) - 1)]
    while stack:
        i, j = stack.pop()
        if j <= i + 1:
            continue
        a, b = line[i], line[j]
        ab = b - a
        n = math.hypot(ab[0], ab[1])
        rel = line[i + 1:j] - a
        dist = np.abs(ab[0] * rel[:, 1] - ab[1] * rel[:, 0]) / n if n > 0.0 else np.hypot(rel[:, 0], rel[:, 1])
        k = int(np.argmax(dist))
        if dist[k] > tol:
            keep[i + 1 + k] = True
            stack += [(i, i + 1 + k), (i + 1 + k, j)]
    return line[keep]


def gripper_slice(sdf, tolerance: float = SLICE_TOLERANCE) -> GripperSlice:
    """The :class:`GripperSlice` of a robot's signed distance grid (:class:`pipeline.robot.GridSDF`, 2-D): the
    vertices of its zero contour (contourpy, as matplotlib draws it), simplified to ``tolerance`` metres."""
    import contourpy  # (a matplotlib dependency)

    values, shape, strides, origin, resolution = sdf.kernel_arrays()
    ax = [origin[k] + resolution * np.arange(shape[k]) for k in range(2)]
    # contourpy's z has rows along its y: the grid's first axis (robot x) is contourpy's y
    lines = contourpy.contour_generator(x=ax[1], y=ax[0], z=sdf.values).lines(0.0)
    pts = [_simplify(np.asarray(line, dtype=np.float64)[:, ::-1], tolerance) for line in lines if len(line) > 1]
    pts = np.unique(np.vstack(pts), axis=0) if pts else np.zeros((0, 2))
    h = float(resolution)
    grad = np.column_stack([sdf.query(pts + [h, 0.0]) - sdf.query(pts - [h, 0.0]),
                            sdf.query(pts + [0.0, h]) - sdf.query(pts - [0.0, h])])
    norm = np.hypot(grad[:, 0], grad[:, 1])
    normals = np.where(norm[:, None] > 0.0, grad / np.where(norm > 0.0, norm, 1.0)[:, None], 0.0)
    return GripperSlice(points=np.ascontiguousarray(pts, dtype=np.float64), normals=normals, values=values,
                        shape=shape, strides=strides, origin=origin, resolution=float(resolution),
                        outside=float(sdf.outside_value))


_SLICES: dict[str, GripperSlice] = {}


def cached_gripper_slice(sdf) -> GripperSlice:
    """:func:`gripper_slice` with its defaults, built once per process for each grid (by its digest)."""
    if sdf.digest not in _SLICES:
        _SLICES[sdf.digest] = gripper_slice(sdf)
    return _SLICES[sdf.digest]


def target_outline(prim: Primitive, spacing: float = OUTLINE_SPACING) -> np.ndarray:
    """Points (B, 2), metres, of the target's outline in its primitive frame where a contact with the gripper's
    faces can be deepest: a box's four corners, a cylinder's outline every ``spacing`` or closer."""
    if prim.kind == "cylinder":
        r = prim.half[0]
        n = max(8, int(math.ceil(2.0 * math.pi * r / spacing)))
        ang = np.arange(n) * (2.0 * math.pi / n)
        return np.column_stack([r * np.cos(ang), r * np.sin(ang)])
    hx, hy = prim.half
    return np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])


@njit(cache=True, inline="always")
def _grid_value(values, grid, qx, qy):
    """The grid's signed distance at robot-frame (qx, qy), by nearest cell (:meth:`GridSDF.query`): ``values`` the
    grid's values, ``grid`` its scalars (origin x, origin y, last index x, last index y (as floats), stride x,
    stride y, resolution, outside value)."""
    # Inlined into sweep_kernel's loops, the scalars in a tuple: called there with the grid's arrays, every call
    # counted their references (atomic operations), most of the kernel's time (docs/experiments/pushtrack-speed.md).
    ix = np.rint((qx - grid[0]) / grid[6])
    iy = np.rint((qy - grid[1]) / grid[6])
    if not (ix >= 0.0 and ix <= grid[2] and iy >= 0.0 and iy <= grid[3]):
        return grid[7]
    return values[int(ix) * grid[4] + int(iy) * grid[5]]


@njit(cache=True)
def sweep_kernel(cylinder, hx, hy, prim_yaw, pcx, pcy, poses, gpts, bpts, values, shape, strides, origin,
                 resolution, outside, g0x, g0y, g1x, g1y, substeps, c, mu, tip, tip_spread, tip_reach):
    """Move every COM pose of ``poses`` (N, 3), in place, as the gripper's slice sweeps from (g0x, g0y) to
    (g1x, g1y) in ``substeps`` steps (the module docstring).

    Parameters
    ----------
    cylinder : bool
        The target is a cylinder of radius ``hx``; else a box of half sides (hx, hy), metres.
    prim_yaw, pcx, pcy
        The primitive's yaw and centre in the COM frame (:class:`pipeline.geometry.Primitive`).
    gpts : ndarray, shape (G, 2)
        The gripper's boundary points in the robot frame (:attr:`GripperSlice.points`).
    bpts : ndarray, shape (B, 2)
        The target's outline points in the primitive frame (:func:`target_outline`).
    values ... outside
        The gripper's signed distance grid (:class:`GripperSlice`).
    c : float, metres
        The limit surface's characteristic length; ``mu`` the pusher-target friction coefficient.
    tip : bool
        A box pushed on a long face (its primitive's x axis) turns about a point of its leading long edge's line,
        as a box tipped onto that edge (``PushTrackParams.motion`` "tip"); else the limit surface, as for its end
        faces.
    tip_spread, tip_reach : float
        That point lies hy * min(1 + tip_spread * hy / |e|, tip_reach) from the edge's middle, on the far side
        from the contact's offset e along the edge (``PushTrackParams.tip_spread``, ``tip_reach``).
    """
    N = poses.shape[0]
    G = gpts.shape[0]
    B = bpts.shape[0]
    dsx = (g1x - g0x) / substeps
    dsy = (g1y - g0y) / substeps
    ds2 = dsx * dsx + dsy * dsy
    if ds2 <= 0.0:
        return
    reach = math.sqrt(hx * hx + hy * hy) if not cylinder else hx
    reach2 = (reach + 1e-6) ** 2
    c2 = c * c
    h = resolution
    grip_r = 0.0
    for g in range(G):
        grip_r = max(grip_r, gpts[g, 0] * gpts[g, 0] + gpts[g, 1] * gpts[g, 1])
    far2 = (math.sqrt(grip_r) + reach + h) ** 2
    grid = (origin[0], origin[1], shape[0] - 1.0, shape[1] - 1.0, strides[0], strides[1], resolution, outside)
    for n in range(N):
        x = poses[n, 0]
        y = poses[n, 1]
        th = poses[n, 2]
        for i in range(substeps):
            gx = g0x + dsx * (i + 1)
            gy = g0y + dsy * (i + 1)
            ct = math.cos(th)
            st = math.sin(th)
            cx = x + ct * pcx - st * pcy
            cy = y + st * pcx + ct * pcy
            if (cx - gx) ** 2 + (cy - gy) ** 2 > far2:
                continue  # the slice cannot reach the target
            cos_p = math.cos(th + prim_yaw)
            sin_p = math.sin(th + prim_yaw)
            # (a) the gripper's points inside the target: the target's outward normal
            best = 0.0
            px = py = mx = my = 0.0
            for g in range(G):
                wx = gx + gpts[g, 0]
                wy = gy + gpts[g, 1]
                dx = wx - cx
                dy = wy - cy
                if dx * dx + dy * dy > reach2:
                    continue
                sd, nx, ny = local_sdf(cylinder, hx, hy, cos_p * dx + sin_p * dy, -sin_p * dx + cos_p * dy)
                if -sd > best:
                    best = -sd
                    px = wx
                    py = wy
                    mx = -(cos_p * nx - sin_p * ny)
                    my = -(sin_p * nx + cos_p * ny)
            # (b) the target's points inside the gripper: the gripper's outward normal
            for b in range(B):
                wx = cx + cos_p * bpts[b, 0] - sin_p * bpts[b, 1]
                wy = cy + sin_p * bpts[b, 0] + cos_p * bpts[b, 1]
                qx = wx - gx
                qy = wy - gy
                v = _grid_value(values, grid, qx, qy)
                if -v > best:
                    ex = (_grid_value(values, grid, qx + h, qy)
                          - _grid_value(values, grid, qx - h, qy))
                    ey = (_grid_value(values, grid, qx, qy + h)
                          - _grid_value(values, grid, qx, qy - h))
                    norm = math.sqrt(ex * ex + ey * ey)
                    if norm <= 0.0:
                        continue
                    best = -v
                    px = wx
                    py = wy
                    mx = ex / norm
                    my = ey / norm
            if best <= 0.0:
                continue
            dn = mx * dsx + my * dsy
            if dn <= 1e-12 * math.sqrt(ds2):
                continue  # the gripper moves along or away from the contact: it does not push there
            frac = min(best / dn, 1.0)
            ux = dsx * frac
            uy = dsy * frac
            dn = dn * frac
            if tip and not cylinder:
                # the contact's offset and normal in the primitive's frame
                qy = -sin_p * (px - cx) + cos_p * (py - cy)
                nx_ = cos_p * mx + sin_p * my
                ny_ = -sin_p * mx + cos_p * my
                if abs(nx_) > abs(ny_) and abs(qy) > 1e-9:
                    # A long face pushed off its middle: the box rests on its leading long edge and turns about a
                    # point of that edge's line on the far side: just beyond its far corner when pushed near an end,
                    # further out (but not beyond tip_reach * hy) when pushed near the middle (docs/estimators.md,
                    # "Pushing models"). The side flips with the offset's sign, as a tipped box
                    # falls to one side or the other; pushed exactly at the middle, no side is the far one: the
                    # limit surface below pushes it straight.
                    lead = hx if nx_ > 0.0 else -hx
                    dist = hy * min(1.0 + tip_spread * hy / abs(qy), tip_reach)
                    oy = -dist if qy > 0.0 else dist
                    corx = cx + cos_p * lead - sin_p * oy
                    cory = cy + sin_p * lead + cos_p * oy
                    den = mx * -(py - cory) + my * (px - corx)  # m . perp(p - cor)
                    if abs(den) > 1e-12:
                        w = dn / den
                        cw = math.cos(w)
                        sw = math.sin(w)
                        rx = x - corx
                        ry = y - cory
                        x = corx + cw * rx - sw * ry
                        y = cory + sw * rx + cw * ry
                        th += w
                        continue
            # the quasi-static twist (pipeline.estimators.pushtrack.quasistatic.push_step, with the contact and normal
            # given)
            rx = px - x
            ry = py - y
            ax = -ry
            ay = rx
            aa = ax * ax + ay * ay
            k = (ax * ux + ay * uy) / (c2 + aa)
            fx = ux - ax * k
            fy = uy - ay * k
            tx = -my
            ty = mx
            fn = fx * mx + fy * my
            ft = fx * tx + fy * ty
            if abs(ft) > mu * max(fn, 0.0):
                sgn = 1.0 if ft >= 0.0 else -1.0
                ex = mx + mu * sgn * tx
                ey = my + mu * sgn * ty
                ae = (ax * ex + ay * ey) / c2
                mfx = ex + ax * ae
                mfy = ey + ay * ae
                kk = dn / max(mx * mfx + my * mfy, 1e-12)
                fx = ex * kk
                fy = ey * kk
            w = (ax * fx + ay * fy) / c2
            x += fx
            y += fy
            th += w
        poses[n, 0] = x
        poses[n, 1] = y
        poses[n, 2] = th


def sweep_push(prim: Primitive, poses: np.ndarray, grip: GripperSlice, outline: np.ndarray, g0: np.ndarray,
               g1: np.ndarray, substeps: int, c: float, mu: float,
               tip: tuple[float, float] | None = None) -> np.ndarray:
    """COM poses (N, 3) after the gripper's slice swept straight from ``g0`` to ``g1`` (2,), metres, against the
    target at ``poses`` (N, 3) (the module docstring); a pose the slice never reaches is returned as it was.
    ``tip``: (spread, reach) of the tipped box's centre of rotation (:func:`sweep_kernel`); None: the limit surface
    on every face."""
    if isinstance(tip, bool):
        raise TypeError("sweep_push: tip is (spread, reach) or None, not a bool")
    out = np.array(poses, dtype=np.float64, copy=True, order="C")
    d = np.asarray(g1, dtype=np.float64) - np.asarray(g0, dtype=np.float64)
    # only the slice's side that faces the motion can enter the target (a side point may, as the target turns,
    # but the front's points reach deeper)
    front = np.ascontiguousarray(grip.points[grip.normals[:, 0] * d[0] + grip.normals[:, 1] * d[1] > 0.0])
    hy = float(prim.half[1]) if len(prim.half) > 1 else 0.0
    spread, reach = (0.0, 1.0) if tip is None else (float(tip[0]), float(tip[1]))
    sweep_kernel(prim.kind == "cylinder", float(prim.half[0]), hy, float(prim.yaw), float(prim.centre[0]),
                 float(prim.centre[1]), out, front, np.ascontiguousarray(outline, dtype=np.float64),
                 grip.values, grip.shape, grip.strides, grip.origin, grip.resolution, grip.outside,
                 float(g0[0]), float(g0[1]), float(g1[0]), float(g1[1]), int(substeps), float(c), float(mu),
                 tip is not None, spread, reach)
    return out


def warm_up() -> None:
    """Compile the kernel (numba caches it on disk), as ``make setup`` does."""
    one = np.zeros((1, 2))
    for cylinder in (False, True):
        sweep_kernel(cylinder, 0.05, 0.05, 0.0, 0.0, 0.0, np.zeros((1, 3)), one, one, np.zeros(4),
                     np.array([2, 2], dtype=np.int64), np.array([2, 1], dtype=np.int64), np.zeros(2), 0.01, 1.0,
                     0.0, 0.0, 0.01, 0.0, 2, 0.05, 0.5, True, 0.1, 1.0)
