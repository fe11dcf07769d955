"""Blind object retrieval, pose estimation: segments of tracked contact points -> the target's planar pose.

The paper's §V-C (REFERENCE_SPEC §6.4-6.5): for every segment of the final segmentation of a run, ICP between
the segment's tracked points and model points sampled from the known target surface (50 on a box outline, 49
evenly around a can), from 30 random initial poses. The segment whose restarts agree best (lowest variance of
the estimated position) is the target; among its 30 estimates the one that penetrates the gripper's visited
poses least (pxpen of the transformed model points against every end-effector position of the run) wins, ties
broken by the lowest ICP error (the paper's rule; the authors' code took the first index instead).

ICP is Open3D's ``registration_icp`` (its KD-tree does the correspondences), point-to-plane onto the model
points with their analytic normals by default, point-to-point (the authors' kind) on request. The problem is
planar, and with every point at one height Open3D's point-to-point ICP can return a rotation by pi about an
in-plane axis, i.e. a mirror image of the plane (ECOSYSTEM §B3; reproduced in ``tests/test_retrieve.py``).
Here both clouds are given twice, at z = 0 and at z = h with h larger than the clouds: correspondences never
cross layers (the two layers hold the same (x, y) sets), the z-block of the cross-covariance then dominates
every in-plane singular value, and Kabsch/Umeyama can only return a rotation about z with a proper (det +1)
in-plane part. Every result is still projected to SE(2) and checked (z-row (0, 0, 1, 0), det > 0); one that
is not is marked invalid instead of being used.

Kernels are pure functions on arrays (:func:`model_points`, :func:`icp_restarts`, :func:`min_clearance`,
:func:`choose`); :func:`estimate_run` runs them for one run and :func:`retrieve` for a segments table and a
directory of collected runs, writing the ``retrieval`` table (one row per run) and the ``candidates`` table
(one row per run, segment and restart). Poses are the target's inertial (COM) frame ``(x, y, yaw)``, the frame
of the recorded ``obj_pose``; positions compared across symmetric poses use the centre of the primitive.
Deviations from the paper and the authors' code are listed in docs/retrieval.md.
"""
from __future__ import annotations

import hashlib
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import pyarrow as pa

from pipeline import schema

__all__ = [
    "RetrievalParams",
    "Primitive",
    "primitive_of",
    "target_primitive",
    "model_points",
    "model_normals",
    "IcpResult",
    "icp_error",
    "layer_height",
    "icp_restarts",
    "initial_transforms",
    "min_clearance",
    "Choice",
    "choose",
    "confidence_notes",
    "RunInfo",
    "load_run",
    "run_files_by_name",
    "Estimate",
    "estimate_run",
    "retrieve",
    "retrieval_table",
    "candidates_table",
    "final_segments_by_run",
    "pose_error",
    "wrap_angle",
    "retrieval_rng",
    "RETRIEVAL_COLUMNS",
    "CANDIDATES_COLUMNS",
    "RETRIEVAL",
    "CANDIDATES",
    "validate_retrieval",
    "validate_candidates",
    "read_retrieval",
]


