"""The robot's signed distance as a grid: :class:`GridSDF` (nearest-cell queries, pxpen, kernel arrays).

STUCCO's penetration term pxpen(x, p) is the signed distance of point ``p`` to the robot at configuration ``x``,
negative inside. The gripper's orientation is fixed, so the robot frame is a pure translation of the world and
``pxpen(x, p) = sdf(p - x)`` with ``sdf`` one grid per robot (docs/simulation.md, "The gripper's signed distance
grid"). :func:`axis_cells` is the authors' rule for the number of cells along an axis, shared by the disc and
Panda grids. Units are metres.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

__all__ = ["GridSDF", "axis_cells"]


@dataclass(frozen=True, eq=False)
class GridSDF:
    """A signed distance function sampled on a regular axis-aligned grid, in the robot frame.

    Cell ``(i_0, ..., i_{D-1})`` holds the signed distance at ``origin + resolution * (i_0, ..., i_{D-1})``
    (cell centres). Queries use the nearest cell, exactly like the authors' cached SDF (docs/simulation.md,
    "The gripper's signed distance grid").

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


def axis_cells(lo: float, hi: float, resolution: float) -> int:
    """Number of cell centres of the authors' axis ``arange(lo, hi + resolution, resolution)``.

    That is ``ceil((hi - lo) / resolution + 1)``, less a 1e-9 cell tolerance: when ``(hi - lo) / resolution`` is an
    integer up to rounding noise, ``arange`` may add a spurious cell (``-(0.05 + 0.01)`` is -0.060000000000000005,
    which gives 122 cells instead of the anchor's 121).
    """
    return int(math.ceil((hi - lo) / resolution + 1.0 - 1e-9))
