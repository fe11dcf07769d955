"""The Panda hand's collision geometry: its meshes, their placement, and the grid SDF built from them (no cache).

The floating Franka Panda hand with closed fingers, as pybullet collides with it (the convex hull of each
collision mesh, inflated by pybullet's collision margin), placed in the robot frame: the gripper origin with its
fixed orientation applied, sliced at the plane of the origin (docs/simulation.md, "The gripper's signed distance
grid"). :func:`build_panda_grid` computes the grid with Open3D; :mod:`pipeline.robot.panda_cache` caches it,
keyed by :func:`builder_digest`. Units are metres and radians.
"""
from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pybullet_data

from pipeline.robot.grid import GridSDF, axis_cells

__all__ = ["BUILDER_VERSION", "PYBULLET_COLLISION_MARGIN", "GRIPPER_EULER", "FINGER_JOINT_Z", "mesh_paths",
           "builder_digest", "build_panda_grid"]

#: Bump when :func:`build_panda_grid` changes in a way that changes its output; part of the cache key.
BUILDER_VERSION = "panda-grid-1"

#: Distance (m) by which pybullet inflates convex-hull collision shapes. Measured: pybullet's getClosestPoints
#: between the hulls and a 1e-8 m sphere is the exact (Open3D) signed distance minus 0.0010 m at every one of
#: 3 243 sampled grid cells (max deviation 1e-6 m), which is what moves the authors' grid minimum to -0.0305 m
#: and its inside fraction to 66 %, and their isolation surface points 1 mm beyond the mesh bounds
#: (docs/simulation.md, "The gripper's signed distance grid"). Simulated contacts happen on that inflated
#: surface, so the grid includes it by default.
PYBULLET_COLLISION_MARGIN = 0.001

# Placement of the collision meshes, from the authors' URDF (docs/simulation.md, "World, gripper, stepping"); the
# pybullet gripper of :mod:`pipeline.sim.gripper` is built from the same constants. Part of the cache key.
#: Prismatic finger joints' origin along hand z, m.
FINGER_JOINT_Z = 0.0584
#: Fixed gripper orientation (roll, pitch, yaw), radians: hand z -> world +x, hand y -> world y, hand x -> world -z.
GRIPPER_EULER = (0.0, math.pi / 2, 0.0)
_FINGER_OPENING = 0.0  # closed fingers (CLOSE_ANGLE), m along +y (left) / -y (right)
_RIGHT_FINGER_YAW = math.pi  # right finger mesh rotated by pi about hand z
_SLICE_Z = 0.0  # plane of the gripper origin, robot frame
# Odd number of rays for Open3D's inside test: one ray can graze a hull edge/vertex and flip the sign. (On the
# 1 mm grid 1 and 3 gave identical values; 3 costs nothing measurable and guards other resolutions.)
_SDF_NSAMPLES = 3


def mesh_paths() -> tuple[Path, Path]:
    """Paths of pybullet_data's Panda hand and finger collision meshes (``hand.obj``, ``finger.obj``)."""
    base = Path(pybullet_data.getDataPath()) / "franka_panda" / "meshes" / "collision"
    return base / "hand.obj", base / "finger.obj"


def builder_digest(resolution: float, collision_margin: float) -> str:
    """sha256 (64 hex digits) of every input of :func:`build_panda_grid`: both mesh files' bytes, the placement
    constants, ``resolution`` and ``collision_margin`` (metres) and :data:`BUILDER_VERSION`."""
    hand, finger = mesh_paths()
    h = hashlib.sha256()
    h.update(hand.read_bytes())
    h.update(finger.read_bytes())
    h.update(
        json.dumps(
            {
                "builder": BUILDER_VERSION,
                "finger_joint_z": FINGER_JOINT_Z,
                "finger_opening": _FINGER_OPENING,
                "right_finger_yaw": _RIGHT_FINGER_YAW,
                "gripper_euler": list(GRIPPER_EULER),
                "slice_z": _SLICE_Z,
                "nsamples": _SDF_NSAMPLES,
                "resolution": float(resolution),
                "collision_margin": float(collision_margin),
            },
            sort_keys=True,
        ).encode()
    )
    return h.hexdigest()


