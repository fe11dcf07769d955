"""Pokes: a generic rummage of a rectangle, built from the rectangle, the gripper start and the walls alone.

The generated scenes' ``[actions] sequence`` (:mod:`pipeline.scenes.generate`), and meant for exploration policies
that know where the target may lie but nothing of the objects: :func:`coverage_passes` never sees an object pose.

Like the paper's hand-typed rummages (``data/scenes/FB.toml`` ...), it pokes into the clutter and pulls back,
rather than ploughing whole lanes sideways. First from the side the gripper starts on: from an approach line before
the region, straight moves along +x into the region at several lateral offsets (lanes), each followed by a retreat
along the same line; the pokes of a round all reach the same depth, each round deeper than the last, so an object
is pushed at most one round's depth step by a poke and touched again from the neighbouring lanes (the hand, 0.2 m
wide, overlaps them) before it is pushed further. Then, with more ``sides``, from lines round the region outside it
(-y, the far side, +y) to its middle, where the walls leave the hand room (docs/scene_generator.md, "The target
region and the rummage"): a target hidden behind the clutter from the start is often in view from another side.
"""
from __future__ import annotations

import math

import numpy as np

from pipeline.scenes.footprint import GRIPPER_OUTLINE_M, bounding_box, gripper_outline, separation
from pipeline.scenes.types import DEFAULT_ACTION_SCALE

__all__ = ["coverage_passes", "coverage_waypoints", "lanes", "DEFAULT_LANE_SPACING_M", "DEPTH_STEP_M", "FAR_SLACK_M",
           "SIDES", "SIDE_CLEARANCE_M"]

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
#: Clearance of the hand from the region's edges on the side lines, and from the walls, metres.
SIDE_CLEARANCE_M = 0.02
#: The sides a rummage may poke from: the start's (along +x), then -y (along +y), the far side (along -x), +y.
SIDES = ("front", "right", "far", "left")
Point = tuple[float, float]


def _strips(lo: float, hi: float, width: float) -> list[float]:
    """Centres of the fewest equal strips at most ``width`` wide that cut [lo, hi]."""
    k = max(1, math.ceil((hi - lo) / width - 1e-9))
    return [lo + (i + 0.5) * (hi - lo) / k for i in range(k)]


def _swept_box(a: Point, b: Point) -> np.ndarray:
    """Outline (4, 2) of the rectangle the hand covers moving straight from base ``a`` to base ``b`` (axis-aligned
    moves: exact; others: a cover)."""
    (x0, y0), (x1, y1) = bounding_box([gripper_outline(a), gripper_outline(b)])
    return np.array([[x1, y0], [x1, y1], [x0, y1], [x0, y0]])


def _side_legs(region_m, line_x: float, y_here: float, spacing: float) -> list[tuple[Point, Point, list[list[Point]]]]:
    """The legs round the region counter-clockwise from (``line_x``, ``y_here``) on the approach line and back:
    each (from, to, pokes), the pokes of a side leg ordered along it, each [on the line, deepest, on the line], in
    rounds of at most ``DEPTH_STEP_M`` that reach the region's middle line."""
    (x0, y0), (x1, y1) = region_m
    (gx0, gy0), (gx1, gy1) = GRIPPER_OUTLINE_M
    c = SIDE_CLEARANCE_M
    y_right, y_left, x_far = y0 - gy1 - c, y1 - gy0 + c, x1 - gx0 + c
    mid_x, mid_y = (x0 + x1) / 2.0, (y0 + y1) / 2.0

    def pokes(lanes_: list[float], axis: int, line: float, depth: float, sign: float) -> list[list[Point]]:
        n = max(1, math.ceil(depth / DEPTH_STEP_M - 1e-9))
        out = []
        for lane in lanes_:
            for r in range(1, n + 1):
                deep = line + sign * depth * r / n
                a, b = ((lane, line), (lane, deep)) if axis == 1 else ((line, lane), (deep, lane))
                out.append([a, b, a])
        return out

    xs = [x - (gx0 + gx1) / 2.0 for x in _strips(x0, x1, gx1 - gx0)]  # bases whose hand covers each strip
    ys = _strips(y0, y1, spacing)
    corners = [(line_x, y_right), (x_far, y_right), (x_far, y_left), (line_x, y_left)]
    return [((line_x, y_here), corners[0], []),
            (corners[0], corners[1], pokes(xs, 1, y_right, mid_y - y0 + c, 1.0)),
            (corners[1], corners[2], pokes(ys, 0, x_far, x1 - mid_x + c, -1.0)),
            (corners[2], corners[3], pokes(xs[::-1], 1, y_left, y1 - mid_y + c, -1.0)),
            (corners[3], (line_x, y_here), [])]


def _walk(legs, reverse: bool) -> list[Point]:
    """Waypoints along ``legs`` (each walked from its start, or backwards with ``reverse``), poking on the way."""
    out: list[Point] = []
    for a, b, pk in legs:
        if reverse:
            a, b, pk = b, a, pk[::-1]
        for poke in pk:
            out += poke
        out.append(b)
    return out


def lanes(region_m, start_m, lane_spacing_m: float) -> list[float]:
    """The lanes' y (metres), in the order they are poked: the region's width cut into the fewest equal strips at
    most ``lane_spacing_m`` wide, one lane on each strip's centre line; first the lane nearest the start's y, then
    the others towards the region's nearer y edge, then those on the other side, outward (the approach line's
    sideways moves add up to less than twice the region's width)."""
    (_, y0), (_, y1) = region_m
    ys = _strips(y0, y1, lane_spacing_m)
    k = len(ys)
    sy = float(start_m[1])
    near = min(range(k), key=lambda i: (abs(ys[i] - sy), i))
    if near <= k - 1 - near:  # the lower y edge is the nearer
        return ys[near::-1] + ys[near + 1:]
    return ys[near:] + ys[near - 1::-1]


