"""Pokes: a generic rummage of a rectangle, built from the rectangle and the gripper start alone.

The generated scenes' ``[actions] sequence`` (:mod:`pipeline.scenes.generate`), and meant for exploration policies
that know where the target may lie but nothing of the objects: :func:`coverage_passes` never sees an object pose.

Like the paper's hand-typed rummages (``data/scenes/FB.toml`` ...), it pokes into the clutter from the side the
gripper starts on and pulls back, rather than ploughing whole lanes sideways: from an approach line before the
region, straight moves along +x into the region at several lateral offsets (lanes), each followed by a retreat
along the same line; the pokes of a round all reach the same depth, each round deeper than the last, so an object
is pushed at most one round's depth step by a poke and touched again from the neighbouring lanes (the hand, 0.2 m
wide, overlaps them) before it is pushed further.
"""
from __future__ import annotations

import math

from pipeline.scenes.footprint import GRIPPER_OUTLINE_M
from pipeline.scenes.types import DEFAULT_ACTION_SCALE

__all__ = ["coverage_passes", "coverage_waypoints", "lanes", "DEFAULT_LANE_SPACING_M", "DEPTH_STEP_M", "FAR_SLACK_M"]

#: Lateral distance between two lanes, metres, at most: the hand is 0.2 m wide (y), so neighbouring pokes overlap.
DEFAULT_LANE_SPACING_M = 0.2
#: Depth a round of pokes adds, metres, at most (the rounds split the depth evenly).
DEPTH_STEP_M = 0.3
#: The deepest pokes stop with the fingertips this far short of the region's far x edge, metres: the region holds
#: the target with a margin, and a target's near face lies more than this inside it.
FAR_SLACK_M = 0.05
#: Fingertips ahead of the gripper base along +x, metres: depths are where the fingertips reach.
_REACH_M = GRIPPER_OUTLINE_M[1][0]
#: Decimals kept of each normalised action (a 0.03 m action is then exact to 1.5 micrometres).
_DECIMALS = 4


def lanes(region_m, start_m, lane_spacing_m: float) -> list[float]:
    """The lanes' y (metres), in the order they are poked: the region's width cut into the fewest equal strips at
    most ``lane_spacing_m`` wide, one lane on each strip's centre line; first the lane nearest the start's y, then
    the others towards the region's nearer y edge, then those on the other side, outward (the approach line's
    sideways moves add up to less than twice the region's width)."""
    (_, y0), (_, y1) = region_m
    k = max(1, math.ceil((y1 - y0) / lane_spacing_m - 1e-9))
    ys = [y0 + (i + 0.5) * (y1 - y0) / k for i in range(k)]
    sy = float(start_m[1])
    near = min(range(k), key=lambda i: (abs(ys[i] - sy), i))
    if near <= k - 1 - near:  # the lower y edge is the nearer
        return ys[near::-1] + ys[near + 1:]
    return ys[near:] + ys[near - 1::-1]


def coverage_waypoints(region_m: tuple[tuple[float, float], tuple[float, float]], start_m: tuple[float, float], *,
                       lane_spacing_m: float = DEFAULT_LANE_SPACING_M) -> list[tuple[float, float]]:
    """Gripper base positions (x, y), metres, of the pokes over ``region_m`` from ``start_m``.

    The approach line is x = min(start x, region x_min - reach) (the fingertips at the region's near edge, or
    the start's if it lies further back). The depth from the line's fingertips to ``FAR_SLACK_M`` before the
    region's far x edge is split into the fewest equal steps of at most ``DEPTH_STEP_M``; round r pokes every lane
    (:func:`lanes`) to r steps deep. A poke is: along the approach line to the lane's y, straight in along +x,
    straight back out to the line.

    Parameters
    ----------
    region_m : ((x_min, y_min), (x_max, y_max)), metres
    start_m : (x, y), metres
        Gripper base at the start.
    lane_spacing_m : float, metres
        Largest lateral distance between lanes, > 0.
    """
    (x0, y0), (x1, y1) = region_m
    if not (x0 < x1 and y0 < y1):
        raise ValueError(f"region {region_m}: expected min < max on both axes")
    if not (lane_spacing_m > 0.0 and math.isfinite(lane_spacing_m)):
        raise ValueError(f"lane spacing {lane_spacing_m!r}: expected a positive number of metres")
    sx, sy = float(start_m[0]), float(start_m[1])
    line = min(sx, x0 - _REACH_M)
    deepest = max(x1 - FAR_SLACK_M, (x0 + x1) / 2.0) - _REACH_M  # base x of the deepest pokes
    n_rounds = max(1, math.ceil((deepest - line) / DEPTH_STEP_M - 1e-9))
    points = [(sx, sy), (line, sy)]
    for r in range(1, n_rounds + 1):
        depth = line + (deepest - line) * r / n_rounds
        for y in lanes(region_m, start_m, lane_spacing_m):
            points += [(line, y), (depth, y), (line, y)]
    return points


def coverage_passes(region_m: tuple[tuple[float, float], tuple[float, float]], start_m: tuple[float, float], *,
                    scale_m: float = DEFAULT_ACTION_SCALE, lane_spacing_m: float = DEFAULT_LANE_SPACING_M
                    ) -> tuple[tuple[float, float], ...]:
    """Normalised actions (u_x, u_y), each in [-1, 1], that move the gripper along :func:`coverage_waypoints`.

    Each leg between waypoints is cut into the fewest equal actions whose displacement is at most ``scale_m`` per
    axis (the scene's ``[actions] scale``); zero-length legs give none. Open loop: a resisting object stops the
    gripper, and later actions start from wherever it is (as the tasks' hand-made sequences do); a poke's retreat
    is the same actions reversed, so a stopped poke ends behind the approach line, never in the clutter.
    Deterministic: a function of its four arguments only.

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