# ---------------------------------------------------------------------------------------------------------------
# Parameters
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RetrievalParams:
    """Parameters of pose estimation (paper §V-C, REFERENCE_SPEC §6.4-6.5); serialised into the metadata.

    Attributes
    ----------
    n_restarts : int
        ICP restarts per segment (30).
    estimation : {"point_to_plane", "point_to_point"}
        Open3D estimator. The authors' ICP was point-to-point; with 50 model points ~9 mm apart it locks
        every tracked point to a model point and stops one spacing away from the truth (on FB seed 0's box,
        1 of 30 restarts within 5 mm and 0.05 rad), while point-to-plane onto the same points with their
        analytic normals slides along the faces (19 of 30, 0.2 mm). "point_to_plane" (default) runs
        point-to-point, then point-to-plane from its result, keeping the point-to-point result when the
        refinement slides off the model.
    n_box_points, n_can_points : int
        Model points on a box outline (50) and around a can (49: 50 evenly spaced angles on [0, 2 pi], the
        duplicate end dropped, as the authors' ``sample_in_order``).
    box_sampling : {"perimeter", "tester"}
        "perimeter": evenly spaced along the outline from a random start (every face gets its share).
        "tester": the authors' rule (testers ~ N(0, tester_sigma^2) projected onto the outline, rejected within
        min_separation of an accepted point), which puts about 40 of 50 points on the long faces and most of
        the rest at the corners, leaving the short faces nearly empty.
    tester_sigma : float, metres
        "tester" sampling spread (0.1).
    min_separation : float, metres
        "tester" sampling separation (0.002).
    max_iteration : int
        ICP iterations per restart (Open3D's default 30; the authors stopped at 20).
    max_correspondence_distance : float, metres
        Open3D's correspondence radius; large, so every tracked point gets its nearest model point like the
        authors' all-pairs matching.
    max_point_distance : float, metres
        An ICP result whose points are farther than this (median) from the model points is not used (0.05):
        with few points, point-to-plane ICP can slide them along tangent planes off the model.
    penetration_tolerance : float, metres
        Penetration of the gripper's visited poses up to this depth counts as none when choosing (ties then
        go to the lowest ICP error), and a chosen pose penetrating deeper is flagged "penetrating" (0.01).
        Not the tracker's 2 mm: objects move and tilt after the gripper has been somewhere, and the planar
        pose cannot show it. The 10 kg cracker box tilts when pushed at the gripper's height (tipping moment
        3.0 N m against 3.1 N m restoring), the run files keep only (x, y, yaw), and the true final pose of
        FB seed 0 reads 8-9 mm inside gripper poses visited while it was tilted; with 2 mm, poses that fit
        the contacts badly but touch no visited pose (12 mm RMSE, 5 cm off) beat the true pose.
    agreement_tolerance : float or None, metres
        The position variance that picks the segment is over the restarts whose ICP error is within this of
        the segment's best (0.002); None: over all 30, as the paper. Restarts that stopped in another local
        minimum say nothing about where the object is, yet dominate the variance of all 30: on FB seeds
        0-9 with ideal contact points (docs/retrieval.md) the pose came within 2 cm and 0.2 rad in 6 of 10
        runs with 0.002 and in 3 of 10 with None (the can's segment chosen instead); on STUCCO's segments
        5 of 10 either way.
    segment_fit_gate : float, metres
        A segment whose best restart has an ICP error above this cannot be the target while another segment
        fits (0.02). Not in the paper: a straight run of points (a wall, a segment far from the target) fits
        one side of a box the same way from every restart, so its position variance is the lowest.
    robot : str
        Gripper grid for pxpen (:func:`pipeline.robot.load_robot`).
    min_points : int
        Fewer points in the chosen segment -> low confidence ("few_points").
    collinear_tolerance : float, metres
        Chosen segment whose smallest principal standard deviation is below this -> "collinear" (a pose
        from points on one line can slide along it).
    max_rmse : float, metres
        Chosen pose with a larger ICP RMSE -> "poor_fit" (points that are not on the target's shape).
    """

    n_restarts: int = 30
    estimation: str = "point_to_plane"
    n_box_points: int = 50
    n_can_points: int = 49
    box_sampling: str = "perimeter"
    tester_sigma: float = 0.1
    min_separation: float = 0.002
    max_iteration: int = 30
    max_correspondence_distance: float = 1.0
    max_point_distance: float = 0.05
    penetration_tolerance: float = 0.01
    agreement_tolerance: float | None = 0.002
    segment_fit_gate: float = 0.02
    robot: str = "panda"
    min_points: int = 3
    collinear_tolerance: float = 0.002
    max_rmse: float = 0.005

    def __post_init__(self) -> None:
        for name in ("n_restarts", "n_box_points", "n_can_points", "max_iteration", "min_points"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        if self.estimation not in ("point_to_plane", "point_to_point"):
            raise ValueError(f"estimation must be 'point_to_plane' or 'point_to_point', got {self.estimation!r}")
        if self.box_sampling not in ("perimeter", "tester"):
            raise ValueError(f"box_sampling must be 'perimeter' or 'tester', got {self.box_sampling!r}")
        for name in ("tester_sigma", "max_correspondence_distance", "max_rmse", "segment_fit_gate",
                     "max_point_distance"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number (metres), got {v!r}")
        if self.agreement_tolerance is not None and not (math.isfinite(self.agreement_tolerance)
                                                         and self.agreement_tolerance >= 0):
            raise ValueError(f"agreement_tolerance must be None or a non-negative number (metres), "
                             f"got {self.agreement_tolerance!r}")
        for name in ("min_separation", "penetration_tolerance", "collinear_tolerance"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a non-negative number (metres), got {v!r}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


# ---------------------------------------------------------------------------------------------------------------
# Planar geometry
# ---------------------------------------------------------------------------------------------------------------


def wrap_angle(a):
    """Angle(s) wrapped to [-pi, pi)."""
    return (np.asarray(a, dtype=np.float64) + np.pi) % (2.0 * np.pi) - np.pi


def _rot(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s], [s, c]])


def _rots(yaw: np.ndarray) -> np.ndarray:
    """Rotation matrices, shape (..., 2, 2), of angles (...)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def _apply(pose: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """World coordinates of frame points: pose (..., 3) as (x, y, yaw), pts (..., N, 2) -> (..., N, 2)."""
    pose = np.asarray(pose, dtype=np.float64)
    R = _rots(pose[..., 2])
    return np.einsum("...ij,...nj->...ni", R, pts) + pose[..., None, :2]


@dataclass(frozen=True)
class Primitive:
    """A box or upright cylinder in its body's inertial (COM) frame: the horizontal slice at contact height.

    Boxes and upright cylinders have the same cross-section at every height they span, so the slice at the
    gripper plane (z = 0.1 m) is the whole shape for contact purposes (REFERENCE_SPEC §1.3).

    Attributes
    ----------
    kind : {"box", "cylinder"}
    half : tuple of float, metres
        Box: half extents (hx, hy) along the primitive's axes. Cylinder: (radius,).
    centre : ndarray, shape (2,), metres
        Primitive centre in the COM frame.
    yaw : float, radians
        Primitive axes in the COM frame.
    name : str
    """

    kind: str
    half: tuple[float, ...]
    centre: np.ndarray
    yaw: float = 0.0
    name: str = ""

    @property
    def symmetry(self) -> float:
        """Smallest rotation (rad) about the centre that maps the shape onto itself: pi for a box (pi/2 if
        square), 0 for a cylinder, meaning any rotation."""
        if self.kind == "cylinder":
            return 0.0
        return math.pi / 2 if abs(self.half[0] - self.half[1]) < 1e-9 else math.pi

    def centre_world(self, pose: np.ndarray) -> np.ndarray:
        """World position (..., 2) of the primitive centre for COM poses (..., 3)."""
        pose = np.asarray(pose, dtype=np.float64)
        return np.einsum("...ij,j->...i", _rots(pose[..., 2]), self.centre) + pose[..., :2]

    def signed_distance(self, points: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """Signed distance (m, negative inside) of world points (N, 2) to the primitive at COM pose (3,)."""
        pose = np.asarray(pose, dtype=np.float64)
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        q = (pts - self.centre_world(pose)) @ _rot(float(pose[2]) + self.yaw)
        if self.kind == "cylinder":
            return np.linalg.norm(q, axis=1) - self.half[0]
        d = np.abs(q) - np.asarray(self.half[:2])
        outside = np.linalg.norm(np.maximum(d, 0.0), axis=1)
        inside = np.minimum(np.max(d, axis=1), 0.0)
        return outside + inside

    def canonical(self, pose: np.ndarray) -> np.ndarray:
        """The representative of a COM pose (3,) under the shape's symmetry.

        Rotations about the primitive centre (not the COM) map the shape onto itself: a box's yaw is brought
        into [-pi/2, pi/2) by a half turn about its centre, a cylinder's yaw is set to 0 keeping its centre.
        """
        pose = np.array(pose, dtype=np.float64)
        c = self.centre_world(pose)
        if self.kind == "cylinder":
            yaw = 0.0
        else:
            sym = self.symmetry
            yaw = float((pose[2] + sym / 2) % sym - sym / 2)
        xy = c - _rot(yaw) @ self.centre
        return np.array([xy[0], xy[1], yaw])


def primitive_of(spec) -> Primitive:
    """The :class:`Primitive` of a scene object (:class:`pipeline.scenes.ObjectSpec`) or wall
    (:class:`pipeline.scenes.WallSpec`), in the frame whose pose the run files record.

    Objects: the primitive sits at ``shape_offset``/``shape_yaw`` in the link frame and the recorded frame is the
    inertial one at ``com_offset``/``com_yaw``, so centre = R(-com_yaw) (shape_offset - com_offset_xy) and yaw =
    shape_yaw - com_yaw. Walls have no offsets (their recorded pose is their centre).
    """
    kind = getattr(spec, "shape", "box")
    if kind not in ("box", "cylinder"):
        raise ValueError(f"object {spec.name!r}: shape {kind!r} is not a box or cylinder")
    if getattr(spec, "rp", (0.0, 0.0)) != (0.0, 0.0):
        raise ValueError(f"object {spec.name!r}: only upright primitives have a constant horizontal slice")
    half = (spec.size[0],) if kind == "cylinder" else (spec.size[0] / 2.0, spec.size[1] / 2.0)
    so = np.asarray(getattr(spec, "shape_offset", (0.0, 0.0)), dtype=np.float64)
    com = np.asarray(getattr(spec, "com_offset", (0.0, 0.0, 0.0))[:2], dtype=np.float64)
    com_yaw = float(getattr(spec, "com_yaw", 0.0))
    centre = _rot(-com_yaw) @ (so - com)
    return Primitive(kind=kind, half=tuple(float(h) for h in half), centre=centre,
                     yaw=float(getattr(spec, "shape_yaw", 0.0)) - com_yaw, name=spec.name)


def target_primitive(scene) -> tuple[int, Primitive]:
    """(object id, primitive) of a scene's target; ValueError if the scene has none."""
    for i, o in enumerate(scene.objects):
        if o.target:
            return i, primitive_of(o)
    raise ValueError(f"{scene.path}: scene {scene.name} has no target object (target = true)")


def model_points(prim: Primitive, params: RetrievalParams, rng: np.random.Generator) -> np.ndarray:
    """Model points on the target's surface at contact height, in its COM frame (REFERENCE_SPEC §6.4).

    Box: testers (x, y) ~ N(0, sigma^2) about the primitive centre, each projected onto the closest point of
    the outline and rejected if within ``min_separation`` of an accepted point, until ``n_box_points``.
    Cylinder: ``n_can_points`` evenly spaced angles (no randomness).

    Returns
    -------
    ndarray, shape (N, 2), metres
    """
    if prim.kind == "cylinder":
        n = params.n_can_points
        ang = np.linspace(0.0, 2.0 * np.pi, n + 1)[:-1]
        local = prim.half[0] * np.column_stack([np.cos(ang), np.sin(ang)])
    elif params.box_sampling == "perimeter":
        hx, hy = prim.half
        n = params.n_box_points
        perimeter = 4.0 * (hx + hy)
        s = (rng.uniform(0.0, 1.0) + np.arange(n)) * (perimeter / n)
        local = _outline_point(s, hx, hy)
    else:
        hx, hy = prim.half
        n = params.n_box_points
        accepted: list[np.ndarray] = []
        sep2 = params.min_separation ** 2
        for _ in range(1000):
            t = rng.normal(0.0, params.tester_sigma, size=(4 * n, 2))
            for q in _project_to_outline(t, hx, hy):
                if all(np.sum((q - a) ** 2) >= sep2 for a in accepted):
                    accepted.append(q)
                    if len(accepted) == n:
                        break
            if len(accepted) == n:
                break
        else:  # pragma: no cover - only with an absurd separation for the box size
            raise ValueError(f"cannot place {n} model points {params.min_separation} m apart on a "
                             f"{2 * hx} x {2 * hy} m outline")
        local = np.array(accepted)
    return local @ _rot(prim.yaw).T + prim.centre


def _outline_point(s: np.ndarray, hx: float, hy: float) -> np.ndarray:
    """Points (N, 2) at arc lengths s (N,) along the outline of [-hx, hx] x [-hy, hy], counter-clockwise from
    (hx, -hy)."""
    s = np.asarray(s, dtype=np.float64) % (4.0 * (hx + hy))
    edges = np.cumsum([0.0, 2 * hy, 2 * hx, 2 * hy, 2 * hx])
    out = np.empty((len(s), 2))
    for k, (start, (x0, y0), (dx, dy)) in enumerate(zip(
            edges[:4], ((hx, -hy), (hx, hy), (-hx, hy), (-hx, -hy)), ((0, 1), (-1, 0), (0, -1), (1, 0)))):
        m = (s >= start) & (s < edges[k + 1])
        u = s[m] - start
        out[m, 0] = x0 + dx * u
        out[m, 1] = y0 + dy * u
    return out


def _project_to_outline(t: np.ndarray, hx: float, hy: float) -> np.ndarray:
    """Closest points on the outline of the rectangle [-hx, hx] x [-hy, hy] to points t (N, 2)."""
    q = np.clip(t, [-hx, -hy], [hx, hy])
    inside = (np.abs(t[:, 0]) < hx) & (np.abs(t[:, 1]) < hy)
    to_x = (hx - np.abs(t[:, 0])) <= (hy - np.abs(t[:, 1]))
    sx = np.where(t[:, 0] >= 0, 1.0, -1.0)
    sy = np.where(t[:, 1] >= 0, 1.0, -1.0)
    q[inside & to_x, 0] = (sx * hx)[inside & to_x]
    q[inside & ~to_x, 1] = (sy * hy)[inside & ~to_x]
    return q


def model_normals(prim: Primitive, model: np.ndarray) -> np.ndarray:
    """Outward unit normals (N, 2) of the primitive's outline at model points (N, 2) given in the COM frame.

    Box: the normal of the nearest side (x sides on ties, i.e. at exact corners); cylinder: radial.
    """
    q = (np.asarray(model, dtype=np.float64) - prim.centre) @ _rot(prim.yaw)
    if prim.kind == "cylinder":
        n = q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-12)
    else:
        hx, hy = prim.half
        on_x = (hx - np.abs(q[:, 0])) <= (hy - np.abs(q[:, 1]))
        n = np.zeros_like(q)
        n[on_x, 0] = np.where(q[on_x, 0] >= 0, 1.0, -1.0)
        n[~on_x, 1] = np.where(q[~on_x, 1] >= 0, 1.0, -1.0)
    return n @ _rot(prim.yaw).T


