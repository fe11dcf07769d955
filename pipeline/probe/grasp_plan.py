"""A grasp planned for the scene as sensed: every approach the target's shape allows, scored by the share of the
plausible set it holds and by whether the gripper can get there (docs/active.md, "The planned grasp").

No per-task script: the candidates are the approaches the target's symmetry allows (a box's two ends, since the
open hand spans only its short side; a can from any side), centred on the set's hypotheses. Each is scored by
the geometric success rule (:mod:`pipeline.grasp_rule`) over the set, and kept only if the gripper can reach its
pre-grasp point and advance along its lane: a path on a grid in the plane from where the gripper is, through
space it has visited or that no sensed object occupies, with a clearance. What counts as occupied comes only from
what the robot sensed (:class:`Surroundings`): the target's hypotheses, the contacts attributed to other objects
(an object of unknown extent lies beyond each), and the scene's static walls (the fixed workspace); never the
objects' true poses.

Everything is arrays: cells (C,), candidate grasps (G,), hypotheses (H,); the path search is one Dijkstra from
the gripper over the grid (scipy.sparse.csgraph).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from pipeline.geometry import Primitive, outline_point, primitive_pose, rotate, wrap_angle, wrap_symmetric
from pipeline.grasp import OPEN, PAD_FROM_BASE, GraspParams, GraspPlan
from pipeline.grasp_rule import box_success, can_success
from pipeline.probe.plane_grid import PlaneGrid, simplify_path

__all__ = ["Surroundings", "PlanningParams", "PlannedGrasp", "plan_grasp", "approach_offset", "held_by"]


@dataclass(frozen=True)
class PlanningParams:
    """Knobs of the planned grasp.

    Attributes
    ----------
    cell : float, metres
        Grid resolution of the path search.
    object_radius : float, metres
        An object met at a contact point is taken as a disc of this radius just beyond the point (the distractors
        of the shipped scenes are 3-5 cm across).
    clearance : float, metres
        Clearance kept from every sensed obstacle, on the way and along the lane.
    target_clearance : float, metres
        Clearance kept from the target's likely hypotheses on the way to the pre-grasp point (a touch turns it
        before the fingers close).
    likely_share : float
        The hypotheses kept clear of are the most likely ones that make up this share of the set's weight.
    max_likely : int
        At most this many of them.
    unknown_cost : float
        Path cost per metre through space never visited, relative to visited space (prefer the known way).
    object_cost : float
        Path cost per metre where the gripper would meet a sensed object never visited (it may push it aside, as
        the paper's script does, but a free way is preferred).
    lane_cost : float
        Cost (metres of free path) of a lane that passes a sensed object.
    between_cost : float
        Further cost (metres of free path) of a lane with a sensed object between the open fingers, short of the
        target: the fingers would close on it, or push it into the target.
    can_directions : int
        Approach directions tried around a can.
    advances : tuple of int
        Approach actions tried, the grasp script's own (4) first: among grasps of equal share and way in, the
        first wins (3 actions stop the fingers near the box's end, where the rule is optimistic).
    attempts : int
        Grasp attempts allowed (each after re-planning with what the last one sensed).
    switch_share : float
        A felt miss of a grasp that held at least this share of the set's weight says the set's segment is not
        the target's: the next attempt is planned on the next-ranked segment's set (when there is one).
    """

    cell: float = 0.01
    object_radius: float = 0.035
    clearance: float = 0.005
    target_clearance: float = 0.01
    likely_share: float = 0.9
    max_likely: int = 12
    unknown_cost: float = 1.5
    object_cost: float = 5.0
    lane_cost: float = 1.0
    between_cost: float = 3.0
    can_directions: int = 16
    advances: tuple[int, ...] = (4, 3, 5)
    attempts: int = 3
    switch_share: float = 0.9


@dataclass
class Surroundings:
    """What the robot sensed around the target, in the plane (metres); nothing here is ground truth.

    Attributes
    ----------
    here : ndarray, shape (2,)
        The gripper's position now.
    visited : ndarray, shape (V, 2)
        Positions the gripper occupied (free space when it was there).
    obstacles : ndarray, shape (O, 2)
        Contact points attributed to objects other than the target.
    walls : list of (centre (2,), half extents (2,), yaw)
        The scene's static walls (the workspace's fixed geometry).
    outline : ndarray, shape (K, 2)
        The gripper's outline (robot frame) during transit.
    tried : ndarray, shape (T, 3)
        Grasps already attempted and felt to miss: (yaw, centre x, centre y); the planner does not repeat them.
    """

    here: np.ndarray
    visited: np.ndarray
    obstacles: np.ndarray
    walls: list
    outline: np.ndarray
    tried: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def moved(self, here: np.ndarray, trail: list | None = None) -> Surroundings:
        """A copy with the gripper at ``here`` (2,), having passed the positions ``trail`` (each (2,))."""
        visited = np.vstack([self.visited, *(trail or []), np.reshape(here, (1, 2))])
        return dataclasses.replace(self, here=np.asarray(here, dtype=np.float64).copy(), visited=visited)

    def with_obstacle(self, point: np.ndarray) -> Surroundings:
        """A copy with one more sensed obstacle contact (2,)."""
        return dataclasses.replace(self, obstacles=np.vstack([self.obstacles, np.reshape(point, (1, 2))]))

    def with_miss(self, yaw: float, centre: np.ndarray) -> Surroundings:
        """A copy that remembers a grasp (yaw, centre (2,)) felt to miss."""
        return dataclasses.replace(self, tried=np.vstack([self.tried, np.r_[yaw, centre][None, :]]))


@dataclass
class PlannedGrasp:
    """The grasp chosen, with its way in.

    Attributes
    ----------
    yaw : float, radians
        Grasp yaw: the hand approaches along ``(-sin yaw, cos yaw)`` and closes along ``(cos yaw, sin yaw)``.
    centre : ndarray, shape (2,)
        Point the grasp is centred on.
    advance : int
        Approach actions.
    offset : float, metres
        Pre-grasp distance before ``centre`` along the approach.
    share : float
        Weighted share of the set the geometric rule says it holds.
    pregrasp, approach : ndarray, shape (2,)
    via : ndarray, shape (W, 2)
        Waypoints to the pre-grasp point (the last is the pre-grasp point itself).
    reachable : bool
        A way in was found (False: ``no_reachable_grasp``; the fields are those of the best share, for reporting).
    cost : float, metres
        Length of the way in (weighted: unknown space costs ``unknown_cost`` per metre).
    """

    yaw: float
    centre: np.ndarray
    advance: int
    offset: float
    share: float
    pregrasp: np.ndarray
    approach: np.ndarray
    via: np.ndarray
    reachable: bool
    cost: float


def _half_along(prim: Primitive) -> float:
    """How far (m) the target extends from its centre along the approach: a box's long half, a can's radius."""
    return float(prim.half[1] if prim.kind == "box" else prim.half[0])


def approach_offset(prim: Primitive) -> float:
    """Pre-grasp distance (m) from the target's centre: the open fingers' tips (``PAD_FROM_BASE[1]`` ahead of the
    hand's base) stay 5 cm short of the target's far extent along the approach (0.24 m for the cracker box, the
    paper's script 0.25; 0.2 m for a can)."""
    return max(0.2, round(_half_along(prim) + PAD_FROM_BASE[1] + 0.05, 2))


def held_by(prim: Primitive, scale: float, yaw: np.ndarray, centre: np.ndarray, advance: np.ndarray,
            offset: float, poses: np.ndarray, params: GraspParams = GraspParams()) -> np.ndarray:
    """Whether each grasp (yaw (G,), centre (G, 2), advance (G,)) holds each COM pose (H, 3), by the geometric
    rule of :mod:`pipeline.grasp_rule` with the pre-grasp ``offset`` (m). Returns bool (G, H)."""
    plan = GraspPlan(offset=offset, yaw_range=None)
    if prim.kind == "cylinder":
        return can_success(prim, poses, yaw, centre, advance, plan, scale)
    return box_success(prim, poses, yaw, centre, advance, plan, scale, params)


def _candidates(prim: Primitive, poses: np.ndarray, weights: np.ndarray, best: int, params: PlanningParams
                ) -> tuple[np.ndarray, np.ndarray]:
    """Candidate (yaw (G,), centre (G, 2)): every approach the shape allows at each hypothesis's centre and at the
    weighted mean centre of the hypotheses agreeing with its yaw; the estimate's first."""
    centres = prim.centre_world(poses)
    axes = primitive_pose(prim, poses)[:, 2]
    order = np.r_[best, np.delete(np.arange(len(poses)), best)]
    if prim.kind == "cylinder":
        dirs = 2 * np.pi * np.arange(params.can_directions) / params.can_directions
        c = np.vstack([centres[order], np.sum(weights[:, None] * centres, axis=0)])
        return np.repeat(dirs[None, :], len(c), axis=0).ravel(), np.repeat(c, len(dirs), axis=0)
    # A box is held across its short side: approach along its long axis (primitive y), from either end.
    near = (np.abs(wrap_symmetric(axes[:, None] - axes[None, :], np.pi)) < 0.05) * weights[None, :]
    # sums, not a matrix product: no BLAS call decides a candidate (the same bits on every CPU)
    pooled = np.sum(near[:, :, None] * centres[None, :, :], axis=1) / np.maximum(near.sum(axis=1), 1e-12)[:, None]
    pooled = np.where(near.sum(axis=1)[:, None] > 0, pooled, centres)  # a group of zero weight: its own centre
    yaw = np.r_[axes[order], axes[order]]
    centre = np.vstack([centres[order], pooled[order]])
    return np.r_[yaw, yaw + np.pi], np.vstack([centre, centre])


def _likely(poses: np.ndarray, weights: np.ndarray, params: PlanningParams) -> np.ndarray:
    """Indices of the most likely hypotheses that make up ``likely_share`` of the weight (at most ``max_likely``)."""
    order = np.argsort(-weights, kind="stable")
    k = int(np.searchsorted(np.cumsum(weights[order]), params.likely_share * np.sum(weights))) + 1
    return order[:min(k, params.max_likely, len(order))]


def _rectangle_outline(hx: float, hy: float, spacing: float) -> np.ndarray:
    """Points (P, 2), metres, about ``spacing`` apart along the outline of [-hx, hx] x [-hy, hy] (at least 8)."""
    n = max(8, int(4 * (hx + hy) / spacing))
    return outline_point((np.arange(n) + 0.5) * 4 * (hx + hy) / n, hx, hy)


def _target_points(prim: Primitive, poses: np.ndarray, spacing: float) -> np.ndarray:
    """Outline points (P, 2) of the target at each pose (H, 3)."""
    pp = primitive_pose(prim, poses)
    if prim.kind == "cylinder":
        n = max(8, int(2 * np.pi * prim.half[0] / spacing))
        a = 2 * np.pi * np.arange(n) / n
        local = prim.half[0] * np.column_stack([np.cos(a), np.sin(a)])
    else:
        local = _rectangle_outline(prim.half[0], prim.half[1], spacing)
    return (pp[:, None, :2] + rotate(local[None, :, :], pp[:, 2, None])).reshape(-1, 2)


def _obstacle_discs(s: Surroundings, prim: Primitive, estimate: np.ndarray, params: PlanningParams) -> np.ndarray:
    """Centres (O', 2) of the discs taken for the other objects: each just beyond its contact point, seen from the
    nearest visited position; contacts within 1 cm of the target at the estimate are the target's own."""
    if len(s.obstacles) == 0:
        return np.zeros((0, 2))
    pts = np.asarray(s.obstacles, dtype=np.float64).reshape(-1, 2)
    pts = pts[prim.signed_distance(pts, estimate) > 0.01]
    if len(pts) == 0:
        return np.zeros((0, 2))
    nearest = s.visited[cKDTree(s.visited).query(pts)[1]]
    away = pts - nearest
    away /= np.maximum(np.linalg.norm(away, axis=1, keepdims=True), 1e-9)
    return pts + params.object_radius * away


def _wall_points(walls: list, spacing: float) -> np.ndarray:
    """Points (P, 2) along each wall's outline at ``spacing`` (the gripper starts outside every wall, so it can
    only enter one across its outline)."""
    out = [np.zeros((0, 2))]
    for centre, half, yaw in walls:
        local = _rectangle_outline(float(half[0]), float(half[1]), spacing)
        out.append(np.asarray(centre, dtype=np.float64) + rotate(local, yaw))
    return np.vstack(out)


def _in_lane_frame(yaw: np.ndarray, pre: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each point (B, 2) in each lane's frame (pre-grasp (G, 2), yaw (G,)): how far along the approach from the
    pre-grasp point, and how far across it (absolute), both (G, B), metres."""
    approach = np.column_stack([-np.sin(yaw), np.cos(yaw)])
    closing = np.column_stack([np.cos(yaw), np.sin(yaw)])
    rel = points[None, :, :] - pre[:, None, :]
    return np.sum(rel * approach[:, None, :], axis=-1), np.abs(np.sum(rel * closing[:, None, :], axis=-1))


def _lane_clear(along: np.ndarray, across: np.ndarray, advance: np.ndarray, scale: float, margin: float
                ) -> np.ndarray:
    """Whether the open hand's swept footprint along each lane (from its pre-grasp point to ``advance`` (G,)
    actions on) keeps ``margin`` from every blocker point, given the points in the lanes' frames (``along``,
    ``across`` (G, B), :func:`_in_lane_frame`). Returns bool (G,)."""
    half_width = OPEN + 0.012 + margin  # the open fingers and their thickness
    inside = (along >= -0.03 - margin) & (along <= advance[:, None] * scale + PAD_FROM_BASE[1] + margin) & \
        (across <= half_width)
    return ~inside.any(axis=1)


def _between_fingers(along: np.ndarray, across: np.ndarray, depth: float) -> np.ndarray:
    """Whether a disc centre lies between the open fingers of each lane within ``depth`` (m) of its pre-grasp point
    along the approach, given the centres in the lanes' frames (``along``, ``across`` (G, B), :func:`_in_lane_frame`).
    Returns bool (G,)."""
    return ((along >= 0.0) & (along <= depth) & (across <= OPEN)).any(axis=1)


def plan_grasp(prim: Primitive, scale: float, poses: np.ndarray, weights: np.ndarray, best: int,
               surroundings: Surroundings, params: PlanningParams = PlanningParams(),
               grasp: GraspParams = GraspParams()) -> PlannedGrasp:
    """The reachable grasp that holds the largest weighted share of the set (COM poses (H, 3), weights (H,) >= 0),
    then the cheapest way in (a lane past a sensed object costing extra), then the estimate's own (``best``) first
    among equals; a lane through a wall is never taken.

    Returns the best share's grasp with ``reachable`` False when no candidate can be reached."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    w = np.asarray(weights, dtype=np.float64)
    if len(poses) == 0 or not (np.all(np.isfinite(poses)) and np.all(np.isfinite(w)) and np.all(w >= 0)
                               and np.sum(w) > 0):
        raise ValueError("plan_grasp: the set needs finite poses and finite weights >= 0, not all 0")
    w = w / np.sum(w)
    offset = approach_offset(prim)
    yaw0, centre0 = _candidates(prim, poses, w, best, params)
    adv = np.asarray(params.advances, dtype=np.float64)
    g_yaw = np.tile(yaw0, len(adv))
    g_centre = np.tile(centre0, (len(adv), 1))
    g_adv = np.repeat(adv, len(yaw0))
    share = np.sum(held_by(prim, scale, g_yaw, g_centre, g_adv, offset, poses, grasp) * w[None, :], axis=1)
    approach = np.column_stack([-np.sin(g_yaw), np.cos(g_yaw)])
    pre = g_centre - offset * approach

    s = surroundings
    discs = _obstacle_discs(s, prim, poses[best], params)
    walls = _wall_points(s.walls, params.cell)
    likely = _target_points(prim, poses[_likely(poses, w, params)], params.cell)
    spanned = np.vstack([s.here[None, :], s.visited, pre, poses[:, :2]])
    grid = PlaneGrid(spanned.min(axis=0) - 0.1, spanned.max(axis=0) + 0.1, params.cell)
    outline = np.asarray(s.outline, dtype=np.float64).reshape(-1, 2)

    def overlaps(points: np.ndarray, radius: float, cells: np.ndarray) -> np.ndarray:
        if len(points) == 0:
            return np.zeros(len(cells), dtype=bool)
        tree = cKDTree((points[:, None, :] - outline[None, :, :]).reshape(-1, 2))
        return np.isfinite(tree.query(cells, distance_upper_bound=radius)[0])

    cells = grid.centres
    by_target = overlaps(likely, params.target_clearance + 0.5 * params.cell, cells)
    by_walls = overlaps(walls, params.clearance + 0.5 * params.cell, cells)
    by_objects = overlaps(discs, params.object_radius + params.clearance, cells)
    seen = np.zeros(len(cells), dtype=bool)
    seen[grid.index(s.visited)] = True
    # The target's hypotheses and the walls are modelled and block; an object of unknown extent only costs (where
    # the gripper has been it cannot be, unless pushed there since: then the attempt feels it and re-plans).
    free = ~by_target & ~by_walls
    # the robot may always leave the space it occupies (a gripper that stopped against a hypothesis of the target)
    near_here = params.target_clearance + 1.5 * params.cell
    free |= np.hypot(cells[:, 0] - s.here[0], cells[:, 1] - s.here[1]) <= near_here
    weight = np.where(seen, 1.0, np.where(by_objects, params.object_cost, params.unknown_cost))
    cost, pred = grid.graph(free, weight, int(grid.index(s.here)[0]))

    pre_cell = grid.index(pre)
    # Nearest-cell rounding may land a pre-grasp point a few millimetres inside a blocked cell: require the cell.
    reach_cost = np.where(free[pre_cell], cost[pre_cell], np.inf)
    lane_margin = params.object_radius + params.clearance
    disc_along, disc_across = _in_lane_frame(g_yaw, pre, discs)  # once, for both tests on the discs
    lane_ok = _lane_clear(disc_along, disc_across, g_adv, scale, lane_margin)
    # an object's disc centred up to its radius beyond the target's near face still lies in the fingers' way
    between = _between_fingers(disc_along, disc_across, offset - _half_along(prim) + params.object_radius)
    lane_in_wall = ~_lane_clear(*_in_lane_frame(g_yaw, pre, walls), g_adv, scale, params.clearance)
    fresh = np.ones(len(g_yaw), dtype=bool)
    for yaw_t, cx, cy in s.tried:
        turn = np.abs(wrap_angle(g_yaw - yaw_t))
        fresh &= (turn > 0.2) | (np.hypot(g_centre[:, 0] - cx, g_centre[:, 1] - cy) > 0.015)
    feasible = np.isfinite(reach_cost) & (share > 0) & fresh & ~lane_in_wall  # the open hand cannot sweep a wall
    if feasible.any():
        # The largest share first; among equal shares the cheapest way in, a lane past a sensed object costing
        # extra, and more with one between the fingers (argmin keeps the estimate's own grasp first among equals).
        top = np.max(share[feasible])
        pick = np.flatnonzero(feasible & (share >= top - 1e-12))
        total = reach_cost + params.lane_cost * ~lane_ok + params.between_cost * between
        j = int(pick[np.argmin(total[pick])])
        node, path = int(pre_cell[j]), []
        while node >= 0:
            path.append(grid.centres[node])
            node = int(pred[node])
        path = np.array(path[::-1])
        path[0], path[-1] = s.here, pre[j]
        via = simplify_path(path, lambda q: free[grid.index(q)] | (np.linalg.norm(q - s.here, axis=1) <= near_here),
                            lambda q: weight[grid.index(q)])
        reachable, c = True, float(reach_cost[j])
    else:
        j = int(np.argmax(share))
        via, reachable, c = pre[j][None, :], False, math.inf
    return PlannedGrasp(yaw=float(g_yaw[j]), centre=g_centre[j].copy(), advance=int(g_adv[j]), offset=offset,
                        share=float(share[j]), pregrasp=pre[j].copy(), approach=approach[j].copy(), via=via,
                        reachable=reachable, cost=c)
