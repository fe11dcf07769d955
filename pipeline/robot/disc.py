"""The disc robot: a grid SDF of a disc centred on the robot origin, the robot of the anchor benchmark streams.

Units are metres.
"""
from __future__ import annotations

import math

import numpy as np

from pipeline.robot.grid import GridSDF, axis_cells

__all__ = ["disc_sdf"]


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
    n = axis_cells(lo, -lo, resolution)
    c = lo + resolution * np.arange(n)
    x, y = np.meshgrid(c, c, indexing="ij")
    return GridSDF(np.hypot(x, y) - radius, np.array([lo, lo]), resolution, name=f"disc:{radius:g}")
