"""The Panda grid's on-disk cache: :func:`panda_sdf` loads the grid from an ``.npz`` file or builds and writes it.

The file name is keyed by :func:`pipeline.robot.panda_mesh.builder_digest` (every input of the builder), so a
stale file is never used; files are written atomically, so parallel workers see either no file or a complete one.
"""
from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np

from pipeline.atomic import atomic_path
from pipeline.robot.grid import GridSDF
from pipeline.robot.panda_mesh import PYBULLET_COLLISION_MARGIN, build_panda_grid, builder_digest
from pipeline.safe_open import regular_file

__all__ = ["panda_sdf"]


def _default_cache_dir() -> Path:
    """``$STUCCO_CACHE_DIR`` if set, else ``~/.cache/stucco``."""
    env = os.environ.get("STUCCO_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "stucco"


def _panda_cache_path(resolution: float, cache_dir: str | os.PathLike | None, collision_margin: float) -> Path:
    """Cache file of the Panda grid: keyed by a sha256 of every input of :func:`build_panda_grid`."""
    digest = builder_digest(resolution, collision_margin)
    directory = Path(cache_dir) if cache_dir is not None else _default_cache_dir()
    return directory / f"panda_sdf_{digest[:20]}.npz"


def _write_atomic_npz(path: Path, **arrays: np.ndarray) -> None:
    """Write ``arrays`` to the ``.npz`` file ``path`` through a temporary file in the same directory."""
    # atomic: concurrent workers see either no file or a complete one
    with atomic_path(path) as tmp, open(tmp, "xb") as f:
        np.savez(f, **arrays)


def _read_grid_npz(path: Path) -> GridSDF:
    """The grid stored by :func:`panda_sdf` in ``path`` (no pickles)."""
    with np.load(regular_file(path, "the gripper's cached grid"), allow_pickle=False) as z:
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

    Loaded from an ``.npz`` cache when present (milliseconds), otherwise built with :func:`build_panda_grid`
    and written atomically. The file name is keyed by a sha256 of both mesh files' bytes, the placement
    constants, ``resolution``, ``collision_margin`` and :data:`~pipeline.robot.panda_mesh.BUILDER_VERSION`, so a
    stale file is never used.

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
    try:
        cached = path.is_file()
    except OSError:  # an unreadable cache folder (e.g. a locked $HOME) is no cache
        cached = False
    if cached:
        try:
            return _read_grid_npz(path)
        except Exception:  # noqa: BLE001 -- a truncated/corrupt cache is rebuilt, never trusted
            pass
    grid = build_panda_grid(resolution, collision_margin)
    try:
        _write_atomic_npz(
            path,
            values=grid.values,
            origin=grid.origin,
            resolution=np.float64(grid.resolution),
            outside_value=np.float64(grid.outside_value),
            name=np.str_(grid.name),
        )
    except OSError as e:  # the cache only saves time: an unwritable $HOME must not stop tracking
        _warn_once(f"stucco: cannot write the Panda grid cache {path} ({e.strerror or e}); building it in memory "
                   "each time (set STUCCO_CACHE_DIR to a writable folder)")
    return grid


_WARNED: set[str] = set()


def _warn_once(message: str) -> None:
    """Print ``message`` to stderr once per process."""
    if message not in _WARNED:
        _WARNED.add(message)
        print(message, file=sys.stderr)
