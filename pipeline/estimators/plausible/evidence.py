"""The evidence the plausible estimator weighs: each contact point's uncertainty and the gripper's free space.

* :func:`recency_sigma`: a point's standard deviation grows with the number of later contacts of its segment,
  since the tracker carried it through those pushes without turning it with the object (docs/estimators.md,
  "The plausible estimator").
* :func:`gripper_lattice` and :func:`free_space_points`: points of the gripper's slice at the poses it occupied
  after the segment's object last moved; the target cannot be there.
"""
from __future__ import annotations

import math

import numpy as np

from pipeline.estimators.plausible.kernel import first_of_cells
from pipeline.estimators.plausible.params import PlausibleParams
from pipeline.portable import exp

__all__ = ["recency_sigma", "target_reach", "gripper_lattice", "cached_gripper_lattice", "free_space_points",
           "first_per_cell"]


def recency_sigma(steps: np.ndarray, params: PlausibleParams) -> np.ndarray:
    """Standard deviation (M,), metres, of each point from the number of later contact steps of its segment."""
    steps = np.asarray(steps, dtype=np.int64).reshape(-1)
    distinct = np.unique(steps)
    later = len(distinct) - np.searchsorted(distinct, steps, side="right")
    # log-space power, so a long history overflows to the cap, never to inf * 0.
    log_sigma = math.log(params.contact_sigma) + later * math.log(params.recency_growth)
    return exp(np.minimum(log_sigma, math.log(params.max_sigma)))


def target_reach(target, points: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre (2,), radius m) of the disc the target (a :class:`~pipeline.geometry.Primitive`) must lie in when it
    touches ``points`` (M, 2), M >= 1: their centroid, and the target's diameter plus the points' largest distance
    from it (every part of the target lies within its diameter of a contact)."""
    centre = points.mean(axis=0)
    radius = 2.0 * (math.hypot(*target.half[:2]) if target.kind == "box" else target.half[0]) \
        + float(np.max(np.linalg.norm(points - centre, axis=1)))
    return centre, radius


def gripper_lattice(sdf, resolution: float) -> np.ndarray:
    """Robot-frame points (G, 2), metres, on a lattice of ``resolution`` inside the gripper's slice (sdf < 0)."""
    lo, hi = sdf.interior_bounds(0.0)
    if not np.all(np.isfinite(lo)):
        return np.zeros((0, 2))
    axes = [np.arange(lo[k], hi[k] + 0.5 * resolution, resolution) for k in range(2)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 2)
    return grid[sdf.query(grid) < 0.0]


_LATTICES: dict[tuple[str, float], np.ndarray] = {}


def cached_gripper_lattice(sdf, resolution: float) -> np.ndarray:
    """:func:`gripper_lattice`, built once per process for each (grid, spacing): it depends on nothing else."""
    key = (sdf.digest, float(resolution))
    if key not in _LATTICES:
        _LATTICES[key] = gripper_lattice(sdf, resolution)
    return _LATTICES[key]


def free_space_points(lattice: np.ndarray, ee_start: np.ndarray, ee_end: np.ndarray, steps: np.ndarray,
                      after_step: int, params: PlausibleParams, centre: np.ndarray, radius: float) -> np.ndarray:
    """World points (F, 2), metres, the gripper occupied while the segment's object stayed where it ended.

    The object last moved during action ``after_step`` (its last contact): the gripper's pose at the end of that
    action and its sweep through every later action (straight from start to end, a pose every
    ``sweep_spacing``) are free of it. Lattice points within ``radius`` of ``centre`` are kept, deduplicated
    on a ``free_resolution`` grid.

    Parameters
    ----------
    lattice : ndarray, shape (G, 2)
        Gripper points in the robot frame (:func:`gripper_lattice`).
    ee_start, ee_end : ndarray, shape (K, 2)
        Gripper position at the start and end of every action.
    steps : ndarray, shape (K,)
        Action index of each row.
    """
    ee_start = np.asarray(ee_start, dtype=np.float64).reshape(-1, 2)
    ee_end = np.asarray(ee_end, dtype=np.float64).reshape(-1, 2)
    steps = np.asarray(steps, dtype=np.int64).reshape(-1)
    later = steps > after_step
    a, b = ee_start[later], ee_end[later]
    n = np.maximum(1, np.ceil(np.linalg.norm(b - a, axis=1) / params.sweep_spacing).astype(np.int64))
    if len(a):
        seg = np.repeat(np.arange(len(a)), n + 1)
        t = np.concatenate([np.linspace(0.0, 1.0, k + 1) for k in n])
        sweep = a[seg] + t[:, None] * (b - a)[seg]
    else:
        sweep = np.zeros((0, 2))
    poses = np.vstack([ee_end[steps == after_step], sweep])
    reach = radius + float(np.max(np.linalg.norm(lattice, axis=1))) if len(lattice) else 0.0
    poses = poses[np.linalg.norm(poses - centre, axis=1) <= reach]
    if len(poses) == 0 or len(lattice) == 0:
        return np.zeros((0, 2))
    pts = (poses[:, None, :] + lattice[None, :, :]).reshape(-1, 2)
    pts = pts[np.linalg.norm(pts - centre, axis=1) <= radius]
    return first_per_cell(pts, params.free_resolution)


def first_per_cell(pts: np.ndarray, resolution: float) -> np.ndarray:
    """The first of the points (P, 2) in each cell of a ``resolution`` grid (cells centred on its multiples), in
    their order: (F, 2), F <= P."""
    if len(pts) == 0:
        return pts
    cell = np.rint(pts / resolution).astype(np.int64)
    # A flag per cell of the cells' bounding box (compiled, :func:`first_of_cells`): the free space is asked for
    # at every action of every filter of pushtrack, and the sort below cost twice as much. Sorting is kept for a
    # box of more cells than a few per point.
    # (only for cells an int64 holds: a NaN, inf or huge point would wrap the box's size and write out of it)
    first = first_of_cells(cell, 4 * len(cell) + 65536) if np.all(np.abs(pts) < 1e9 * resolution) else ()
    if len(first):
        return pts[first]
    # One int64 per cell (row-major in the cells' bounding box): np.unique over rows (axis=0) sorts them as
    # opaque bytes, ten times slower; the first point of each cell is the same either way (a stable sort).
    cell -= cell.min(axis=0)
    _, first = np.unique(cell[:, 0] * (int(cell[:, 1].max()) + 1) + cell[:, 1], return_index=True)
    return pts[np.sort(first)]
