"""Coverage passes: a generic rummage of a rectangle, built from the rectangle and the gripper start alone.

The generated scenes' ``[actions] sequence`` (:mod:`pipeline.scenes.generate`), and meant for exploration policies
that know where the target may lie but nothing of the objects: :func:`coverage_passes` never sees an object pose.
"""
from __future__ import annotations

import math

from pipeline.scenes.footprint import GRIPPER_OUTLINE_M
from pipeline.scenes.types import DEFAULT_ACTION_SCALE

__all__ = ["coverage_passes", "coverage_waypoints", "DEFAULT_LANE_SPACING_M"]

#: Depth step between two lanes, metres: a little over half the hand's length along x (0.139 m), so each lane's
#: sweep overlaps the previous one.
DEFAULT_LANE_SPACING_M = 0.08
#: Fingertips ahead of the gripper base along +x, metres: lane depths are where the fingertips sweep.
_REACH_M = GRIPPER_OUTLINE_M[1][0]
#: Decimals kept of each normalised action (a 0.03 m action is then exact to 1.5 micrometres).
_DECIMALS = 4


def coverage_waypoints(region_m: tuple[tuple[float, float], tuple[float, float]], start_m: tuple[float, float], *,
                       lane_spacing_m: float = DEFAULT_LANE_SPACING_M) -> list[tuple[float, float]]:
    """Gripper base positions (x, y), metres, of a boustrophedon over ``region_m``, from ``start_m``.

    From the start, move sideways to the region's nearer y edge, then forward until the fingertips are
    ``lane_spacing_m`` into the region; sweep across it along y to the other edge, step ``lane_spacing_m`` deeper,
    sweep back, and so on until the fingertips have swept the region's far x edge. The hand is 0.2 m wide, so a
    sweep with its centre on the region's edges carries it 0.1 m past each one.

    Parameters
    ----------
    region_m : ((x_min, y_min), (x_max, y_max)), metres
    start_m : (x, y), metres
        Gripper base at the start.
    lane_spacing_m : float, metres
        Depth between lanes, > 0.
    """
    (x0, y0), (x1, y1) = region_m
    if not (x0 < x1 and y0 < y1):
        raise ValueError(f"region {region_m}: expected min < max on both axes")
    if not (lane_spacing_m > 0.0 and math.isfinite(lane_spacing_m)):
        raise ValueError(f"lane spacing {lane_spacing_m!r}: expected a positive number of metres")
    n_lanes = max(1, math.ceil((x1 - x0) / lane_spacing_m - 1e-9))
    depths = [min(x0 + lane_spacing_m * (k + 1), x1) for k in range(n_lanes)]
    sx, sy = float(start_m[0]), float(start_m[1])
    side, other = (y0, y1) if abs(sy - y0) <= abs(sy - y1) else (y1, y0)
    points = [(sx, sy), (sx, side)]
    for depth in depths:
        base_x = depth - _REACH_M
        points += [(base_x, side), (base_x, other)]
        side, other = other, side
    return points


def coverage_passes(region_m: tuple[tuple[float, float], tuple[float, float]], start_m: tuple[float, float], *,
                    scale_m: float = DEFAULT_ACTION_SCALE, lane_spacing_m: float = DEFAULT_LANE_SPACING_M
                    ) -> tuple[tuple[float, float], ...]:
    """Normalised actions (u_x, u_y), each in [-1, 1], that move the gripper along :func:`coverage_waypoints`.

    Each leg between waypoints is cut into the fewest equal actions whose displacement is at most ``scale_m`` per
    axis (the scene's ``[actions] scale``); zero-length legs give none. Open loop: a resisting object stops the
    gripper, and later actions start from wherever it is (as the tasks' hand-made sequences do).

    Parameters
    ----------
    region_m : ((x_min, y_min), (x_max, y_max)), metres
    start_m : (x, y), metres
    scale_m : float, metres per unit action, > 0
    lane_spacing_m : float, metres
    """
    if not (scale_m > 0.0 and math.isfinite(scale_m)):
        raise ValueError(f"action scale {scale_m!r}: expected a positive number of metres")
    points = coverage_waypoints(region_m, start_m, lane_spacing_m=lane_spacing_m)
    actions: list[tuple[float, float]] = []
    for (ax, ay), (bx, by) in zip(points, points[1:]):
        dx, dy = bx - ax, by - ay
        n = math.ceil(max(abs(dx), abs(dy)) / scale_m - 1e-9)
        if n <= 0:
            continue
        u = (round(dx / (n * scale_m), _DECIMALS) + 0.0, round(dy / (n * scale_m), _DECIMALS) + 0.0)
        actions += [u] * n
    return tuple(actions)