# ---------------------------------------------------------------------------------------------------------------
# ICP
# ---------------------------------------------------------------------------------------------------------------


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
    the surface, so their centroid is never the centre, and on the stored FB run no restart from the centre
    reached the true pose, against 5-9 of 30 from random points of the bounding box.)
    """
    model = np.asarray(model, dtype=np.float64)
    theta = rng.uniform(0.0, 2.0 * np.pi, n)
    lo, hi = model.min(axis=0), model.max(axis=0)
    anchor = lo + rng.uniform(0.0, 1.0, (n, 2)) * (hi - lo)
    c = np.asarray(points, dtype=np.float64).mean(axis=0)
    t = anchor - np.einsum("bij,j->bi", _rots(theta), c)
    return np.column_stack([t, theta])


def _matrix(tf: np.ndarray) -> np.ndarray:
    """4x4 homogeneous matrix of a planar (tx, ty, theta)."""
    T = np.eye(4)
    T[:2, :2] = _rot(float(tf[2]))
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
    moved = np.einsum("bij,mj->bmi", _rots(world_to_model[:, 2]), points) + world_to_model[:, None, :2]
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
    # Open3D's solve then returned tilted matrices in 79 of 1470 refinements on FB/TC runs; a third copy of
    # both clouds at z = -h with vertical normals pins z and the tilts without touching the in-plane residuals.
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
        moved = points @ _rot(got[2]).T + got[:2]
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
    pos = -np.einsum("bij,bj->bi", _rots(-theta), out[:, :2])
    poses = np.column_stack([pos, wrap_angle(-theta)])
    rmse = icp_error(out, points, model, normals if plane else None)
    return IcpResult(world_to_model=out, poses=poses, rmse=rmse, valid=valid)


# ---------------------------------------------------------------------------------------------------------------
# Scoring and choice
# ---------------------------------------------------------------------------------------------------------------


def min_clearance(sdf, model: np.ndarray, poses: np.ndarray, ee: np.ndarray) -> np.ndarray:
    """Smallest pxpen of the posed model points against every visited gripper position.

    Parameters
    ----------
    sdf : pipeline.robot.GridSDF
        The gripper grid; pxpen(x, p) = sdf.query(p - x).
    model : ndarray, shape (N, 2)
        Model points, COM frame.
    poses : ndarray, shape (B, 3)
        Candidate object poses.
    ee : ndarray, shape (K, 2)
        Gripper positions visited in the run.

    Returns
    -------
    ndarray, shape (B,), metres
        min over (k, n) of sdf(pose(model_n) - ee_k); negative = the pose penetrates the gripper somewhere it
        has been; ``sdf.outside_value`` when no model point comes near any gripper position.
    """
    world = _apply(np.asarray(poses, dtype=np.float64), np.asarray(model, dtype=np.float64))  # (B, N, 2)
    ee = np.asarray(ee, dtype=np.float64).reshape(-1, 2)
    if len(ee) == 0 or world.shape[0] == 0:
        return np.full(world.shape[0], float(sdf.outside_value))
    vals = sdf.query(world[:, :, None, :] - ee[None, None, :, :])  # (B, N, K)
    return vals.reshape(len(world), -1).min(axis=1)


@dataclass(frozen=True)
class Choice:
    """Which segment and which restart the selection rule picked.

    Attributes
    ----------
    segment_index : int
        Index into the list of segments given to :func:`choose` (-1 if none).
    restart : int
        Restart of that segment (-1 if none).
    position_var : ndarray, shape (S,), m^2
        Per segment: unbiased variance of the restarts' estimated positions (x plus y), over the valid
        restarts that agree (see :func:`choose`); inf when fewer than 2 are valid.
    rank : list of ndarray
        Per segment, each restart's rank under (excess penetration, ICP RMSE) (0 = best; invalid last).
    """

    segment_index: int
    restart: int
    position_var: np.ndarray
    rank: list[np.ndarray]


def choose(centres: Sequence[np.ndarray], penetration: Sequence[np.ndarray], rmse: Sequence[np.ndarray],
           valid: Sequence[np.ndarray], tolerance: float, fit_gate: float | None = None,
           agreement: float | None = None) -> Choice:
    """The paper's selection rule over S segments of B restarts each.

    1. The segment with the lowest variance of the estimated positions (``centres``) wins; ties go to the
       segment listed first. The variance is over the valid restarts, or with ``agreement`` over those whose
       ICP error is within ``agreement`` of the segment's best (all valid ones if fewer than two are). With
       ``fit_gate``, only segments whose best valid restart has an ICP error <= fit_gate compete, unless none
       has.
    2. Within it, the restart that penetrates the visited gripper poses least: excess penetration
       max(0, penetration - tolerance), then on ties the lowest ICP error, then the lowest restart index.

    Parameters
    ----------
    centres : sequence of ndarray, shape (B, 2)
        Estimated positions (of the primitive centre, so a symmetric shape's arbitrary yaw adds no variance).
    penetration : sequence of ndarray, shape (B,), metres
        max(0, -min_clearance).
    rmse : sequence of ndarray, shape (B,)
        ICP error of each restart.
    valid : sequence of ndarray, shape (B,), bool
    tolerance : float, metres
    fit_gate : float or None, metres
    agreement : float or None, metres
    """
    var = np.full(len(centres), np.inf)
    best_err = np.full(len(centres), np.inf)
    ranks = []
    for s, (c, pen, err, ok) in enumerate(zip(centres, penetration, rmse, valid)):
        ok = np.asarray(ok, dtype=bool)
        if ok.any():
            best_err[s] = float(np.min(np.asarray(err)[ok]))
        use = ok
        if agreement is not None and ok.any():
            near = ok & (np.asarray(err) <= best_err[s] + agreement)
            use = near if near.sum() >= 2 else ok
        if use.sum() >= 2:
            var[s] = float(np.var(np.asarray(c)[use], axis=0, ddof=1).sum())
        excess = np.maximum(np.asarray(pen) - tolerance, 0.0)
        key0 = np.where(ok, excess, np.inf)
        order = np.lexsort((np.arange(len(ok)), np.where(ok, err, np.inf), key0))
        rank = np.empty(len(ok), dtype=np.int64)
        rank[order] = np.arange(len(ok))
        ranks.append(rank)
    if not len(centres):
        return Choice(-1, -1, var, ranks)
    eligible = np.isfinite(best_err)
    if fit_gate is not None and np.any(best_err <= fit_gate):
        eligible &= best_err <= fit_gate
    pool = np.where(eligible, var, np.inf)
    if np.isfinite(pool).any():
        s_best = int(np.flatnonzero(pool == pool[np.isfinite(pool)].min())[0])
    elif eligible.any():
        # No eligible segment has two valid restarts: the first with any valid one.
        s_best = int(np.flatnonzero(eligible)[0])
    else:
        s_best = 0
    return Choice(s_best, int(np.argmin(ranks[s_best])), var, ranks)


def confidence_notes(points: np.ndarray | None, rmse: float, penetration: float, params: RetrievalParams) -> list[str]:
    """Why an estimate should not be trusted (empty list: confident).

    ``no_points`` (empty segmentation), ``few_points`` (fewer than ``min_points``), ``collinear`` (smallest
    principal standard deviation below ``collinear_tolerance``: the pose can slide along the line),
    ``poor_fit`` (ICP RMSE above ``max_rmse``: the points are not on the target's shape, e.g. a segment of
    another object), ``penetrating`` (the chosen pose penetrates a visited gripper pose deeper than
    ``penetration_tolerance``).
    """
    if points is None or len(points) == 0:
        return ["no_points"]
    notes: list[str] = []
    if len(points) < params.min_points:
        notes.append("few_points")
    if len(points) >= 2:
        sv = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
        if sv[-1] / math.sqrt(len(points)) < params.collinear_tolerance:
            notes.append("collinear")
    if not (rmse <= params.max_rmse):
        notes.append("poor_fit")
    if penetration > params.penetration_tolerance:
        notes.append("penetrating")
    return notes


# ---------------------------------------------------------------------------------------------------------------
# Runs
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class RunInfo:
    """What retrieval and scoring need from a collected run file (``sim_run`` table, docs/simulation.md).

    Attributes
    ----------
    run : str
    path : Path
    scene : pipeline.scenes.Scene
    seed : int
    ee : ndarray, shape (K + 1, 2), metres
        Gripper positions visited: the start of the first action, then the end of every action.
    final_poses : ndarray, shape (B, 3)
        Every body's inertial-frame (x, y, yaw) after the last action, in ``scene.body_names`` order.
    target_id : int
    target : Primitive
    """

    run: str
    path: Path
    scene: Any
    seed: int
    ee: np.ndarray
    final_poses: np.ndarray
    target_id: int
    target: Primitive

    @property
    def final_ee(self) -> np.ndarray:
        return self.ee[-1]

    @property
    def true_pose(self) -> np.ndarray:
        """The target's pose after the last action (3,)."""
        return self.final_poses[self.target_id]


def _read_run_table(path: Path, columns: list[str] | None = None) -> pa.Table:
    import pyarrow.parquet as pq

    if not path.is_file():
        raise schema.SchemaError(path, None, None, "file not found")
    try:
        return pq.read_table(path, columns=columns)
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError, OSError, KeyError) as e:
        raise schema.SchemaError(path, None, None, f"not a collected run file ({' '.join(str(e).split())})") from None


