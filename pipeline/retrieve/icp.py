"""Planar ICP of a segment's points onto the target's model points from many restarts, in SE(2).

Point-to-point ICP as Open3D's ``registration_icp`` runs it (nearest model point within the correspondence
radius; the closed-form best rigid transform of the pairs; stop when fitness and inlier RMSE change by less than
1e-9 or after ``max_iteration``), optionally followed by point-to-plane ICP onto the model's normals (the
linearised step of Open3D's point-to-plane estimator, restricted to the plane). It is written here, in SE(2),
batched over the restarts: Open3D's ICP (its own TBB threads and SIMD kernels) did not give the same bits twice
on one machine, let alone across CPUs, and a 3-D ICP of planar points needs guarding against mirrored results.
Nearest neighbours come from scipy's cKDTree; every sum runs in a fixed order and every angle through
:mod:`pipeline.portable`, so the result is the same on every x86-64 CPU (docs/evaluation.md, "Same numbers on
every machine").
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from pipeline.geometry import apply_pose, rotate, wrap_angle
from pipeline.portable import atan2
from pipeline.retrieve.params import RetrievalParams
from pipeline.spd import solve_spd

__all__ = ["IcpResult", "initial_transforms", "icp_error", "icp_restarts"]


@dataclass(frozen=True)
class IcpResult:
    """ICP of one segment from B initial transforms.

    Attributes
    ----------
    world_to_model : ndarray, shape (B, 3)
        (tx, ty, theta): model = R(theta) world + t, the transform ICP estimates.
    poses : ndarray, shape (B, 3)
        Object pose (x, y, yaw) in the world: the inverse transform.
    rmse : ndarray, shape (B,), metres
        ICP error (:func:`icp_error`): root mean square over all points of the distance to the nearest model
        point (point-to-point) or of that distance along its normal (point-to-plane).
    valid : ndarray, shape (B,), bool
        ICP left the points within ``max_point_distance`` (median) of the model points.
    """

    world_to_model: np.ndarray
    poses: np.ndarray
    rmse: np.ndarray
    valid: np.ndarray


def initial_transforms(points: np.ndarray, model: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Random initial world -> model transforms (n, 3) as (tx, ty, theta).

    theta ~ U[0, 2 pi) about the segment's centroid, and the centroid is put at a uniformly random point of the
    model's bounding box. (The authors rotated about the world origin with zero translation, which starts ICP
    tens of centimetres away. Putting the centroid on the model's centre instead traps ICP: contacts lie on
    the surface, so their centroid is never the centre; docs/retrieval.md, "Initial poses", has the figures.)
    """
    model = np.asarray(model, dtype=np.float64)
    theta = rng.uniform(0.0, 2.0 * np.pi, n)
    lo, hi = model.min(axis=0), model.max(axis=0)
    anchor = lo + rng.uniform(0.0, 1.0, (n, 2)) * (hi - lo)
    c = np.asarray(points, dtype=np.float64).mean(axis=0)
    t = anchor - rotate(np.broadcast_to(c, (n, 2)), theta)
    return np.column_stack([t, theta])


def icp_error(world_to_model: np.ndarray, points: np.ndarray, model: np.ndarray,
              normals: np.ndarray | None = None) -> np.ndarray:
    """ICP matching error (B,) of points (M, 2) moved by transforms (B, 3), root mean square over the points.

    Without ``normals``: the distance to the nearest model point (N, 2), what point-to-point ICP minimises.
    With model ``normals`` (N, 2): the distance along the nearest model point's normal (what point-to-plane
    ICP minimises), but at least the distance to that point minus half the largest gap between neighbouring
    model points, so that a point slid past the end of a face (which the normal does not see) still counts.
    """
    moved = apply_pose(world_to_model, points)  # (B, M, 2): the transform applied like a pose
    diff = moved[:, :, None, :] - model[None, None, :, :]  # (B, M, N, 2)
    nearest = np.argmin(np.sum(diff ** 2, axis=-1), axis=2)  # (B, M)
    d = np.take_along_axis(diff, nearest[..., None, None], axis=2)[:, :, 0, :]  # (B, M, 2)
    if normals is None:
        r2 = np.sum(d ** 2, axis=-1)
    else:
        gaps = np.sqrt(np.sum((model[:, None, :] - model[None, :, :]) ** 2, axis=-1))
        np.fill_diagonal(gaps, np.inf)
        half_gap = 0.5 * float(gaps.min(axis=1).max()) if len(model) > 1 else 0.0
        along = np.abs(np.sum(d * np.asarray(normals)[nearest], axis=-1))
        r2 = np.maximum(along, np.linalg.norm(d, axis=-1) - half_gap) ** 2
    return np.sqrt(r2.mean(axis=1))


