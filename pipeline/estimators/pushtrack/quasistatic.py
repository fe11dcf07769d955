"""The quasi-static model of planar pushing with an ellipsoidal limit surface (Lynch, Mason), the motion model of
the pushtrack estimator (docs/retrieval.md, "The pushtrack estimator"; :mod:`pipeline.estimators.pushtrack.filter` is
its filter).

A pusher at a point of the target's surface moves by d. The target's twist is proportional to (f, m / c^2) for
the applied force f and moment m about the COM, c the limit surface's characteristic length: the contact sticks
when the force the sticking motion needs lies inside the friction cone, and slides along the cone's edge
otherwise. Vectorised over poses (N, 3); no loop over them.
"""
from __future__ import annotations

import numpy as np

from pipeline.geometry import Primitive, dot2, primitive_sdf, rotate

__all__ = ["limit_surface_length", "surface_contact", "push_step"]


def limit_surface_length(prim: Primitive, n: int = 64) -> float:
    """Characteristic length c (m) of the ellipsoidal limit surface of a uniform pressure over the primitive's
    footprint: the mean distance of the footprint from the COM (the ratio of the largest friction moment to the
    largest friction force)."""
    u = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    if prim.kind == "cylinder":
        r = prim.half[0]
        q = np.stack(np.meshgrid(u * r, u * r, indexing="ij"), -1).reshape(-1, 2)
        q = q[np.hypot(q[:, 0], q[:, 1]) <= r]
    else:
        q = np.stack(np.meshgrid(u * prim.half[0], u * prim.half[1], indexing="ij"), -1).reshape(-1, 2)
    world = rotate(q, prim.yaw) + prim.centre  # footprint in the COM frame
    return float(np.mean(np.hypot(world[:, 0], world[:, 1])))


def surface_contact(prim: Primitive, pose: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest surface point (N, 2) to world point(s) p (2,) or (N, 2) of the target at COM poses (N, 3), and the
    outward normal (N, 2) there."""
    yaw = pose[:, 2] + prim.yaw
    centre = prim.centre_world(pose)
    q = rotate(p - centre, yaw, inverse=True)
    sd, g = primitive_sdf(prim, q)
    on = q - sd[:, None] * g
    return rotate(on, yaw) + centre, rotate(g, yaw)


def push_step(prim: Primitive, pose: np.ndarray, p: np.ndarray, d: np.ndarray, c: float, mu: float,
              motion: str = "push") -> np.ndarray:
    """Poses (N, 3) after the pusher at world point p (2,) moves by d (2,), metres, against targets at COM poses
    (N, 3), quasi-statically (the module docstring). A pusher moving away from the surface leaves the pose."""
    cp, n = surface_contact(prim, pose, p)
    m = -n  # the direction the pusher can push in
    dn = dot2(m, d)
    if motion == "static":
        return pose.copy()
    if motion == "translate":
        return pose + np.column_stack([m * np.maximum(dn, 0.0)[:, None], np.zeros(len(pose))])
    r = cp - pose[:, :2]
    a = np.column_stack([-r[:, 1], r[:, 0]])  # r rotated by +90 deg: the contact velocity per unit turn
    c2 = c * c
    # Sticking: the force whose twist moves the contact point with the pusher, f = M^-1 d with
    # M = I + a a^T / c^2 (Sherman-Morrison, written out).
    f = d - a * (dot2(a, d) / (c2 + dot2(a, a)))[:, None]
    fn = dot2(f, m)
    t = np.column_stack([-m[:, 1], m[:, 0]])
    ft = dot2(f, t)
    slide = np.abs(ft) > mu * np.maximum(fn, 0.0)
    # Sliding: the force on the friction cone's edge, scaled so the contact's normal velocity is the pusher's.
    edge = m + (mu * np.where(ft >= 0.0, 1.0, -1.0))[:, None] * t
    mf = edge + a * (dot2(a, edge) / c2)[:, None]
    k = dn / np.maximum(dot2(m, mf), 1e-12)
    f = np.where(slide[:, None], edge * k[:, None], f)
    w = dot2(a, f) / c2
    moving = dn > 0.0
    step = np.column_stack([f, w]) * moving[:, None]
    return pose + step