def coverage_waypoints(region_m: tuple[tuple[float, float], tuple[float, float]], start_m: tuple[float, float], *,
                       lane_spacing_m: float = DEFAULT_LANE_SPACING_M, sides: tuple[str, ...] = ("front",),
                       walls=()) -> list[tuple[float, float]]:
    """Gripper base positions (x, y), metres, of the pokes over ``region_m`` from ``start_m``.

    The approach line is x = min(start x, region x_min - reach) (the fingertips at the region's near edge, or
    the start's if it lies further back). The depth from the line's fingertips to ``FAR_SLACK_M`` before the
    region's far x edge is split into the fewest equal steps of at most ``DEPTH_STEP_M``; round r pokes every lane
    (:func:`lanes`) to r steps deep. A poke is: along the approach line to the lane's y, straight in along +x,
    straight back out to the line. The other ``sides`` follow, on a round of the region (:func:`_side_legs`): each
    leg walked whole where the hand's swept rectangle stays ``SIDE_CLEARANCE_M`` from every wall; with a leg barred,
    the hand goes round as far as the first barred leg, pokes along it as far as it keeps that clearance
    (:func:`_partial`) and comes back, then the same the other way round as far as the last barred leg.

    Parameters
    ----------
    region_m : ((x_min, y_min), (x_max, y_max)), metres
    start_m : (x, y), metres
        Gripper base at the start.
    lane_spacing_m : float, metres
        Largest lateral distance between lanes, > 0.
    sides : tuple of str
        Among :data:`SIDES` ("front" only: the start's side, as before the round was added).
    walls : sequence of ndarray, shape (4, 2)
        Outlines of the scene's walls, metres (static geometry, known to the robot).
    """
    unknown = sorted(set(sides) - set(SIDES))
    if unknown:
        raise ValueError(f"sides {unknown}: expected some of {', '.join(SIDES)}")
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
    if "front" in sides:
        for r in range(1, n_rounds + 1):
            depth = line + (deepest - line) * r / n_rounds
            for y in lanes(region_m, start_m, lane_spacing_m):
                points += [(line, y), (depth, y), (line, y)]
    if not set(sides) - {"front"}:
        return points
    # Round the region on lines outside it, counter-clockwise, and where a wall bars a leg, as far as it lets the
    # hand and back, then the other way round as far as it lets the hand and back.
    legs = _side_legs(region_m, line, points[-1][1], lane_spacing_m)
    for k, name in ((1, "right"), (2, "far"), (3, "left")):
        if name not in sides:
            legs[k] = (legs[k][0], legs[k][1], [])
    clear = [_clear(a, b, walls) for a, b, _ in legs]
    if all(clear):
        return points + _walk(legs, False)
    first, last = clear.index(False), len(clear) - 1 - clear[::-1].index(False)
    out = _walk(legs[:first], False)
    done: set[int] = set()
    out += _partial(legs[first], walls, False, done)
    out += _walk([(a, b, []) for a, b, _ in legs[:first]][::-1], True)
    way = legs[last + 1:][::-1]
    out += _walk(way, True)
    out += _partial(legs[last], walls, True, done if last == first else set())
    out += _walk([(a, b, []) for a, b, _ in way][::-1], False)
    return points + out


def _clear(a: Point, b: Point, walls) -> bool:
    """Whether the hand moving straight from base ``a`` to base ``b`` keeps ``SIDE_CLEARANCE_M`` from every wall."""
    return all(separation(_swept_box(a, b), w) >= SIDE_CLEARANCE_M for w in walls)


def _partial(leg, walls, backward: bool, done: set[int]) -> list[Point]:
    """The pokes of a barred leg the hand reaches from its start (its end with ``backward``) along its line, in
    order, up to the first one whose way along the line or whose own move comes within the clearance of a wall,
    and the way back; the indices of the pokes made are added to ``done`` and those already in it are skipped (the
    leg poked from both ends). A wall near a corner of the round then costs the pokes near it, not the whole side."""
    a, b, pokes = leg
    home = b if backward else a
    order = range(len(pokes) - 1, -1, -1) if backward else range(len(pokes))
    out: list[Point] = []
    for i in order:
        line, deep, _ = pokes[i]
        if not (_clear(home, line, walls) and _clear(line, deep, walls)):
            break
        if i not in done:
            done.add(i)
            out += pokes[i]
    return out + [home] if out else out


def coverage_passes(region_m: tuple[tuple[float, float], tuple[float, float]], start_m: tuple[float, float], *,
                    scale_m: float = DEFAULT_ACTION_SCALE, lane_spacing_m: float = DEFAULT_LANE_SPACING_M,
                    sides: tuple[str, ...] = ("front",), walls=()) -> tuple[tuple[float, float], ...]:
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
    points = coverage_waypoints(region_m, start_m, lane_spacing_m=lane_spacing_m, sides=sides, walls=walls)
    actions: list[tuple[float, float]] = []
    for (ax, ay), (bx, by) in zip(points, points[1:]):
        dx, dy = bx - ax, by - ay
        n = math.ceil(max(abs(dx), abs(dy)) / scale_m - 1e-9)
        if n <= 0:
            continue
        u = (round(dx / (n * scale_m), _DECIMALS) + 0.0, round(dy / (n * scale_m), _DECIMALS) + 0.0)
        actions += [u] * n
    return tuple(actions)
