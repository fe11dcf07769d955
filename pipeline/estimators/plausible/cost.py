"""The plausible estimator's cost of a pose and its Gauss-Newton terms (contact, free space, others; the terms are
described in :mod:`pipeline.estimators.plausible.fit`), the batched Levenberg-Marquardt refinement of many poses at
once, and the random starting poses."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.estimators.plausible.kernel import CONTACT, FREE, piece_terms, piece_terms_each
from pipeline.estimators.plausible.params import PlausibleParams
from pipeline.geometry import Primitive, outline_point, primitive_sdf, rotate, wrap_angle
from pipeline.spd import solve_spd

__all__ = ["Terms", "to_local", "evaluate_terms", "compiled_terms", "refine", "initial_poses"]


def to_local(world: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points (P, 2) in each primitive pose's frame (B, P, 2), and their offsets from the centre."""
    d = world[None, :, :] - pose[:, None, :2]
    return rotate(d, pose[:, 2, None], inverse=True), d


@dataclass
class Terms:
    """Costs (B,) of B poses, in squared contact sigmas."""

    contact: np.ndarray
    free: np.ndarray
    others: np.ndarray

    @property
    def total(self) -> np.ndarray:
        return self.contact + self.free + self.others


def evaluate_terms(prim: Primitive, pose: np.ndarray, points: np.ndarray, sigma: np.ndarray, free: np.ndarray,
                   others: np.ndarray, params: PlausibleParams, jacobian: bool = False):
    """Terms of primitive poses (B, 3) = (centre x, centre y, yaw of the primitive axes); with ``jacobian``
    also the Gauss-Newton normal matrix (B, 3, 3) and gradient (B, 3) (IRLS weights for the robust term)."""
    B = len(pose)
    costs, pieces = [], []
    c2 = params.outlier_sigmas ** 2
    s0 = params.contact_sigma
    for pts, kind in ((points, "contact"), (free, "free"), (others, "others")):
        if len(pts) == 0:
            costs.append(np.zeros(B))
            continue
        q, d = to_local(pts, pose)
        sd, g_local = primitive_sdf(prim, q)
        if kind == "contact":
            u = sd / sigma
            costs.append((0.5 * c2 * u * u / (c2 + u * u)).sum(axis=1))
            weight, resid, scale = (c2 / (c2 + u * u)) ** 2, u, 1.0 / sigma[None, :]
        else:
            tol = params.free_tolerance if kind == "free" else params.other_tolerance
            r = np.minimum(sd + tol, 0.0) / s0
            costs.append(params.free_weight * 0.5 * (r * r).sum(axis=1))
            weight, resid, scale = np.where(r < 0.0, params.free_weight, 0.0), r, np.full((1, 1), 1.0 / s0)
        if jacobian:
            g = rotate(g_local, pose[:, 2, None])
            gx, gy = g[..., 0], g[..., 1]
            # d sd / d centre = -g ; d sd / d yaw = -g . (-dy, dx) for the offset d of the point from the centre
            J = np.stack([-gx, -gy, gx * d[..., 1] - gy * d[..., 0]], axis=-1) * scale[..., None]
            pieces.append((resid, weight, J))
    terms = Terms(*costs)
    if not jacobian:
        return terms
    H = np.zeros((B, 3, 3))
    grad = np.zeros((B, 3))
    for resid, weight, J in pieces:
        wJ = J * weight[..., None]
        # Written out and summed over the points in a fixed order (no einsum/BLAS: docs/evaluation.md).
        H += np.sum(wJ[..., :, None] * J[..., None, :], axis=1)
        grad += np.sum(wJ * resid[..., None], axis=1)
    return terms, H, grad