def load_run(path: str | Path) -> RunInfo:
    """Read a collected run file (one (scene, seed)); SchemaError naming the file and column on problems."""
    from pipeline.scenes import load_scene

    path = Path(path)
    need = ["run", "seed", "ee_start_x_m", "ee_start_y_m", "ee_x_m", "ee_y_m", "obj_pose"]
    import pyarrow.parquet as pq

    try:
        names = pq.read_schema(path).names if path.is_file() else []
    except (pa.ArrowInvalid, OSError) as e:
        raise schema.SchemaError(path, None, None, f"not a Parquet file ({' '.join(str(e).split())})") from None
    t = _read_run_table(path, [c for c in need if c in names])
    for c in need:
        if c not in t.column_names:
            raise schema.SchemaError(path, c, None, "missing; expected a collected run file (stucco collect)")
    if t.num_rows == 0:
        raise schema.SchemaError(path, None, None, "has no actions")
    meta = schema.read_metadata(path)
    params = meta.get("params") or {}
    scene_name = params.get("scene")
    if not scene_name:
        raise schema.SchemaError(path, None, None, "metadata has no params.scene; expected a file from stucco collect")
    scene = load_scene(scene_name)
    bodies = params.get("bodies")
    if bodies is not None and list(bodies) != list(scene.body_names):
        raise schema.SchemaError(path, "obj_pose", None, f"bodies {bodies} differ from scene {scene.name}'s "
                                                         f"{list(scene.body_names)}; was the scene file edited?")
    f64 = lambda c: np.asarray(t.column(c).to_numpy(zero_copy_only=False), dtype=np.float64)  # noqa: E731
    ee = np.vstack([[f64("ee_start_x_m")[0], f64("ee_start_y_m")[0]], np.column_stack([f64("ee_x_m"), f64("ee_y_m")])])
    final = np.asarray(t.column("obj_pose")[t.num_rows - 1].as_py(), dtype=np.float64).reshape(-1, 3)
    if final.shape[0] != len(scene.body_names):
        raise schema.SchemaError(path, "obj_pose", t.num_rows - 1,
                                 f"has {final.shape[0]} bodies; scene {scene.name} has {len(scene.body_names)}")
    tid, prim = target_primitive(scene)
    runs = set(t.column("run").to_pylist())
    if len(runs) != 1:
        raise schema.SchemaError(path, "run", None, f"holds {len(runs)} runs; expected one run per file")
    return RunInfo(run=runs.pop(), path=path, scene=scene, seed=int(t.column("seed")[0].as_py()), ee=ee,
                   final_poses=final, target_id=tid, target=prim)