def _correspond(tree: cKDTree, moved: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Nearest model point of each moved point (B, M, 2) within ``radius``: (index (B, M), matched (B, M) bool)."""
    d, idx = tree.query(moved.reshape(-1, 2), k=1)
    idx = np.minimum(idx, tree.n - 1).reshape(moved.shape[:2])
    return idx, (d <= radius).reshape(moved.shape[:2])


def _fit_stats(moved: np.ndarray, target: np.ndarray, matched: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Open3D's fitness (matched share) and inlier RMSE (metres) of B restarts, each (B,)."""
    r2 = np.where(matched, np.sum((moved - target) ** 2, axis=-1), 0.0)
    n = matched.sum(axis=1)
    return n / matched.shape[1], np.sqrt(np.sum(r2, axis=1) / np.maximum(n, 1))


def _point_to_point(points: np.ndarray, target: np.ndarray, matched: np.ndarray) -> np.ndarray:
    """Closed-form rigid transforms (B, 3) (tx, ty, theta) taking points (M, 2) onto their matched targets
    (B, M, 2): the 2-D Kabsch/Umeyama solution, theta = atan2 of the summed cross and dot products."""
    w = matched.astype(np.float64)
    n = np.maximum(w.sum(axis=1), 1.0)[:, None]
    p_mean = np.sum(w[..., None] * points[None], axis=1) / n
    q_mean = np.sum(w[..., None] * target, axis=1) / n
    p = points[None] - p_mean[:, None, :]
    q = target - q_mean[:, None, :]
    cross = np.sum(w * (p[..., 0] * q[..., 1] - p[..., 1] * q[..., 0]), axis=1)
    dot = np.sum(w * (p[..., 0] * q[..., 0] + p[..., 1] * q[..., 1]), axis=1)
    theta = atan2(cross, dot)
    return np.column_stack([q_mean - rotate(p_mean, theta), theta])


def _point_to_plane_step(moved: np.ndarray, target: np.ndarray, normals: np.ndarray,
                         matched: np.ndarray) -> np.ndarray:
    """Linearised point-to-plane step (B, 3) (dx, dy, dtheta) for moved points (B, M, 2) against matched target
    points and their normals (B, M, 2): least squares of (p + dtheta (-p_y, p_x) + d - q) . n."""
    w = matched.astype(np.float64)
    nx, ny = normals[..., 0], normals[..., 1]
    r = (moved[..., 0] - target[..., 0]) * nx + (moved[..., 1] - target[..., 1]) * ny
    J = np.stack([nx, ny, moved[..., 0] * ny - moved[..., 1] * nx], axis=-1)  # (B, M, 3)
    wJ = J * w[..., None]
    H = np.sum(wJ[..., :, None] * J[..., None, :], axis=1) + 1e-12 * np.eye(3)
    g = np.sum(wJ * r[..., None], axis=1)
    return -solve_spd(H, g)


def _compose(step: np.ndarray, tf: np.ndarray) -> np.ndarray:
    """The transform (B, 3) of applying ``tf`` then the small transform ``step`` (B, 3) (dx, dy, dtheta)."""
    return np.column_stack([rotate(tf[:, :2], step[:, 2]) + step[:, :2], tf[:, 2] + step[:, 2]])


def _icp(points: np.ndarray, model: np.ndarray, tree: cKDTree, inits: np.ndarray, params: RetrievalParams,
         normals: np.ndarray | None) -> np.ndarray:
    """ICP iterations from transforms (B, 3): point-to-point, or point-to-plane with ``normals``; the final
    transforms (B, 3). Each restart stops on its own when fitness and inlier RMSE change by < 1e-9."""
    tf = inits.copy()
    radius = params.max_correspondence_distance

    def state(tf):
        moved = apply_pose(tf, points)
        idx, matched = _correspond(tree, moved, radius)
        return moved, idx, matched, _fit_stats(moved, model[idx], matched)

    moved, idx, matched, (fit, rmse) = state(tf)
    active = np.ones(len(tf), dtype=bool)
    for _ in range(params.max_iteration):
        a = np.flatnonzero(active)
        if not len(a):
            break
        # Only the restarts still moving are computed (every quantity is per restart, so the bits are those of
        # computing all of them); a converged restart keeps its transform.
        if normals is None:
            new = _point_to_point(points, model[idx[a]], matched[a])
        else:
            new = _compose(_point_to_plane_step(moved[a], model[idx[a]], normals[idx[a]], matched[a]), tf[a])
        # A restart without any correspondence does not move (Open3D's update is then the identity).
        new = np.where(matched[a].any(axis=1)[:, None], new, tf[a])
        moved2, idx2, matched2, (fit2, rmse2) = state(new)
        done = (np.abs(fit2 - fit[a]) < 1e-9) & (np.abs(rmse2 - rmse[a]) < 1e-9)
        tf[a], moved[a], idx[a], matched[a], fit[a], rmse[a] = new, moved2, idx2, matched2, fit2, rmse2
        active[a[done]] = False
    return tf


def icp_restarts(points: np.ndarray, model: np.ndarray, inits: np.ndarray, params: RetrievalParams,
                 normals: np.ndarray | None = None) -> IcpResult:
    """ICP of tracked points onto model points from each initial transform, batched over the restarts.

    Parameters
    ----------
    points : ndarray, shape (M, 2), metres
        The segment's tracked points (world), M >= 1.
    model : ndarray, shape (N, 2), metres
        Model points in the target's COM frame.
    inits : ndarray, shape (B, 3)
        Initial world -> model transforms (tx, ty, theta), e.g. from :func:`initial_transforms`.
    params : RetrievalParams
        ``estimation``: point-to-point, or ("point_to_plane") point-to-point followed by point-to-plane from
        its result.
    normals : ndarray, shape (N, 2), optional
        Outward unit normals of the model points (:func:`model_normals`); required for point-to-plane.

    Returns
    -------
    IcpResult
        A result leaving the points farther than ``max_point_distance`` (median) from the model points (slid
        off the model) is not used: point-to-plane falls back to its point-to-point start, otherwise the
        restart keeps its initial transform and is marked invalid. ``rmse`` is :func:`icp_error` of the
        estimator used.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    model = np.asarray(model, dtype=np.float64).reshape(-1, 2)
    inits = np.asarray(inits, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        raise ValueError("icp_restarts: a segment needs at least one point")
    plane = params.estimation == "point_to_plane"
    if plane and normals is None:
        raise ValueError("icp_restarts: point-to-plane ICP needs the model normals")
    tree = cKDTree(model)

    def on_model(tf: np.ndarray) -> np.ndarray:
        """(B,) bool: the median point lies within max_point_distance of a model point. Point-to-plane lets a
        few points slide along the tangent planes past the model's end (three points on a can slid hundreds
        of metres in a TC run): such a result fits no part of the model. (The median, so that one stray
        tracked point does not invalidate a segment.)"""
        moved = apply_pose(tf, points)
        d, _ = tree.query(moved.reshape(-1, 2), k=1)
        return np.all(np.isfinite(tf), axis=1) & (np.median(d.reshape(moved.shape[:2]), axis=1)
                                                  <= params.max_point_distance)

    p2p = _icp(points, model, tree, inits, params, None)
    ok = on_model(p2p)
    out = np.where(ok[:, None], p2p, inits)
    valid = ok.copy()
    if plane:
        # Point-to-point first (correspondences settle), then point-to-plane slides the points along the faces
        # past the 9 mm spacing of the model points; if that fails, keep the point-to-point result.
        start = np.where(ok[:, None], p2p, inits)
        p2l = _icp(points, model, tree, start, params, np.asarray(normals, dtype=np.float64))
        ok2 = on_model(p2l)
        out = np.where(ok2[:, None], p2l, out)
        valid |= ok2
    out[:, 2] = wrap_angle(out[:, 2])
    theta = out[:, 2]
    pos = -rotate(out[:, :2], theta, inverse=True)
    poses = np.column_stack([pos, wrap_angle(-theta)])
    rmse = icp_error(out, points, model, normals if plane else None)
    return IcpResult(world_to_model=out, poses=poses, rmse=rmse, valid=valid)
