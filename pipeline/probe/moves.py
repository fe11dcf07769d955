"""Guarded moves and transit of the probing policy (docs/active.md): retrace visited
positions, advance along a line until the detector reports contact and back off, return to where the scripted
part ended. Every action goes through the collect stage's ``act`` callback, which simulates and records it."""
from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from pipeline.geometry import Primitive
from pipeline.probe.belief import PoseSet, Sensing
from pipeline.probe.transit import Keepout, path_to, transit_graph

#: Visited positions within this distance (m) of where a transit met an object are left out of later transits.
BLOCK_RADIUS = 0.03

__all__ = ["Act", "retrace", "guarded_move", "transit_limits", "reaching", "return_to_start"]

Act = Callable[[float, float], dict]


def retrace(act: Act, here: np.ndarray, path: np.ndarray, step: float, backoff: float,
            light: Callable[[dict], bool] | None = None, push_through: float = 0.0) -> tuple[np.ndarray, int, bool]:
    """Move through the waypoints ``path`` (P, 2) in actions no longer than ``step`` per axis; at the first action
    detected in contact, back off by ``backoff`` and stop. With ``light`` (an action's row -> whether its contact
    met less than the light limit), a light contact does not stop the move for the first ``push_through`` metres
    moved in contact: a light object that came to lie across visited space is pushed on, as the guarded move
    does (:func:`guarded_move`). Returns (position, actions, contact)."""
    pts = np.vstack([here[None, :], np.asarray(path, dtype=np.float64).reshape(-1, 2)])
    n, pushed = 0, 0.0
    for a, b in zip(pts[:-1], pts[1:]):
        d = b - a
        k = int(np.ceil(np.max(np.abs(d)) / step - 1e-9))
        for _ in range(max(k, 0)):
            row = act(float(d[0] / k), float(d[1] / k))
            n += 1
            here = np.array([row["ee_x_m"], row["ee_y_m"]])
            if row["in_contact"] and light is not None and pushed < push_through and light(row):
                pushed += math.hypot(*d) / k
                continue
            if row["in_contact"]:
                u = -d / math.hypot(*d) * backoff
                row = act(float(u[0]), float(u[1]))
                return np.array([row["ee_x_m"], row["ee_y_m"]]), n + 1, True
    return here, n, False


def guarded_move(act: Act, here: np.ndarray, direction: np.ndarray, predicted: np.ndarray, params,
                 light: Callable[[dict], bool] | None = None) -> tuple[np.ndarray, int, bool, float]:
    """Advance along ``direction`` until contact, then back off. Returns (position, actions, contact, travel to the
    contact in metres (inf without one)).

    ``params`` is a :class:`pipeline.probe.policy.ProbeParams`. ``predicted`` (H,): each hypothesis's travel to
    contact (inf: none); the move is fast until ``slow_zone`` before the earliest and gives up ``overshoot`` past
    the latest finite one (or at ``plan.max_travel``). With ``params.push_through`` and ``light`` (an action's row
    -> whether its contact met less than the light limit), a light contact does not stop the move: it goes on in
    fine steps, pushing what it met (or past it, once it slid aside), for at most ``push_through`` metres from
    the first contact, and stops at the first contact that is not light (travel: to the first contact).
    """
    fin = predicted[np.isfinite(predicted)]
    slow = max(0.0, float(fin.min()) - params.slow_zone) if len(fin) else 0.0
    limit = min(params.plan.max_travel, float(fin.max()) + params.overshoot) if len(fin) else params.plan.max_travel
    t, n = 0.0, 0
    d = np.asarray(direction, dtype=np.float64)
    contact, first, carry = False, math.inf, params.push_through if light is not None else 0.0
    while t < limit:
        step = params.coarse_step if t + params.coarse_step <= slow and first == math.inf else params.fine_step
        row = act(float(d[0] * step), float(d[1] * step))
        n += 1
        t += step
        here = np.array([row["ee_x_m"], row["ee_y_m"]])
        if row["in_contact"]:
            first = min(first, t)
            if t - first < carry and light(row):
                continue  # a light object: push it aside
            contact = True
            break
    else:  # past the limit while pushing a light object on: it is still a contact to back off from
        contact = first < math.inf and bool(row["in_contact"])
    travel = first if contact else np.inf
    if contact:
        row = act(float(-d[0] * params.backoff), float(-d[1] * params.backoff))
        n += 1
        here = np.array([row["ee_x_m"], row["ee_y_m"]])
    return here, n, contact, travel


def transit_limits(sensing: Sensing, target: Primitive, belief: PoseSet, outline: np.ndarray, plan,
                   returning: bool = False) -> list[tuple[np.ndarray, Keepout | None]]:
    """What transit must avoid, strictest first: pairs of (visited positions reached in contact by a probe or
    blocked by a transit's contact (K,), :attr:`Sensing.avoided`; the keep-out around the target at the set's
    estimate). ``plan`` is a
    :class:`pipeline.probe.planning.PlanParams`; the first pair that leaves transit somewhere to go is used, and
    a probe is planned under the laxer ones in turn when it leaves none (:func:`reaching`,
    :func:`pipeline.probe.policy.next_probe`).

    Transit to a probe's start only keeps the gripper's positions out of the target (a move that grazes it ends
    the probe as a contact, and starts close to the target are the informative ones: keeping the clearance there
    as well cost grasps, docs/active.md).

    The return before the grasp must not touch the target at all (a contact there turns it after the last
    decision, unseen): it keeps ``plan.transit_clearance`` from it, positions and moves alike, else two thirds
    of that, one third, none (the far side of the target may be linked to the rest by a narrow passage), then
    positions only, and last no keep-out, for a gripper that ended the scripted part pressed against the
    target."""
    touching = sensing.avoided
    pose = np.asarray(belief.poses[belief.best], dtype=np.float64)
    positions = Keepout(target, pose, outline, 0.0, links=False)
    if not returning:
        return [(touching, positions), (touching, None)]
    margins = plan.transit_clearance * np.array([1.0, 2 / 3, 1 / 3, 0.0])
    return [(touching, Keepout(target, pose, outline, float(m))) for m in margins] + \
        [(touching, positions), (touching, None)]


