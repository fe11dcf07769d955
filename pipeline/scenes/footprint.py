"""Outlines on the plane: objects, walls and the gripper as convex polygons, their separation, and how much of
the target the others hide from a point (no pybullet here; used by :mod:`pipeline.scenes.generate`).

Every polygon is an array (V, 2) of world (x, y) metres, counter-clockwise. A cylinder's outline is the regular
polygon circumscribing its circle, so a test passed by the polygon is passed by the circle too (conservative).
"""
from __future__ import annotations

import math

import numpy as np

from pipeline.geometry import dot2, rotate, wrap_angle
from pipeline.portable import atan2
from pipeline.scenes.types import ObjectSpec, WallSpec

__all__ = ["GRIPPER_OUTLINE_M", "CIRCLE_SIDES", "object_outline", "wall_outline", "gripper_outline", "rectangle",
           "inside", "containment_problem",
           "separation", "ray_entry", "hidden_fraction", "bounding_box"]

#: The closed Panda hand's outline on the plane in the gripper base frame, ((x_min, y_min), (x_max, y_max)) in
#: metres, fingers along +x (docs/simulation.md, "World, gripper, stepping"): the bounding box of pybullet_data's
#: hand and finger hulls at the fixed orientation (measured: x -0.0259 .. 0.1122, y -0.1040 .. 0.1004), rounded
#: outward to the millimetre. Kept here as numbers so this package stays free of pybullet and Open3D.
GRIPPER_OUTLINE_M = ((-0.026, -0.104), (0.113, 0.101))
#: Sides of the polygon standing for a cylinder's circle.
CIRCLE_SIDES = 16


def rectangle(centre: tuple[float, float], sides: tuple[float, float], yaw: float) -> np.ndarray:
    """Corners (4, 2), metres, of a rectangle with full ``sides`` (x, y) in its own frame, turned by ``yaw``
    (radians) about its ``centre``."""
    hx, hy = sides[0] / 2.0, sides[1] / 2.0
    local = np.array([[hx, -hy], [hx, hy], [-hx, hy], [-hx, -hy]])
    return rotate(local, yaw) + np.asarray(centre, dtype=np.float64)


def object_outline(o: ObjectSpec) -> np.ndarray:
    """Outline (V, 2), metres, of an upright object at its spawn pose: a box's rectangle, or the
    :data:`CIRCLE_SIDES`-gon circumscribing a cylinder's circle."""
    centre = o.centre_xy
    if o.shape == "box":
        return rectangle(centre, (o.size[0], o.size[1]), o.yaw + o.shape_yaw)
    radius = o.size[0] / math.cos(math.pi / CIRCLE_SIDES)
    angles = np.arange(CIRCLE_SIDES) * (2.0 * math.pi / CIRCLE_SIDES)
    return np.stack([centre[0] + radius * np.cos(angles), centre[1] + radius * np.sin(angles)], axis=1)


def wall_outline(w: WallSpec) -> np.ndarray:
    """Outline (4, 2), metres, of a wall."""
    return rectangle(w.position, (w.size[0], w.size[1]), w.yaw)


def gripper_outline(start: tuple[float, float]) -> np.ndarray:
    """Outline (4, 2), metres, of the gripper with its base at ``start`` (x, y)."""
    (x0, y0), (x1, y1) = GRIPPER_OUTLINE_M
    return np.array([[start[0] + x1, start[1] + y0], [start[0] + x1, start[1] + y1], [start[0] + x0, start[1] + y1],
                     [start[0] + x0, start[1] + y0]])


def _normals(poly: np.ndarray) -> np.ndarray:
    """Outward unit normals (V, 2) of a counter-clockwise polygon's edges (edge i runs from vertex i to i+1)."""
    edge = np.roll(poly, -1, axis=0) - poly
    n = np.stack([edge[:, 1], -edge[:, 0]], axis=1)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def separation(a: np.ndarray, b: np.ndarray) -> float:
    """Largest gap (metres) between the projections of two convex polygons on their edge normals.

    Positive: the polygons are at least this far apart (a lower bound of their distance, exact when the closest
    features are an edge and a vertex). Zero or negative: they touch or overlap.
    """
    axes = np.concatenate([_normals(a), _normals(b)])
    # element-wise products, not BLAS: a redraw must not hinge on the last bits of a matrix product
    pa, pb = dot2(a[:, None, :], axes[None, :, :]), dot2(b[:, None, :], axes[None, :, :])
    gaps = np.maximum(pb.min(axis=0) - pa.max(axis=0), pa.min(axis=0) - pb.max(axis=0))
    return float(gaps.max())


