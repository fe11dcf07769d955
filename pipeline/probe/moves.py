"""Guarded moves and transit of the probing policy (docs/retrieval.md, "Active retrieval"): retrace visited
positions, advance along a line until the detector reports contact and back off, return to where the scripted
part ended. Every action goes through the collect stage's ``act`` callback, which simulates and records it."""
from __future__ import annotations

import math

from typing import Callable

import numpy as np

from pipeline.geometry import Primitive
from pipeline.probe.belief import PoseSet, Sensing
from pipeline.probe.planning import near_target, path_to, transit_graph

__all__ = ["Act", "retrace", "guarded_move", "blocked_positions", "return_to_start"]

Act = Callable[[float, float], dict]


def retrace(act: Act, here: np.ndarray, path: np.ndarray, step: float, backoff: float
            ) -> tuple[np.ndarray, int, bool]:
    """Move through the waypoints ``path`` (P, 2) in actions no longer than ``step`` per axis; at the first action
    detected in contact, back off by ``backoff`` and stop. Returns (position, actions, contact)."""
    pts = np.vstack([here[None, :], np.asarray(path, dtype=np.float64).reshape(-1, 2)])
    n = 0
    for a, b in zip(pts[:-1], pts[1:]):
        d = b - a
        k = int(np.ceil(np.max(np.abs(d)) / step - 1e-9))
        for _ in range(max(k, 0)):
            row = act(float(d[0] / k), float(d[1] / k))
            n += 1
            here = np.array([row["ee_x_m"], row["ee_y_m"]])
            if row["in_contact"]:
                u = -d / math.hypot(*d) * backoff
                row = act(float(u[0]), float(u[1]))
                return np.array([row["ee_x_m"], row["ee_y_m"]]), n + 1, True
    return here, n, False


def guarded_move(act: Act, here: np.ndarray, direction: np.ndarray, predicted: np.ndarray, params
                 ) -> tuple[np.ndarray, int, bool, float]:
    """Advance along ``direction`` until contact, then back off. Returns (position, actions, contact, travel to the
    contact in metres (inf without one)).

    ``params`` is a :class:`pipeline.probe.policy.ProbeParams`. ``predicted`` (H,): each hypothesis's travel to
    contact (inf: none); the move is fast until ``slow_zone`` before the earliest and gives up ``overshoot`` past
    the latest finite one (or at ``plan.max_travel``).
    """
    fin = predicted[np.isfinite(predicted)]
    slow = max(0.0, float(fin.min()) - params.slow_zone) if len(fin) else 0.0
    limit = min(params.plan.max_travel, float(fin.max()) + params.overshoot) if len(fin) else params.plan.max_travel
    t, n = 0.0, 0
    d = np.asarray(direction, dtype=np.float64)
    contact = False
    while t < limit:
        step = params.coarse_step if t + params.coarse_step <= slow else params.fine_step
        row = act(float(d[0] * step), float(d[1] * step))
        n += 1
        t += step
        here = np.array([row["ee_x_m"], row["ee_y_m"]])
        if row["in_contact"]:
            contact = True
            break
    travel = t if contact else np.inf
    if contact:
        row = act(float(-d[0] * params.backoff), float(-d[1] * params.backoff))
        n += 1
        here = np.array([row["ee_x_m"], row["ee_y_m"]])
    return here, n, contact, travel


def blocked_positions(sensing: Sensing, target: Primitive, belief: PoseSet, outline: np.ndarray,
             link_radius: float = 0.02) -> np.ndarray:
    """Visited positions (K,) transit must avoid: reached in contact by a probe, or overlapping the target at the
    set's estimate (the gripper passed there before the target was pushed there) unless that leaves the gripper
    nowhere to go (it ended the scripted part pressed against the target)."""
    touching = np.asarray(sensing.touching, dtype=bool)
    near = near_target(target, belief.poses[belief.best], sensing.visited, outline, 0.0)
    near[-1] = False  # where the gripper is now
    if np.isfinite(transit_graph(sensing.visited, link_radius, touching | near)[0]).sum() <= 1:
        return touching
    return touching | near


def return_to_start(act: Act, sensing: Sensing, params, blocked: np.ndarray, attempts: int = 4) -> int:
    """Retrace visited positions (not those reached in contact) from the current one to the scripted part's last
    position not reached in contact; a contact on the way (an object now lies where the gripper once passed)
    backs off and the visited positions within 3 cm of it are left out of the next try. Returns the actions made
    (none if the position cannot be reached)."""
    visited = sensing.visited.copy()
    touching = np.asarray(blocked, dtype=bool).copy()
    here, n = visited[-1], 0
    for _ in range(attempts):
        visited = np.vstack([visited, here])
        touching = np.r_[touching, False]
        dist, pred = transit_graph(visited, params.plan.link_radius, touching)
        free = np.flatnonzero(~touching[:sensing.n_scripted + 1] & np.isfinite(dist[:sensing.n_scripted + 1]))
        if len(free) == 0:
            break
        here, k, contact = retrace(act, here, path_to(pred, visited, int(free[-1])), params.transit_step,
                                   params.backoff)
        n += k
        if not contact:
            break
        touching |= np.linalg.norm(visited - here, axis=1) < 0.03
    return n
