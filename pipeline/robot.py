"""Gripper geometry: the robot's signed distance ("pxpen") as a grid, and its isolation surface points.

STUCCO's penetration term pxpen(x, p) is the signed distance of point ``p`` to the robot at configuration ``x``,
negative inside. Because the gripper's orientation is fixed (REFERENCE_SPEC §1.2), the robot frame is a pure
translation of the world and ``pxpen(x, p) = sdf(p - x)``, with ``sdf`` a grid cached once per robot
(REFERENCE_SPEC §4.2). Two robots are provided:

* :func:`disc_sdf` -- a disc of given radius, the robot of the anchor benchmark streams;
* :func:`panda_sdf` -- the floating Franka Panda hand (closed fingers) sliced at the plane of its origin, built
  from pybullet's collision meshes with Open3D and cached on disk.

:func:`surface_points` gives the candidate contact points and outward normals used by isolation
(REFERENCE_SPEC §3.3), computed on the same grid so isolation and tracking agree on where the surface is.
:func:`load_robot` maps a CLI string (``"panda"``, ``"disc:0.05"``) to a grid.

Units are metres throughout.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

__all__ = [
    "GridSDF",
    "disc_sdf",
    "panda_sdf",
    "surface_points",
    "load_robot",
    "BUILDER_VERSION",
    "PYBULLET_COLLISION_MARGIN",
]

#: Bump when :func:`_build_panda_grid` changes in a way that changes its output; part of the cache key.
BUILDER_VERSION = "panda-grid-1"

#: Distance (m) by which pybullet inflates convex-hull collision shapes. Measured: pybullet's getClosestPoints
#: between the hulls and a 1e-8 m sphere is the exact (Open3D) signed distance minus 0.0010 m at every one of
#: 3 243 sampled grid cells (max deviation 1e-6 m), which is what moves the authors' grid minimum to -0.0305 m
#: and its inside fraction to 66 % (REFERENCE_SPEC §4.2), and their surface points 1 mm beyond the mesh bounds
#: (§3.3). Simulated contacts happen on that inflated surface, so the grid includes it by default.
PYBULLET_COLLISION_MARGIN = 0.001

# Placement of the collision meshes, from the authors' URDF (REFERENCE_SPEC §1.2). Part of the cache key.
_FINGER_JOINT_Z = 0.0584  # prismatic finger joints' origin along hand z, m
_FINGER_OPENING = 0.0  # closed fingers (CLOSE_ANGLE), m along +y (left) / -y (right)
_RIGHT_FINGER_YAW = math.pi  # right finger mesh rotated by pi about hand z
_GRIPPER_EULER = (0.0, math.pi / 2, 0.0)  # fixed (roll, pitch, yaw): hand z -> world +x, hand x -> world -z
_SLICE_Z = 0.0  # plane of the gripper origin, robot frame
# Odd number of rays for Open3D's inside test: one ray can graze a hull edge/vertex and flip the sign. (On the
# 1 mm grid 1 and 3 gave identical values; 3 costs nothing measurable and guards other resolutions.)
_SDF_NSAMPLES = 3


# ---------------------------------------------------------------------------------------------------------------
# The grid
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class GridSDF:
    """A signed distance function sampled on a regular axis-aligned grid, in the robot frame.

    Cell ``(i_0, ..., i_{D-1})`` holds the signed distance at ``origin + resolution * (i_0, ..., i_{D-1})``
    (cell centres). Queries use the nearest cell, exactly like the authors' cached SDF (REFERENCE_SPEC §4.2).

    Parameters
    ----------
    values : ndarray, shape (n_0, ..., n_{D-1}), float64, metres
        Signed distance at the cell centres; negative inside the robot. Stored as a read-only C-contiguous copy.
    origin : ndarray, shape (D,), metres
        Robot-frame coordinate of cell index 0 on each axis.
    resolution : float, metres
        Cell spacing (same on every axis).
    outside_value : float, metres
        Value returned for queries that fall outside the grid (1.0, as in the authors' code): far from the robot.
    name : str
        Human-readable name, e.g. ``"panda"`` or ``"disc:0.05"``.

    Notes
    -----
    Equality and hashing are by identity (arrays make field-wise equality ambiguous); compare :attr:`digest`.
    """

    values: np.ndarray
    origin: np.ndarray
    resolution: float
    outside_value: float = 1.0
    name: str = ""

    def __post_init__(self) -> None:
        values = np.array(self.values, dtype=np.float64, order="C", copy=True)
        origin = np.array(self.origin, dtype=np.float64, copy=True).reshape(-1)
        if values.ndim < 1 or origin.shape != (values.ndim,):
            raise ValueError(f"GridSDF: origin shape {origin.shape} does not match values of ndim {values.ndim}")
        if min(values.shape) < 1:
            raise ValueError(f"GridSDF: empty grid of shape {values.shape}")
        resolution = float(self.resolution)
        if not (resolution > 0 and math.isfinite(resolution)):
            raise ValueError(f"GridSDF: resolution must be a positive finite number, got {self.resolution!r}")
        # Read-only: the grid is shared by every particle and by the numba kernel's flat view.
        values.setflags(write=False)
        origin.setflags(write=False)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "resolution", resolution)
        object.__setattr__(self, "outside_value", float(self.outside_value))
        object.__setattr__(self, "name", str(self.name))

    @property
    def ndim(self) -> int:
        """int: D, the dimension of the points."""
        return self.values.ndim

    @property
    def shape(self) -> tuple[int, ...]:
        """tuple of int: (n_0, ..., n_{D-1}), the number of cells per axis."""
        return self.values.shape

    @property
    def upper(self) -> np.ndarray:
        """ndarray, shape (D,), metres: robot-frame coordinate of the last cell centre on each axis."""
        return self.origin + self.resolution * (np.asarray(self.values.shape, dtype=np.float64) - 1.0)

    @cached_property
    def digest(self) -> str:
        """str: first 16 hex digits of the sha256 of shape, values, origin and resolution (for output metadata).

        The shape is hashed too because the flat bytes of the values alone do not determine the grid.
        """
        h = hashlib.sha256()
        h.update(np.asarray(self.values.shape, dtype="<i8").tobytes())
        h.update(np.ascontiguousarray(self.values, dtype="<f8").tobytes())
        h.update(np.asarray(self.origin, dtype="<f8").tobytes())
        h.update(np.float64(self.resolution).astype("<f8").tobytes())
        return h.hexdigest()[:16]

    def query(self, q: np.ndarray) -> np.ndarray:
        """Signed distance at robot-frame points, by nearest cell.

        The cell index is ``idx_d = rint((q_d - origin_d) / resolution)`` on each axis: round half to even,
        the rule of ``torch.round`` in the authors' code and of ``np.rint`` / ``round`` in numba, so a kernel
        using :meth:`kernel_arrays` gets identical values. A point whose index falls outside ``[0, n_d - 1]``
        on any axis (or that is NaN) gets :attr:`outside_value`.

        Parameters
        ----------
        q : array_like, shape (..., D), metres
            Points in the robot frame; any batch shape, including ``(0, D)`` and a single ``(D,)`` point.

        Returns
        -------
        ndarray, shape (...), float64, metres
            Signed distance, negative inside the robot (a 0-d array for a single point).
        """
        q = np.asarray(q, dtype=np.float64)
        d = self.ndim
        if q.ndim < 1 or q.shape[-1] != d:
            raise ValueError(f"GridSDF.query: expected points of shape (..., {d}), got {q.shape}")
        idx = np.rint((q - self.origin) / self.resolution)
        n = np.asarray(self.values.shape, dtype=np.float64)
        # Written as a positive test so NaN compares False and lands outside.
        inside = np.all((idx >= 0.0) & (idx <= n - 1.0), axis=-1)
        idx = np.where(inside[..., None], idx, 0.0).astype(np.int64)
        vals = self.values[tuple(idx[..., k] for k in range(d))]
        return np.where(inside, vals, self.outside_value)

    def pxpen(self, configs: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Signed distance of world points to the robot at world configurations: ``query(points - configs)``.

        Parameters
        ----------
        configs : array_like, shape (..., D), metres
            Robot positions (the robot frame's origin in the world).
        points : array_like, shape (..., D), metres
            World points; broadcast against ``configs``. For the authors' M x N matrix pass
            ``configs[:, None, :]`` and ``points[None, :, :]``.

        Returns
        -------
        ndarray, shape broadcast(configs, points)[:-1], float64, metres
        """
        return self.query(np.asarray(points, dtype=np.float64) - np.asarray(configs, dtype=np.float64))

    def interior_bounds(self, threshold: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Robot-frame bounding box of the cell centres whose value is below ``threshold``.

        A query ``q`` can only get a value ``< threshold`` (``threshold <= outside_value``) if it lies in
        ``[lo - resolution / 2, hi + resolution / 2]`` on every axis (nearest-cell rounding); pad by half a cell
        when using the box to skip pairs that cannot penetrate.

        Parameters
        ----------
        threshold : float, metres

        Returns
        -------
        lo, hi : ndarray, shape (D,), metres
            Box corners; if no cell qualifies, an empty box with ``lo = +inf > hi = -inf``.
        """
        mask = self.values < threshold
        d = self.ndim
        if not mask.any():
            return np.full(d, np.inf), np.full(d, -np.inf)
        lo = np.empty(d)
        hi = np.empty(d)
        for k in range(d):
            other = tuple(a for a in range(d) if a != k)
            hit = np.flatnonzero(mask.any(axis=other)) if other else np.flatnonzero(mask)
            lo[k] = self.origin[k] + self.resolution * hit[0]
            hi[k] = self.origin[k] + self.resolution * hit[-1]
        return lo, hi

    def kernel_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
        """Plain arrays for a compiled (numba) lookup equal to :meth:`query`.

        Flat index of cell ``idx`` = ``sum_d idx_d * strides_d``; compute ``idx_d`` with ``np.rint`` as in
        :meth:`query` and return :attr:`outside_value` when any ``idx_d`` is outside ``[0, shape_d - 1]``.

        Returns
        -------
        values_flat : ndarray, shape (n_0 * ... * n_{D-1},), float64, C-contiguous, read-only
        shape : ndarray, shape (D,), int64
        strides : ndarray, shape (D,), int64, in elements
        origin : ndarray, shape (D,), float64, metres
        resolution : float, metres
        """
        values_flat = self.values.reshape(-1)  # a view: values is C-contiguous
        shape = np.asarray(self.values.shape, dtype=np.int64)
        strides = np.asarray(self.values.strides, dtype=np.int64) // self.values.itemsize
        return values_flat, shape, strides, np.array(self.origin, dtype=np.float64), self.resolution


def _axis(lo: float, hi: float, resolution: float) -> int:
    """Number of cell centres of the authors' axis ``arange(lo, hi + resolution, resolution)``.

    That is ``ceil((hi - lo) / resolution + 1)``, less a 1e-9 cell tolerance: when ``(hi - lo) / resolution`` is an
    integer up to rounding noise, ``arange`` may add a spurious cell (``-(0.05 + 0.01)`` is -0.060000000000000005,
    which gives 122 cells instead of the anchor's 121).
    """
    return int(math.ceil((hi - lo) / resolution + 1.0 - 1e-9))


# ---------------------------------------------------------------------------------------------------------------
# Disc
# ---------------------------------------------------------------------------------------------------------------


def disc_sdf(radius: float, resolution: float = 0.001, margin: float = 0.01) -> GridSDF:
    """Grid SDF of a disc centred on the robot origin (the anchor streams' robot).

    Parameters
    ----------
    radius : float, metres
        Disc radius, > 0.
    resolution : float, metres
        Cell spacing.
    margin : float, metres
        Free space around the disc: the grid covers ``[-(radius + margin), radius + margin]`` on both axes,
        with ``arange(lo, hi + resolution, resolution)`` cell centres as in the authors' benchmark.

    Returns
    -------
    GridSDF
        2-D grid with values ``hypot(x, y) - radius`` at the cell centres, named ``"disc:<radius>"``.
    """
    radius = float(radius)
    if not (radius > 0 and math.isfinite(radius)):
        raise ValueError(f"disc_sdf: radius must be a positive finite number of metres, got {radius!r}")
    lo = -(radius + margin)
    n = _axis(lo, -lo, resolution)
    c = lo + resolution * np.arange(n)
    x, y = np.meshgrid(c, c, indexing="ij")
    return GridSDF(np.hypot(x, y) - radius, np.array([lo, lo]), resolution, name=f"disc:{radius:g}")


# ---------------------------------------------------------------------------------------------------------------
# Franka Panda hand
# ---------------------------------------------------------------------------------------------------------------


def _panda_mesh_paths() -> tuple[Path, Path]:
    """Paths of pybullet's Panda hand and finger collision meshes."""
    import pybullet_data  # only a data path; cheap, but kept out of module import on principle

    base = Path(pybullet_data.getDataPath()) / "franka_panda" / "meshes" / "collision"
    return base / "hand.obj", base / "finger.obj"


def _default_cache_dir() -> Path:
    env = os.environ.get("STUCCO_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "stucco"


def _panda_cache_path(resolution: float, cache_dir: str | os.PathLike | None, collision_margin: float) -> Path:
    """Cache file of the Panda grid: keyed by a sha256 of every input of :func:`_build_panda_grid`."""
    hand, finger = _panda_mesh_paths()
    h = hashlib.sha256()
    h.update(hand.read_bytes())
    h.update(finger.read_bytes())
    h.update(
        json.dumps(
            {
                "builder": BUILDER_VERSION,
                "finger_joint_z": _FINGER_JOINT_Z,
                "finger_opening": _FINGER_OPENING,
                "right_finger_yaw": _RIGHT_FINGER_YAW,
                "gripper_euler": list(_GRIPPER_EULER),
                "slice_z": _SLICE_Z,
                "nsamples": _SDF_NSAMPLES,
                "resolution": float(resolution),
                "collision_margin": float(collision_margin),
            },
            sort_keys=True,
        ).encode()
    )
    directory = Path(cache_dir) if cache_dir is not None else _default_cache_dir()
    return directory / f"panda_sdf_{h.hexdigest()[:20]}.npz"


def _rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_euler_xyz(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """pybullet's getQuaternionFromEuler convention: R = Rz(yaw) @ Ry(pitch) @ Rx(roll)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    return _rot_z(yaw) @ ry @ rx


def _panda_hulls() -> list[tuple[np.ndarray, np.ndarray]]:
    """Convex hulls of the closed Panda hand's collision meshes, placed in the robot frame.

    Returns
    -------
    list of (vertices (V, 3) float64 metres, triangles (T, 3) int64)
        Hand, left finger, right finger, in the robot frame (gripper origin, fixed orientation applied).
    """
    import open3d as o3d

    hand_path, finger_path = _panda_mesh_paths()

    def hull(path: Path) -> tuple[np.ndarray, np.ndarray]:
        mesh = o3d.io.read_triangle_mesh(str(path))
        if len(mesh.vertices) == 0:
            raise RuntimeError(f"could not read mesh {path}")
        # pybullet collides with the convex hull of each mesh, not with the mesh itself.
        h, _ = mesh.compute_convex_hull()
        return np.asarray(h.vertices, dtype=np.float64), np.asarray(h.triangles, dtype=np.int64)

    hand_v, hand_t = hull(hand_path)
    finger_v, finger_t = hull(finger_path)
    r = _rot_euler_xyz(*_GRIPPER_EULER)
    joint = np.array([0.0, 0.0, _FINGER_JOINT_Z])
    left = finger_v + joint + np.array([0.0, _FINGER_OPENING, 0.0])
    right = finger_v @ _rot_z(_RIGHT_FINGER_YAW).T + joint - np.array([0.0, _FINGER_OPENING, 0.0])
    return [(hand_v @ r.T, hand_t), (left @ r.T, finger_t), (right @ r.T, finger_t)]


def _build_panda_grid(resolution: float = 0.001, collision_margin: float = PYBULLET_COLLISION_MARGIN) -> GridSDF:
    """Build the Panda grid SDF from the meshes (no cache): measured 0.05 s, 0.9 s with Open3D's first import.

    Grid bounds are the xy bounding box of the placed hulls (REFERENCE_SPEC §4.2), cell centres
    ``arange(min, max + resolution, resolution)`` per axis (see :func:`_axis`), values = 3-D signed distance at ``z = _SLICE_Z``
    minus ``collision_margin``.
    """
    import open3d as o3d

    hulls = _panda_hulls()
    all_v = np.vstack([v for v, _ in hulls])
    lo = all_v[:, :2].min(axis=0)
    hi = all_v[:, :2].max(axis=0)
    nx = _axis(lo[0], hi[0], resolution)
    ny = _axis(lo[1], hi[1], resolution)
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


def _write_atomic_npz(path: Path, **arrays: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, path)  # atomic: concurrent workers see either no file or a complete one
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def _read_grid_npz(path: Path) -> GridSDF:
    with np.load(path, allow_pickle=False) as z:
        return GridSDF(
            z["values"],
            z["origin"],
            float(z["resolution"]),
            float(z["outside_value"]),
            str(z["name"]),
        )


def panda_sdf(
    resolution: float = 0.001,
    cache_dir: str | os.PathLike | None = None,
    collision_margin: float = PYBULLET_COLLISION_MARGIN,
) -> GridSDF:
    """Grid SDF of the floating Franka Panda hand with closed fingers, in its origin's horizontal plane.

    Loaded from an ``.npz`` cache when present (milliseconds), otherwise built with :func:`_build_panda_grid`
    and written atomically. The file name is keyed by a sha256 of both mesh files' bytes, the placement
    constants, ``resolution``, ``collision_margin`` and :data:`BUILDER_VERSION`, so a stale file is never used.

    Parameters
    ----------
    resolution : float, metres
        Cell spacing (the authors used 0.001: 140 x 206 cells).
    cache_dir : str or path-like, optional
        Cache directory; default ``$STUCCO_CACHE_DIR``, else ``~/.cache/stucco``.
    collision_margin : float, metres
        Subtracted from the exact signed distance; default :data:`PYBULLET_COLLISION_MARGIN` reproduces the
        authors' pybullet-built grid. Pass 0 for the bare convex hulls.

    Returns
    -------
    GridSDF
        2-D grid named ``"panda"``; x along the fingers (palm -> fingertips), y the finger opening axis.
    """
    resolution = float(resolution)
    if not (resolution > 0 and math.isfinite(resolution)):
        raise ValueError(f"panda_sdf: resolution must be a positive finite number, got {resolution!r}")
    path = _panda_cache_path(resolution, cache_dir, collision_margin)
    if path.is_file():
        try:
            return _read_grid_npz(path)
        except Exception:  # noqa: BLE001 -- a truncated/corrupt cache is rebuilt, never trusted
            pass
    grid = _build_panda_grid(resolution, collision_margin)
    _write_atomic_npz(
        path,
        values=grid.values,
        origin=grid.origin,
        resolution=np.float64(grid.resolution),
        outside_value=np.float64(grid.outside_value),
        name=np.str_(grid.name),
    )
    return grid


# ---------------------------------------------------------------------------------------------------------------
# Isolation surface points
# ---------------------------------------------------------------------------------------------------------------


# Cells of linear extrapolation added around the grid for surface work: the pybullet margin puts the surface up
# to 1 mm beyond the mesh-bounded grid (REFERENCE_SPEC §3.3 points reach y = -0.105 while the grid stops at -0.104).
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
    """Candidate contact points on the robot's surface and their outward normals (REFERENCE_SPEC §3.3).

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


# ---------------------------------------------------------------------------------------------------------------
# CLI strings
# ---------------------------------------------------------------------------------------------------------------

_ROBOT_FORMS = ("expected 'panda' or 'disc:RADIUS' with RADIUS a positive number of metres (e.g. 'disc:0.05'), "
                "or 'panda:RES' for the Panda grid at RES metres per cell (e.g. 'panda:0.002')")


def load_robot(spec: str) -> GridSDF:
    """Robot grid from a CLI string.

    Parameters
    ----------
    spec : str
        ``"panda"`` -> :func:`panda_sdf` (cached); ``"panda:RES"`` -> :func:`panda_sdf` at RES metres per cell;
        ``"disc:RADIUS"`` (metres, e.g. ``"disc:0.05"``) ->
        :func:`disc_sdf`.

    Returns
    -------
    GridSDF

    Raises
    ------
    ValueError
        Unknown name, or a radius that is not a positive finite number; the one-line message names the
        accepted forms.
    """
    text = str(spec).strip()
    if text == "panda":
        return panda_sdf()
    if text.startswith("panda:"):
        # SDF resolution as an accuracy knob (`stucco bench accuracy`): 'panda:0.002' = 2 mm cells.
        raw = text[len("panda:"):]
        try:
            res = float(raw)
        except ValueError:
            raise ValueError(f"robot {spec!r}: resolution {raw!r} is not a number; {_ROBOT_FORMS}") from None
        if not (0 < res <= 0.05 and math.isfinite(res)):
            raise ValueError(f"robot {spec!r}: resolution must be in (0, 0.05] metres; {_ROBOT_FORMS}")
        return panda_sdf(resolution=res)
    if text.startswith("disc:"):
        raw = text[len("disc:"):]
        try:
            radius = float(raw)
        except ValueError:
            raise ValueError(f"robot {spec!r}: radius {raw!r} is not a number; {_ROBOT_FORMS}") from None
        if not (radius > 0 and math.isfinite(radius)):
            raise ValueError(f"robot {spec!r}: radius must be positive and finite; {_ROBOT_FORMS}")
        return disc_sdf(radius)
    raise ValueError(f"unknown robot {spec!r}; {_ROBOT_FORMS}")