def compiled_terms(prim: Primitive, pose: np.ndarray, points: np.ndarray, sigma: np.ndarray, free: np.ndarray,
                   others: np.ndarray, params: PlausibleParams, jacobian: bool = False):
    """:func:`evaluate_terms` through the compiled kernel (:mod:`pipeline.estimators.plausible.kernel`): the same
    bits, without the (B, P, 3, 3) temporaries. ``points`` may also be (B, P, 2), each pose with its own contact
    points (the pushtrack estimator's particles): row b then has the bits of pose b with ``points[b]`` alone."""
    pose = np.ascontiguousarray(pose, dtype=np.float64)
    B = len(pose)
    yaw = pose[:, 2, None]  # the view rotate() takes its cosines from in evaluate_terms: the same numpy call
    cos_t, sin_t = np.cos(yaw)[:, 0].copy(), np.sin(yaw)[:, 0].copy()
    c2 = params.outlier_sigmas ** 2
    s0 = params.contact_sigma
    hy = prim.half[1] if len(prim.half) > 1 else 0.0
    costs, H, grad = [], np.zeros((B, 3, 3)), np.zeros((B, 3))
    for pts, kind in ((points, "contact"), (free, "free"), (others, "others")):
        if len(pts) == 0 or np.shape(pts)[-2] == 0:
            costs.append(np.zeros(B))
            continue
        cost, h, g = np.empty(B), np.empty((B, 3, 3)), np.empty((B, 3))
        pts = np.ascontiguousarray(pts, dtype=np.float64)
        if pts.ndim == 3:
            piece_terms_each(prim.kind == "cylinder", prim.half[0], hy, pose, cos_t, sin_t, pts,
                             np.ascontiguousarray(sigma, dtype=np.float64), 0.5 * c2, c2, jacobian, cost, h, g,
                             np.empty(pts.shape[1]))
        else:
            tol = params.free_tolerance if kind == "free" else params.other_tolerance
            piece_terms(prim.kind == "cylinder", prim.half[0], hy, pose, cos_t, sin_t, pts,
                        np.ascontiguousarray(sigma if kind == "contact" else np.zeros(0), dtype=np.float64),
                        CONTACT if kind == "contact" else FREE, 0.5 * c2, c2, tol, s0, 1.0 / s0, params.free_weight,
                        jacobian, cost, h, g, np.empty(len(pts)))
        costs.append(cost if kind == "contact" else params.free_weight * 0.5 * cost)
        if jacobian:
            H += h
            grad += g
    terms = Terms(*costs)
    return (terms, H, grad) if jacobian else terms


def refine(prim: Primitive, init: np.ndarray, points: np.ndarray, sigma: np.ndarray, free: np.ndarray,
           others: np.ndarray, params: PlausibleParams) -> tuple[np.ndarray, Terms]:
    """Batched Levenberg-Marquardt from primitive poses (B, 3); steps capped at 2 cm and 0.2 rad.

    ``points`` (P, 2), or (B, P, 2) with each pose's own (:func:`compiled_terms`). Returns the refined poses (B, 3),
    yaw wrapped to [-pi, pi), and their :class:`Terms`.
    """
    pose = np.array(init, dtype=np.float64)
    lam = np.full(len(pose), 1e-3)
    terms, H, grad = compiled_terms(prim, pose, points, sigma, free, others, params, jacobian=True)
    cost = terms.total
    eye = np.eye(3)
    for _ in range(params.iterations):
        diag = np.maximum(np.diagonal(H, axis1=1, axis2=2), 1e-9)
        A = H + lam[:, None, None] * (eye * diag[:, None, :]) + 1e-12 * eye
        step = -solve_spd(A, grad)
        move = np.linalg.norm(step[:, :2], axis=1)
        shrink = np.minimum(1.0, np.minimum(0.02 / np.maximum(move, 1e-12), 0.2 / np.maximum(np.abs(step[:, 2]),
                                                                                            1e-12)))
        trial = pose + step * shrink[:, None]
        t2, H2, g2 = compiled_terms(prim, trial, points, sigma, free, others, params, jacobian=True)
        better = np.isfinite(t2.total) & (t2.total < cost)
        pose = np.where(better[:, None], trial, pose)
        cost = np.where(better, t2.total, cost)
        H = np.where(better[:, None, None], H2, H)
        grad = np.where(better[:, None], g2, grad)
        lam = np.clip(np.where(better, lam * 0.3, lam * 10.0), 1e-9, 1e9)
    pose[:, 2] = wrap_angle(pose[:, 2])
    return pose, compiled_terms(prim, pose, points, sigma, free, others, params)


def initial_poses(prim: Primitive, points: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """n primitive poses (n, 3): stratified yaw from a random offset, the points' centroid on a random point of
    the outline (a contact is on the surface, so the centroid of a few is near it, not at the centre)."""
    theta = (rng.uniform() + np.arange(n)) * (2.0 * np.pi / n)
    if prim.kind == "cylinder":
        ang = rng.uniform(0.0, 2.0 * np.pi, n)
        u = prim.half[0] * np.column_stack([np.cos(ang), np.sin(ang)])
    else:
        hx, hy = prim.half
        u = outline_point(rng.uniform(0.0, 4.0 * (hx + hy), n), hx, hy)
    return np.column_stack([points.mean(axis=0) - rotate(u, theta), theta])