def _mat(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Matrix product (N, K) x (K, M) written out with a fixed summation order: numpy's ``@`` goes through
    OpenBLAS, whose last bits change with the CPU (docs/evaluation.md, "Same numbers on every machine")."""
    return np.sum(a[:, :, None] * b[None, :, :], axis=1)


def _rot_z(angle: float) -> np.ndarray:
    """3-D rotation matrix, shape (3, 3), about z by ``angle`` radians (mesh placement; planar rotations are in
    :mod:`pipeline.geometry`)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_euler_xyz(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """pybullet's getQuaternionFromEuler convention: R = Rz(yaw) @ Ry(pitch) @ Rx(roll)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    return _mat(_mat(_rot_z(yaw), ry), rx)


def _panda_hulls() -> list[tuple[np.ndarray, np.ndarray]]:
    """Convex hulls of the closed Panda hand's collision meshes, placed in the robot frame.

    Returns
    -------
    list of (vertices (V, 3) float64 metres, triangles (T, 3) int64)
        Hand, left finger, right finger, in the robot frame (gripper origin, fixed orientation applied).
    """
    # Open3D is imported only when the grid is built (a cache miss): its import takes about 1 s (measured,
    # -X importtime), and every tracker process imports this package to load the cached grid.
    import open3d as o3d

    hand_path, finger_path = mesh_paths()

    def hull(path: Path) -> tuple[np.ndarray, np.ndarray]:
        mesh = o3d.io.read_triangle_mesh(str(path))
        if len(mesh.vertices) == 0:
            raise RuntimeError(f"could not read mesh {path}")
        # pybullet collides with the convex hull of each mesh, not with the mesh itself.
        h, _ = mesh.compute_convex_hull()
        return np.asarray(h.vertices, dtype=np.float64), np.asarray(h.triangles, dtype=np.int64)

    hand_v, hand_t = hull(hand_path)
    finger_v, finger_t = hull(finger_path)
    r = _rot_euler_xyz(*GRIPPER_EULER)
    joint = np.array([0.0, 0.0, FINGER_JOINT_Z])
    left = finger_v + joint + np.array([0.0, _FINGER_OPENING, 0.0])
    right = _mat(finger_v, _rot_z(_RIGHT_FINGER_YAW).T) + joint - np.array([0.0, _FINGER_OPENING, 0.0])
    return [(_mat(hand_v, r.T), hand_t), (_mat(left, r.T), finger_t), (_mat(right, r.T), finger_t)]


def build_panda_grid(resolution: float = 0.001, collision_margin: float = PYBULLET_COLLISION_MARGIN) -> GridSDF:
    """Build the Panda grid SDF from the meshes (no cache): measured 0.05 s, 0.9 s with Open3D's first import.

    Grid bounds are the xy bounding box of the placed hulls (docs/simulation.md, "The gripper's signed distance
    grid"), cell centres ``arange(min, max + resolution, resolution)`` per axis (see
    :func:`pipeline.robot.grid.axis_cells`), values = 3-D signed distance at ``z = _SLICE_Z`` minus
    ``collision_margin``.
    """
    import open3d as o3d  # only on a cache miss, as in _panda_hulls (1 s import)

    hulls = _panda_hulls()
    all_v = np.vstack([v for v, _ in hulls])
    lo = all_v[:, :2].min(axis=0)
    hi = all_v[:, :2].max(axis=0)
    nx = axis_cells(lo[0], hi[0], resolution)
    ny = axis_cells(lo[1], hi[1], resolution)
    x, y = np.meshgrid(lo[0] + resolution * np.arange(nx), lo[1] + resolution * np.arange(ny), indexing="ij")
    query = np.stack([x, y, np.full_like(x, _SLICE_Z)], axis=-1).astype(np.float32)
    query_t = o3d.core.Tensor(query)
    dist = np.full(x.shape, np.inf)
    for v, t in hulls:
        # One scene per hull: the inside test counts ray crossings over the whole scene, so overlapping hulls
        # (the fingers touch, the fingers' bases sit in the palm) in one scene would give wrong signs.
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(t.astype(np.uint32)))
        d = scene.compute_signed_distance(query_t, nsamples=_SDF_NSAMPLES).numpy().astype(np.float64)
        dist = np.minimum(dist, d)  # union of solids = minimum of signed distances
    return GridSDF(dist - collision_margin, lo, resolution, name="panda")