def reaching(sensing: Sensing, limits: list[tuple[np.ndarray, Keepout | None]], link_radius: float
             ) -> list[tuple[np.ndarray, Keepout | None, tuple[np.ndarray, np.ndarray] | None]]:
    """``limits`` (:func:`transit_limits`, strictest first) from the first under which transit reaches some
    visited position other than the current one (the last limit alone otherwise), each with the transit graph
    built to find it ((distance, predecessor) of :func:`transit_graph` for the first, None for the rest)."""
    for i, (touching, keepout) in enumerate(limits[:-1]):
        graph = transit_graph(sensing.visited, link_radius, touching, keepout)
        if np.isfinite(graph[0]).sum() > 1:
            return [(*limits[i], graph)] + [(*lim, None) for lim in limits[i + 1:]]
    return [(*limits[-1], None)]


def return_to_start(act: Act, sensing: Sensing, params, limits: list[tuple[np.ndarray, Keepout | None]],
                    attempts: int = 4, grasp_path: Callable[[np.ndarray], np.ndarray] | None = None) -> int:
    """Retrace visited positions (not those reached in contact, nor through the keep-out) from the current one to
    where the grasp can start: with ``grasp_path`` (a start (2,) -> the positions (M, 2) the grasp's move to its
    pre-grasp point passes, :func:`pipeline.probe.transit.grasp_transit`), the nearest position from which that
    move keeps the strictest keep-out's clearance from the target; else (or when none does) the scripted part's
    last position clear of the strictest keep-out (else its last position). Either is sought under the strictest
    of ``limits`` (:func:`transit_limits`) that reaches one. A contact on the way (an object now lies where the
    gripper once passed) backs off and the visited positions within 3 cm of it are left out of the next try.
    Returns the actions made (none if no position can be reached or the gripper is already there)."""
    visited = sensing.visited.copy()
    masks = [np.asarray(t, dtype=bool).copy() for t, _ in limits]
    here, n = visited[-1], 0
    for _ in range(attempts):
        visited = np.vstack([visited, here])
        masks = [np.r_[m, False] for m in masks]
        # The scripted part may have ended pressed against the target: aim for its last position clear of the
        # strictest keep-out first, then for its last position.
        strict = limits[0][1]
        clear = strict.clearance(visited) >= strict.margin if strict is not None else np.ones(len(visited), bool)
        scripted = slice(0, sensing.n_scripted + 1)
        graphs: dict[int, tuple] = {}  # limit -> (dist, pred): each graph built once per try
        path = None
        if grasp_path is not None and strict is not None:
            path = _grasp_start(visited, masks, limits, graphs, params.plan.link_radius, grasp_path, strict)
        for want in (clear[scripted], np.ones(sensing.n_scripted + 1, dtype=bool)):
            if path is not None:
                break
            for j, (mask, (_, keepout)) in enumerate(zip(masks, limits)):
                if j not in graphs:
                    graphs[j] = transit_graph(visited, params.plan.link_radius, mask, keepout)
                dist, pred = graphs[j]
                free = np.flatnonzero(want & ~mask[scripted] & np.isfinite(dist[scripted]))
                if len(free):
                    path = path_to(pred, visited, int(free[-1]))
                    break
        if path is None or len(path) == 0:
            break
        here, k, contact = retrace(act, here, path, params.transit_step, params.backoff)
        n += k
        if not contact:
            break
        near = np.linalg.norm(visited - here, axis=1) < BLOCK_RADIUS
        masks = [m | near for m in masks]
    return n


def _grasp_start(visited: np.ndarray, masks: list, limits: list, graphs: dict, link_radius: float,
                 grasp_path: Callable[[np.ndarray], np.ndarray], strict: Keepout) -> np.ndarray | None:
    """The retraced path (P, 2; empty: stay) to the nearest visited position, reachable under the strictest of
    ``limits`` with a keep-out that checks moves (``links``) under which one is, from which the grasp's move to
    its pre-grasp point keeps ``strict.margin`` from the target; None if there is none."""
    for j, (mask, (_, keepout)) in enumerate(zip(masks, limits)):
        if keepout is None or not keepout.links:
            break  # transit that may touch or cross the target is no start for a grasp that must not
        if j not in graphs:
            graphs[j] = transit_graph(visited, link_radius, mask, keepout)
        dist, pred = graphs[j]
        reach = np.flatnonzero(~mask & np.isfinite(dist))
        # Nearest first, each candidate's grasp move checked only until one keeps clear.
        for node in reach[np.argsort(dist[reach], kind="stable")]:
            way = grasp_path(visited[node])
            if len(way) < 2 or np.min(strict.link_clearance(way[:-1], way[1:])) >= strict.margin:
                return np.zeros((0, 2)) if node == len(visited) - 1 else path_to(pred, visited, int(node))
    return None
