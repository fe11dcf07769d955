"""Planar ICP of a segment's points onto the target's model points from many restarts, in SE(2).

Point-to-point ICP as Open3D's ``registration_icp`` runs it (nearest model point within the correspondence
radius; the closed-form best rigid transform of the pairs; stop when fitness and inlier RMSE change by less than
1e-9 or after ``max_iteration``), optionally followed by point-to-plane ICP onto the model's normals (the
linearised step of Open3D's point-to-plane estimator, restricted to the plane). It is written here, in SE(2):
Open3D's ICP (its own TBB threads and SIMD kernels) did not give the same bits twice
on one machine, let alone across CPUs, and a 3-D ICP of planar points needs guarding against mirrored results.
The iterations and the nearest model points run in the compiled kernels of :mod:`pipeline.estimators.paper.icp_kernel`
(brute force over the ~50 model points, the distances scipy's cKDTree gave before); every sum runs in a fixed
order and every angle through the C library's scalar functions, so the result is the same on every x86-64 CPU
(docs/evaluation.md, "Same numbers on every machine").
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.estimators.paper.icp_kernel import icp_kernel, nearest_model
from pipeline.estimators.params import RetrievalParams
from pipeline.geometry import apply_pose, rotate, wrap_angle

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
    the surface, so their centroid is never the centre; docs/retrieval.md, "Deviations from the paper", has the
    figures.)
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
    nearest, _ = nearest_model(np.ascontiguousarray(moved), np.ascontiguousarray(model))  # (B, M)
    d = moved - model[nearest]  # (B, M, 2)
    if normals is None:
        r2 = np.sum(d ** 2, axis=-1)
    else:
        gaps = np.sqrt(np.sum((model[:, None, :] - model[None, :, :]) ** 2, axis=-1))
        np.fill_diagonal(gaps, np.inf)
        half_gap = 0.5 * float(gaps.min(axis=1).max()) if len(model) > 1 else 0.0
        along = np.abs(np.sum(d * np.asarray(normals)[nearest], axis=-1))
        r2 = np.maximum(along, np.linalg.norm(d, axis=-1) - half_gap) ** 2
    return np.sqrt(r2.mean(axis=1))


def _icp(points: np.ndarray, model: np.ndarray, inits: np.ndarray, params: RetrievalParams,
         normals: np.ndarray | None) -> np.ndarray:
    """ICP iterations from transforms (B, 3): point-to-point, or point-to-plane with ``normals``; the final
    transforms (B, 3). Each restart stops on its own when fitness and inlier RMSE change by < 1e-9. The
    iterations run in :func:`pipeline.estimators.paper.icp_kernel.icp_kernel`, one restart at a time (restarts are
    independent), with the arithmetic of the batched numpy form kept in ``tests/test_icp_kernel.py``."""
    plane = normals is not None
    return icp_kernel(np.ascontiguousarray(points), np.ascontiguousarray(model),
                      np.ascontiguousarray(normals) if plane else np.zeros((1, 2)), np.ascontiguousarray(inits),
                      float(params.max_correspondence_distance), int(params.max_iteration), plane)


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

    def on_model(tf: np.ndarray) -> np.ndarray:
        """(B,) bool: the median point lies within max_point_distance of a model point. Point-to-plane lets a
        few points slide along the tangent planes past the model's end (three points on a can slid hundreds
        of metres in a TC run): such a result fits no part of the model. (The median, so that one stray
        tracked point does not invalidate a segment.)"""
        moved = apply_pose(tf, points)
        _, d2 = nearest_model(moved, model)
        # The distance as scipy's cKDTree computes it (inf for a point that is not finite).
        d = np.where(np.isfinite(d2), np.sqrt(np.where(np.isfinite(d2), d2, 0.0)), np.inf)
        return np.all(np.isfinite(tf), axis=1) & (np.median(d, axis=1) <= params.max_point_distance)

    p2p = _icp(points, model, inits, params, None)
    ok = on_model(p2p)
    out = np.where(ok[:, None], p2p, inits)
    valid = ok.copy()
    if plane:
        # Point-to-point first (correspondences settle), then point-to-plane slides the points along the faces
        # past the 9 mm spacing of the model points; if that fails, keep the point-to-point result.
        start = np.where(ok[:, None], p2p, inits)
        p2l = _icp(points, model, start, params, np.asarray(normals, dtype=np.float64).reshape(-1, 2))
        ok2 = on_model(p2l)
        out = np.where(ok2[:, None], p2l, out)
        valid |= ok2
    out[:, 2] = wrap_angle(out[:, 2])
    theta = out[:, 2]
    pos = -rotate(out[:, :2], theta, inverse=True)
    poses = np.column_stack([pos, wrap_angle(-theta)])
    rmse = icp_error(out, points, model, normals if plane else None)
    return IcpResult(world_to_model=out, poses=poses, rmse=rmse, valid=valid)