def ray_entry(origin: np.ndarray, direction: np.ndarray, poly: np.ndarray) -> float:
    """Distance (in units of ``direction``'s length) along the ray ``origin + t direction``, t >= 0, at which it
    enters the convex polygon; 0 if ``origin`` is inside, inf if the ray misses it (Cyrus-Beck clipping)."""
    normals = _normals(poly)
    towards = dot2(normals, direction)  # < 0: the ray crosses this edge going in
    offset = (poly - origin) * normals
    dist = offset.sum(axis=1)  # n . (p - o): > 0 while the origin is on the inner side of the edge
    t_in, t_out = 0.0, math.inf
    for d, s in zip(towards, dist):
        if abs(d) < 1e-15:
            if s < 0.0:  # parallel to the edge and outside it
                return math.inf
            continue
        t = s / d
        if d < 0.0:
            t_in = max(t_in, t)
        else:
            t_out = min(t_out, t)
    return t_in if t_in <= t_out else math.inf


def hidden_fraction(start: tuple[float, float], target: np.ndarray, others: list[np.ndarray],
                    n_rays: int = 41) -> float:
    """Share of the target's silhouette seen from ``start`` that other outlines cover, in [0, 1].

    ``n_rays`` rays from ``start`` spread evenly over the angle the target spans; a ray counts as hidden when it
    enters another outline before the target's. ``target`` and ``others`` are outlines (V, 2), metres.
    """
    origin = np.asarray(start, dtype=np.float64)
    rel = target - origin
    centre = math.atan2(*(target.mean(axis=0) - origin)[::-1])
    angles = wrap_angle(atan2(rel[:, 1], rel[:, 0]) - centre)  # relative, wrapped
    lo, hi = float(angles.min()), float(angles.max())
    hidden = 0
    for k in range(n_rays):
        a = centre + lo + (hi - lo) * (k + 0.5) / n_rays
        d = np.array([math.cos(a), math.sin(a)])
        t_target = ray_entry(origin, d, target)
        if any(ray_entry(origin, d, o) < t_target for o in others):
            hidden += 1
    return hidden / n_rays


def bounding_box(polys: list[np.ndarray]) -> tuple[tuple[float, float], tuple[float, float]]:
    """((x_min, y_min), (x_max, y_max)), metres, of a list of outlines."""
    pts = np.concatenate(polys)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    return (float(lo[0]), float(lo[1])), (float(hi[0]), float(hi[1]))


def inside(point, poly: np.ndarray) -> bool:
    """Whether ``point`` (2,) lies strictly inside the convex counter-clockwise polygon ``poly`` (V, 2)."""
    a = np.asarray(poly, dtype=np.float64)
    b = np.roll(a, -1, axis=0)
    q = np.asarray(point, dtype=np.float64)
    cross = (b[:, 0] - a[:, 0]) * (q[1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (q[0] - a[:, 0])
    return bool(np.all(cross > 0.0))


def containment_problem(objects, walls, start) -> str | None:
    """Why a scene's layout is impossible, or None: an object whose centre lies inside another object or a wall,
    or a gripper start inside one. Shallow interpenetration is left to the simulator's settling, as the paper's
    levels need it (FB's box and can overlap by 2 cm at spawn); a centre inside another body is no layout at all."""
    bodies = [(o.name, object_outline(o)) for o in objects] + [(w.name, wall_outline(w)) for w in walls]
    for o in objects:
        for name, poly in bodies:
            if name != o.name and inside(o.centre_xy, poly):
                return f"object {o.name!r} has its centre inside {name!r}"
    if start is not None:
        for name, poly in bodies:
            if inside(start, poly):
                return f"the gripper starts inside {name!r}"
    return None