def run_files_by_name(directory: str | Path) -> dict[str, Path]:
    """Run name -> collected run file, for every ``*.parquet`` in ``directory`` (non-recursive)."""
    import pyarrow.parquet as pq

    directory = Path(directory)
    if not directory.is_dir():
        raise ValueError(f"{directory}: not a directory of collected runs")
    out: dict[str, Path] = {}
    for f in sorted(directory.glob("*.parquet")):
        try:
            if "run" not in pq.read_schema(f).names or "obj_pose" not in pq.read_schema(f).names:
                continue  # another table kind living in the same directory
            runs = pq.read_table(f, columns=["run"]).column("run")
        except (pa.ArrowInvalid, OSError):
            continue
        if len(runs):
            name = runs[0].as_py()
            if name in out:
                raise ValueError(f"{directory}: run {name!r} is in both {out[name].name} and {f.name}")
            out[name] = f
    return out


def _run_key(run: str) -> int:
    # Same formula as pipeline.track.stage.run_key (sha256 of the name), without importing the tracker.
    return int.from_bytes(hashlib.sha256(run.encode("utf-8")).digest()[:8], "little")


#: Third entry of retrieval's SeedSequence: keeps its draws independent of the tracker's stream of the run.
_STREAM = int.from_bytes(hashlib.sha256(b"retrieve").digest()[:4], "little")


