"""Planar ICP of a segment's points onto the target's model points from many restarts (Open3D), never mirrored.

With every point at one height, Open3D's point-to-point ICP can return a rotation by pi about an in-plane axis,
a mirror image of the plane. Both clouds are given twice, at z = 0 and at z = h with h larger than the clouds:
correspondences never cross layers, the z-block of the cross-covariance dominates every in-plane singular
value, and Kabsch/Umeyama can only return a rotation about z with a proper in-plane part. Every result is still
projected to SE(2) and checked; one that is not a rotation about z is marked invalid (docs/retrieval.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.geometry import rot2, rots2, wrap_angle
from pipeline.retrieve.params import RetrievalParams

__all__ = ["IcpResult", "initial_transforms", "layer_height", "icp_error", "icp_restarts"]


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
        The Open3D result was a finite rotation about z (checked before projecting to SE(2)).
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
    t = anchor - np.einsum("bij,j->bi", rots2(theta), c)
    return np.column_stack([t, theta])


def _matrix(tf: np.ndarray) -> np.ndarray:
    """4x4 homogeneous matrix of a planar (tx, ty, theta)."""
    T = np.eye(4)
    T[:2, :2] = rot2(float(tf[2]))
    T[:2, 3] = tf[:2]
    return T


def _layered_cloud(pts: np.ndarray, h: float, normals: np.ndarray | None = None, floor: bool = False):
    """Open3D cloud of planar points (N, 2) copied at z = 0 and z = h (and z = -h with ``floor``); with
    ``normals`` (N, 2) the first two copies get them (horizontal) and the floor copy gets +z."""
    import open3d as o3d

    heights = (0.0, h, -h) if floor else (0.0, h)
    xyz = np.vstack([np.column_stack([pts, np.full(len(pts), z)]) for z in heights])
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
    if normals is not None:
        n3 = np.column_stack([normals, np.zeros(len(normals))])
        up = np.tile([0.0, 0.0, 1.0], (len(normals), 1))
        cloud.normals = o3d.utility.Vector3dVector(np.vstack([n3, n3] + ([up] if floor else [])))
    return cloud


def layer_height(points: np.ndarray, model: np.ndarray) -> float:
    """Height (m) of the second copy of both clouds.

    Point-to-point: the z-entry of the cross-covariance is M h^2 / 2 and every in-plane singular value is at
    most 2 M S T (S, T: largest distance of a point from its cloud's centroid), so h > 2 sqrt(S T) keeps the z
    axis the dominant, never-reflected direction; h = max(1, 4 (S + T)) >= 8 sqrt(S T) leaves a wide margin.
    Point-to-plane: the model normals are horizontal, so a tilt of the source would move its two layers
    differently and only add residual; the same h serves.
    """
    s = float(np.max(np.linalg.norm(points - points.mean(axis=0), axis=1))) if len(points) else 0.0
    t = float(np.max(np.linalg.norm(model - model.mean(axis=0), axis=1)))
    return max(1.0, 4.0 * (s + t))


def icp_error(world_to_model: np.ndarray, points: np.ndarray, model: np.ndarray,
              normals: np.ndarray | None = None) -> np.ndarray:
    """ICP matching error (B,) of points (M, 2) moved by transforms (B, 3), root mean square over the points.

    Without ``normals``: the distance to the nearest model point (N, 2), what point-to-point ICP minimises.
    With model ``normals`` (N, 2): the distance along the nearest model point's normal (what point-to-plane
    ICP minimises), but at least the distance to that point minus half the largest gap between neighbouring
    model points, so that a point slid past the end of a face (which the normal does not see) still counts.
    """
    moved = np.einsum("bij,mj->bmi", rots2(world_to_model[:, 2]), points) + world_to_model[:, None, :2]
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


def icp_restarts(points: np.ndarray, model: np.ndarray, inits: np.ndarray, params: RetrievalParams,
                 normals: np.ndarray | None = None) -> IcpResult:
    """ICP of tracked points onto model points from each initial transform (Open3D ``registration_icp``).

    Parameters
    ----------
    points : ndarray, shape (M, 2), metres
        The segment's tracked points (world), M >= 1.
    model : ndarray, shape (N, 2), metres
        Model points in the target's COM frame.
    inits : ndarray, shape (B, 3)
        Initial world -> model transforms (tx, ty, theta), e.g. from :func:`initial_transforms`.
    params : RetrievalParams
        ``estimation``: Open3D's point-to-point estimator, or ("point_to_plane") point-to-point followed by
        point-to-plane from its result.
    normals : ndarray, shape (N, 2), optional
        Outward unit normals of the model points (:func:`model_normals`); required for point-to-plane.

    Returns
    -------
    IcpResult
        Every result is a rotation about z: Open3D's 4x4 is checked (z-row (0, 0, 1, 0), finite, in-plane
        determinant > 0) and projected to SE(2). A result failing the check, or leaving the points farther than
        ``max_point_distance`` (median) from the model points (slid off the model), is not used: point-to-plane
        falls back to its point-to-point start, otherwise the restart keeps its initial transform and is
        marked invalid. ``rmse`` is :func:`icp_error` of the estimator used.
    """
    import open3d as o3d

    reg = o3d.pipelines.registration
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    model = np.asarray(model, dtype=np.float64).reshape(-1, 2)
    inits = np.asarray(inits, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        raise ValueError("icp_restarts: a segment needs at least one point")
    plane = params.estimation == "point_to_plane"
    if plane and normals is None:
        raise ValueError("icp_restarts: point-to-plane ICP needs the model normals")
    h = layer_height(points, model)
    source = _layered_cloud(points, h)
    # Point-to-plane with horizontal normals only leaves t_z (and with few points the tilts) unconstrained, and
    # Open3D's solve then returns tilted matrices (docs/retrieval.md, "Point-to-plane refinement"); a third copy
    # of both clouds at z = -h with vertical normals pins z and the tilts without touching the in-plane residuals.
    source_floor = _layered_cloud(points, h, floor=True) if plane else None
    p2p = reg.TransformationEstimationPointToPoint(with_scaling=False)
    p2p_target = _layered_cloud(model, h)
    p2l = reg.TransformationEstimationPointToPlane()
    p2l_target = _layered_cloud(model, h, normals, floor=True) if plane else None
    crit = reg.ICPConvergenceCriteria(relative_fitness=1e-9, relative_rmse=1e-9, max_iteration=params.max_iteration)

    def run(source, target, estimation, tf: np.ndarray) -> np.ndarray | None:
        """Planar (tx, ty, theta) Open3D converged to from tf, or None if its matrix is not a rotation about z
        (or leaves a point off the model)."""
        T = np.asarray(reg.registration_icp(source, target, params.max_correspondence_distance, _matrix(tf),
                                            estimation, crit).transformation)
        planar = (np.all(np.isfinite(T)) and abs(T[2, 2] - 1.0) < 1e-6 and abs(T[2, 3]) < 1e-6
                  and np.all(np.abs(T[2, :2]) < 1e-6) and np.all(np.abs(T[:2, 2]) < 1e-6)
                  and np.linalg.det(T[:2, :2]) > 0.0)
        if not planar:
            return None
        # Closest rotation to the 2x2 block (exactly it, up to rounding, for a proper planar result).
        got = np.array([T[0, 3], T[1, 3], math.atan2(T[1, 0] - T[0, 1], T[0, 0] + T[1, 1])])
        moved = points @ rot2(got[2]).T + got[:2]
        gap = np.median(np.sqrt(np.min(np.sum((moved[:, None, :] - model[None, :, :]) ** 2, axis=-1), axis=1)))
        # Point-to-plane lets a few points slide along the model's tangent planes past its end (three points on
        # a can slid hundreds of metres in a TC run): such a result fits no part of the model. (The median, so
        # that one stray tracked point does not invalidate a segment.)
        return got if gap <= params.max_point_distance else None

    out = inits.copy()
    valid = np.zeros(len(inits), dtype=bool)
    for b, tf in enumerate(inits):
        got = run(source, p2p_target, p2p, tf)
        if plane:
            # Point-to-point first (correspondences settle), then point-to-plane slides the points along the
            # faces past the 9 mm spacing of the model points; if that fails, keep the point-to-point result.
            refined = run(source_floor, p2l_target, p2l, got if got is not None else tf)
            got = refined if refined is not None else got
        if got is not None:
            out[b] = got
            valid[b] = True
    theta = out[:, 2]
    pos = -np.einsum("bij,bj->bi", rots2(-theta), out[:, :2])
    poses = np.column_stack([pos, wrap_angle(-theta)])
    rmse = icp_error(out, points, model, normals if plane else None)
    return IcpResult(world_to_model=out, poses=poses, rmse=rmse, valid=valid)