def retrieval_rng(seed: int, run: str) -> tuple[np.random.Generator, np.random.Generator]:
    """(model points, ICP restarts) generators of one run: SeedSequence([seed, run_key(run), STREAM]).spawn(2)."""
    a, b = np.random.SeedSequence([int(seed), _run_key(run), _STREAM]).spawn(2)
    return np.random.default_rng(a), np.random.default_rng(b)


# ---------------------------------------------------------------------------------------------------------------
# One run
# ---------------------------------------------------------------------------------------------------------------


@dataclass
class Estimate:
    """Pose estimate of one run and the candidates behind it.

    Attributes
    ----------
    pose : ndarray, shape (3,)
        Target COM pose (x, y, yaw), canonical under the target's symmetry; finite even without points (then
        the last gripper position, yaw 0, flagged ``no_points``).
    segment : int
        Chosen segment id (-1 if none).
    n_points, n_segments : int
    position_var : float, m^2
        Variance of the chosen segment's restart positions (inf if undefined).
    rmse, penetration : float, metres
    notes : list of str
        Low-confidence reasons (:func:`confidence_notes`).
    candidates : dict of ndarray
        Columns of the candidates table for this run.
    icp_s : float
        Wall time of model sampling, ICP, scoring and choice.
    """

    pose: np.ndarray
    segment: int
    n_points: int
    n_segments: int
    position_var: float
    rmse: float
    penetration: float
    notes: list[str]
    candidates: dict[str, np.ndarray]
    icp_s: float
    model: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    @property
    def low_confidence(self) -> bool:
        return bool(self.notes)


def estimate_run(segments: Sequence[tuple[int, np.ndarray]], target: Primitive, ee: np.ndarray, sdf,
                 params: RetrievalParams, rng_model: np.random.Generator, rng_restarts: np.random.Generator
                 ) -> Estimate:
    """Estimate the target pose from the segments of one run.

    Parameters
    ----------
    segments : sequence of (segment id, ndarray (M_s, 2))
        Final tracked points of each segment, world metres.
    target : Primitive
    ee : ndarray, shape (K, 2)
        Gripper positions visited in the run.
    sdf : GridSDF
        Gripper grid for pxpen.
    params : RetrievalParams
    rng_model, rng_restarts : numpy.random.Generator

    Returns
    -------
    Estimate
    """
    import open3d  # noqa: F401  (imported before the clock starts: the first import takes about a second)

    t0 = time.perf_counter()
    model = model_points(target, params, rng_model)
    normals = model_normals(target, model)
    ee = np.asarray(ee, dtype=np.float64).reshape(-1, 2)
    segs = [(int(s), np.asarray(p, dtype=np.float64).reshape(-1, 2)) for s, p in segments]
    segs = [(s, p) for s, p in segs if len(p) > 0]
    B = params.n_restarts
    results, centres, pens, rmses, valids = [], [], [], [], []
    for _, pts in segs:
        inits = initial_transforms(pts, model, B, rng_restarts)
        res = icp_restarts(pts, model, inits, params, normals)
        clear = min_clearance(sdf, model, res.poses, ee)
        results.append(res)
        centres.append(target.centre_world(res.poses))
        pens.append(np.maximum(-clear, 0.0))
        rmses.append(res.rmse)
        valids.append(res.valid)
    choice = choose(centres, pens, rmses, valids, params.penetration_tolerance, params.segment_fit_gate,
                    params.agreement_tolerance)
    cand: dict[str, list] = {k: [] for k in ("segment", "restart", "n_points", "x_m", "y_m", "yaw_rad",
                                             "icp_rmse_m", "penetration_m", "valid", "position_var_m2", "rank",
                                             "segment_chosen", "chosen")}
    for i, ((sid, pts), res) in enumerate(zip(segs, results)):
        cand["segment"].append(np.full(B, sid))
        cand["restart"].append(np.arange(B))
        cand["n_points"].append(np.full(B, len(pts)))
        cand["x_m"].append(res.poses[:, 0])
        cand["y_m"].append(res.poses[:, 1])
        cand["yaw_rad"].append(res.poses[:, 2])
        cand["icp_rmse_m"].append(res.rmse)
        cand["penetration_m"].append(pens[i])
        cand["valid"].append(res.valid)
        v = choice.position_var[i]
        cand["position_var_m2"].append(np.full(B, v if math.isfinite(v) else np.nan))
        cand["rank"].append(choice.rank[i])
        cand["segment_chosen"].append(np.full(B, i == choice.segment_index))
        cand["chosen"].append((np.arange(B) == choice.restart) & (i == choice.segment_index))
    candidates = {k: (np.concatenate(v) if v else np.zeros(0)) for k, v in cand.items()}
    if choice.segment_index < 0:
        pose = np.array([ee[-1, 0], ee[-1, 1], 0.0]) if len(ee) else np.zeros(3)
        return Estimate(pose=pose, segment=-1, n_points=0, n_segments=0, position_var=math.inf, rmse=math.nan,
                        penetration=0.0, notes=["no_points"], candidates=candidates,
                        icp_s=time.perf_counter() - t0, model=model)
    i, b = choice.segment_index, choice.restart
    pts = segs[i][1]
    pose = target.canonical(results[i].poses[b])
    rmse = float(rmses[i][b])
    pen = float(pens[i][b])
    var = float(choice.position_var[i])
    notes = confidence_notes(pts, rmse, pen, params)
    if not results[i].valid[b]:
        notes.append("no_valid_icp")
    return Estimate(pose=pose, segment=segs[i][0], n_points=len(pts), n_segments=len(segs), position_var=var,
                    rmse=rmse, penetration=pen, notes=notes, candidates=candidates, icp_s=time.perf_counter() - t0,
                    model=model)


def pose_error(target: Primitive, estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(position error m, yaw error rad) of an estimated COM pose against the true one.

    Position: distance between the estimated and true primitive centres (invariant under the shape's symmetry;
    differs from the COM distance by at most twice the COM-centre offset, 2.6 mm for the cracker box). Yaw:
    modulo the symmetry, pi for a box (result in [0, pi/2]), 0 for a cylinder.
    """
    est = np.asarray(estimate, dtype=np.float64)
    tru = np.asarray(truth, dtype=np.float64)
    pos = float(np.linalg.norm(target.centre_world(est) - target.centre_world(tru)))
    sym = target.symmetry
    if sym == 0.0:
        return pos, 0.0
    d = float((est[2] - tru[2]) % sym)
    return pos, min(d, sym - d)


# ---------------------------------------------------------------------------------------------------------------
# Tables
# ---------------------------------------------------------------------------------------------------------------

_C = schema.Column
_RUN = _C("run", pa.string(), "", False, "Run id '<scene>/<seed>' (as in the contacts, tracks, segments tables).")

RETRIEVAL_COLUMNS: tuple[schema.Column, ...] = (
    _RUN,
    _C("scene", pa.string(), "", False, "Scene of the run."),
    _C("seed", pa.int64(), "", False, "Run seed."),
    _C("method", pa.string(), "", False, "Tracking method that produced the segments."),
    _C("target", pa.string(), "", False, "Name of the target object."),
    _C("x_m", pa.float64(), "m", False, "Estimated target COM x (canonical under the target's symmetry).",
       finite=True),
    _C("y_m", pa.float64(), "m", False, "Estimated target COM y.", finite=True),
    _C("yaw_rad", pa.float64(), "rad", False, "Estimated target yaw: [-pi/2, pi/2) for a box, 0 for a can.",
       finite=True),
    _C("segment", pa.int64(), "", False, "Chosen segment (-1: none, the segmentation was empty).", minimum=-1),
    _C("n_points", pa.int64(), "", False, "Tracked points in the chosen segment.", minimum=0),
    _C("n_segments", pa.int64(), "", False, "Segments in the run's final segmentation.", minimum=0),
    _C("position_var_m2", pa.float64(), "m^2", True,
       "Unbiased variance (x + y) of the chosen segment's restart positions (those within agreement_tolerance "
       "of its best ICP error); null if undefined.", minimum=0.0),
    _C("icp_rmse_m", pa.float64(), "m", True, "ICP error of the chosen pose; null without points.", minimum=0.0),
    _C("penetration_m", pa.float64(), "m", False,
       "Deepest penetration of the chosen pose into a visited gripper pose (0: none).", finite=True, minimum=0.0),
    _C("low_confidence", pa.bool_(), "", False, "The estimate has a reason not to be trusted (see notes)."),
    _C("notes", pa.string(), "", False, "Comma-separated low-confidence reasons (no_points, few_points, "
       "collinear, poor_fit, penetrating, no_valid_icp); empty when confident."),
    _C("true_x_m", pa.float64(), "m", False, "True target COM x after the last action.", finite=True),
    _C("true_y_m", pa.float64(), "m", False, "True target COM y after the last action.", finite=True),
    _C("true_yaw_rad", pa.float64(), "rad", False, "True target yaw after the last action.", finite=True),
    _C("position_error_m", pa.float64(), "m", False, "Distance between estimated and true primitive centres.",
       finite=True, minimum=0.0),
    _C("yaw_error_rad", pa.float64(), "rad", False, "Yaw error modulo the target's symmetry (pi box, any can).",
       finite=True, minimum=0.0),
    _C("grasp_success", pa.bool_(), "", True, "Simulated grasp at the estimate succeeded (null: not simulated)."),
    _C("grasp_outcome", pa.string(), "", False, "Why the grasp succeeded or failed ('' if not simulated)."),
    _C("icp_s", pa.float64(), "s", False, "Wall time of model sampling, ICP, scoring and choice.", finite=True,
       minimum=0.0),
    _C("grasp_s", pa.float64(), "s", True, "Wall time of the grasp simulation (null: not simulated).",
       minimum=0.0),
)

CANDIDATES_COLUMNS: tuple[schema.Column, ...] = (
    _RUN,
    _C("segment", pa.int64(), "", False, "Segment the candidate was fitted to.", minimum=0),
    _C("restart", pa.int64(), "", False, "ICP restart 0..n_restarts-1.", minimum=0),
    _C("n_points", pa.int64(), "", False, "Points in the segment.", minimum=1),
    _C("x_m", pa.float64(), "m", False, "Candidate target COM x.", finite=True),
    _C("y_m", pa.float64(), "m", False, "Candidate target COM y.", finite=True),
    _C("yaw_rad", pa.float64(), "rad", False, "Candidate yaw in [-pi, pi) (not canonicalised).", finite=True),
    _C("icp_rmse_m", pa.float64(), "m", False,
       "ICP error of the segment's points (point-to-plane by default, see icp_error).", finite=True, minimum=0.0),
    _C("penetration_m", pa.float64(), "m", False, "Deepest penetration into a visited gripper pose (0: none).",
       finite=True, minimum=0.0),
    _C("valid", pa.bool_(), "", False, "Open3D returned a rotation about z (always, by construction) keeping the "
       "points within max_point_distance (median) of the model; invalid candidates keep their initial pose."),
    _C("position_var_m2", pa.float64(), "m^2", True, "The segment's restart position variance (repeated).",
       minimum=0.0),
    _C("rank", pa.int64(), "", False, "Rank within the segment by (excess penetration, ICP error); 0 = best.",
       minimum=0),
    _C("segment_chosen", pa.bool_(), "", False,
       "The run's chosen segment (lowest position variance among the segments that fit)."),
    _C("chosen", pa.bool_(), "", False, "This candidate is the run's estimate (before canonicalisation)."),
)


def _check_one_per_run(cols) -> None:
    _, counts = np.unique(cols.run_codes, return_counts=True)
    if (counts > 1).any():
        name = cols.run_names[int(np.flatnonzero(counts > 1)[0])]
        r = int(np.flatnonzero(cols.run_codes == cols.run_names.index(name))[1])
        cols.fail("run", r, f"run {name!r} appears more than once; expected one row per run")


RETRIEVAL = schema.TableSpec("retrieval", RETRIEVAL_COLUMNS,
                             rules=("One row per run.",
                                    "Timing columns (`icp_s`, `grasp_s`) are the only ones that differ between "
                                    "two identical runs."),
                             check=_check_one_per_run)
CANDIDATES = schema.TableSpec("candidates", CANDIDATES_COLUMNS,
                              rules=("One row per (run, segment, restart).",
                                     "Exactly one row per run with a non-empty segmentation has `chosen` true."))


def validate_retrieval(table: pa.Table, path: str | Path = "<table>") -> pa.Table:
    """Validate a retrieval table (one-line SchemaError)."""
    return schema.validate_spec(table, RETRIEVAL, path)


def validate_candidates(table: pa.Table, path: str | Path = "<table>") -> pa.Table:
    return schema.validate_spec(table, CANDIDATES, path)


def read_retrieval(path: str | Path) -> pa.Table:
    """Read and validate a retrieval table written by ``stucco retrieve``."""
    return validate_retrieval(schema._read_parquet(path), path)


# ---------------------------------------------------------------------------------------------------------------
# The stage
# ---------------------------------------------------------------------------------------------------------------


def final_segments_by_run(segments: pa.Table) -> dict[str, list[tuple[int, np.ndarray]]]:
    """Run -> [(segment id, points (M, 2))] of the final estimate of each run (unassigned points, segment -1,
    are left out)."""
    from pipeline.segment import final_estimates

    final = final_estimates(segments)
    out: dict[str, list[tuple[int, np.ndarray]]] = {}
    if final.num_rows == 0:
        return out
    run = np.asarray(final.column("run").to_pylist(), dtype=object)
    seg = final.column("segment").to_numpy()
    xy = np.column_stack([final.column("x_m").to_numpy(), final.column("y_m").to_numpy()])
    for r in dict.fromkeys(run):
        m = run == r
        out[r] = [(int(s), xy[m & (seg == s)]) for s in np.unique(seg[m]) if s >= 0]
    return out


@dataclass
class RunOutput:
    row: dict[str, Any]
    candidates: dict[str, np.ndarray]


def _retrieve_one(info: RunInfo, segs: list[tuple[int, np.ndarray]], method: str, root_seed: int,
                  params: RetrievalParams, grasp: bool, grasp_params) -> RunOutput:
    from pipeline.robot import load_robot

    sdf = load_robot(params.robot)
    rm, rr = retrieval_rng(root_seed, info.run)
    est = estimate_run(segs, info.target, info.ee, sdf, params, rm, rr)
    truth = info.true_pose
    pos_err, yaw_err = pose_error(info.target, est.pose, truth)
    row = dict(run=info.run, scene=info.scene.name, seed=info.seed, method=method, target=info.target.name,
               x_m=float(est.pose[0]), y_m=float(est.pose[1]), yaw_rad=float(est.pose[2]), segment=est.segment,
               n_points=est.n_points, n_segments=est.n_segments,
               position_var_m2=est.position_var if math.isfinite(est.position_var) else None,
               icp_rmse_m=est.rmse if math.isfinite(est.rmse) else None, penetration_m=est.penetration,
               low_confidence=est.low_confidence, notes=",".join(est.notes),
               true_x_m=float(truth[0]), true_y_m=float(truth[1]), true_yaw_rad=float(truth[2]),
               position_error_m=pos_err, yaw_error_rad=yaw_err, grasp_success=None, grasp_outcome="",
               icp_s=est.icp_s, grasp_s=None)
    if grasp:
        from pipeline.grasp import GraspParams, grasp_at

        g = grasp_at(info.scene, info.final_poses, info.final_ee, est.pose, grasp_params or GraspParams())
        row.update(grasp_success=g.success, grasp_outcome=g.outcome, grasp_s=g.wall_s)
    cand = dict(est.candidates)
    cand["run"] = np.full(len(cand["segment"]), info.run, dtype=object)
    return RunOutput(row, cand)


def retrieve(segments: pa.Table, run_dir: str | Path, *, method: str = "stucco", root_seed: int = 0,
             params: RetrievalParams = RetrievalParams(), grasp: bool = True, grasp_params=None, jobs: int = 1,
             progress: Callable | None = None, segments_path: str = "<segments>") -> tuple[pa.Table, pa.Table]:
    """The ``retrieve`` stage: a segments table and the collected runs in, retrieval and candidates tables out.

    Every run file in ``run_dir`` gets one row: a run absent from the segments table had no tracked contact
    (an empty segmentation) and is estimated as such (flagged ``no_points``). A run of the segments table
    without a run file is an error.

    Parameters
    ----------
    segments : pyarrow.Table
        A validated segments table (its final estimate per run is used).
    run_dir : path
        Directory of ``stucco collect`` files.
    method : str
        Tracking method, recorded in the output.
    root_seed : int
    params : RetrievalParams
    grasp : bool
        Simulate the grasp at the estimate (:func:`pipeline.grasp.grasp_at`).
    grasp_params : pipeline.grasp.GraspParams, optional
    jobs : int
        Runs processed in parallel processes.
    progress : callable, optional
        Wraps the iterable of finished runs (``progress(iterable, total=)``).

    Returns
    -------
    retrieval, candidates : pyarrow.Table
    """
    files = run_files_by_name(run_dir)
    by_run = final_segments_by_run(segments)
    missing = [r for r in by_run if r not in files]
    if missing:
        raise ValueError(f"{segments_path}: run {missing[0]!r} has no collected run file in {run_dir} "
                         f"({len(files)} run file(s) there)")
    infos = [load_run(files[r]) for r in files]
    args = [(info, by_run.get(info.run, []), method, root_seed, params, grasp, grasp_params) for info in infos]
    if jobs > 1 and len(args) > 1:
        from joblib import Parallel, delayed

        results = Parallel(n_jobs=min(jobs, len(args)), return_as="generator")(
            delayed(_retrieve_one)(*a) for a in args)
    else:
        results = (_retrieve_one(*a) for a in args)
    if progress is not None:
        results = progress(results, total=len(args))
    outs = list(results)
    return retrieval_table([o.row for o in outs]), candidates_table([o.candidates for o in outs])


def retrieval_table(rows: list[dict[str, Any]]) -> pa.Table:
    """Rows (dicts keyed by :data:`RETRIEVAL_COLUMNS`) -> validated retrieval table."""
    arrays = {c.name: pa.array([r[c.name] for r in rows], type=c.type) for c in RETRIEVAL_COLUMNS}
    return validate_retrieval(pa.table(arrays))


def candidates_table(parts: list[dict[str, np.ndarray]]) -> pa.Table:
    """Per-run candidate columns -> validated candidates table."""
    arrays = {}
    for c in CANDIDATES_COLUMNS:
        vals = [p[c.name] for p in parts if len(p[c.name])]
        data = np.concatenate(vals) if vals else np.zeros(0)
        if c.type == pa.string():
            arrays[c.name] = pa.array(data.tolist() if len(data) else [], type=pa.string())
        elif c.name == "position_var_m2":
            data = np.asarray(data, dtype=np.float64)
            arrays[c.name] = pa.array(data, type=pa.float64(), mask=~np.isfinite(data))
        else:
            arrays[c.name] = pa.array(np.asarray(data).astype(c.type.to_pandas_dtype()), type=c.type)
    return validate_candidates(pa.table(arrays))
