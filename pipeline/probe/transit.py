"""Transit of the probing policy: the graph of the gripper's visited positions it may retrace, and the keep-out
around the target's estimate that transit respects (docs/active.md).

The gripper only moves through space it has occupied before, so transit retraces visited positions: consecutive
ones, or any two closer than ``link_radius`` (the gripper occupied both). But the target has been pushed since
the scripted part passed there, so a visited position, or the straight move between two, may now sweep the
gripper through the target, and a return that touches it after the last decision turns it unseen (docs/active.md,
"The return and the grasp's move"). A :class:`Keepout` drops those positions and links.

Everything is vectorised over (links, samples along a link, outline points); nothing here reads the simulation.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from pipeline.geometry import Primitive, primitive_pose, primitive_sdf, rotate
from pipeline.grasp import GraspParams

__all__ = ["Keepout", "transit_graph", "path_to", "grasp_transit", "grasp_via"]


@dataclass(frozen=True)
class Keepout:
    """The region transit keeps the gripper out of: within ``margin`` (m) of the target at a COM pose (3,).

    Attributes
    ----------
    prim : Primitive
        The target's shape.
    pose : ndarray, shape (3,)
        COM pose (x, y, yaw) of the set's estimate.
    outline : ndarray, shape (G, 2), metres
        The gripper's outline points (robot frame).
    margin : float, metres
        Clearance kept (0: the outline may not enter the primitive).
    links : bool
        Whether the moves between positions are kept out too, not only the positions.
    spacing : float, metres
        Largest gap between the positions checked along a link (0.01, the outline's resolution).
    """

    prim: Primitive
    pose: np.ndarray
    outline: np.ndarray
    margin: float
    links: bool = True
    spacing: float = 0.01

    def clearance(self, positions: np.ndarray) -> np.ndarray:
        """Least distance (K,), metres, from the gripper at each position (K, 2) to the target (negative: inside)."""
        pp = primitive_pose(self.prim, np.asarray(self.pose, dtype=np.float64).reshape(3))
        pts = np.asarray(positions, dtype=np.float64).reshape(-1, 2)[:, None, :] + self.outline[None, :, :]
        sd, _ = primitive_sdf(self.prim, rotate(pts - pp[:2], pp[2], inverse=True))
        return sd.min(axis=1)

    def link_clearance(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Least clearance (E,), metres, of the gripper along the straight moves from a (E, 2) to b (E, 2), ends
        included; inf for links too far from the target to come within ``margin`` (a bound on the target's and
        the outline's radii)."""
        a = np.asarray(a, dtype=np.float64).reshape(-1, 2)
        b = np.asarray(b, dtype=np.float64).reshape(-1, 2)
        out = np.full(len(a), np.inf)
        if len(a) == 0:
            return out
        centre = self.prim.centre_world(np.asarray(self.pose, dtype=np.float64).reshape(1, 3))[0]
        reach = math.hypot(*self.prim.half[:2]) + float(np.max(np.linalg.norm(self.outline, axis=1))) \
            + self.margin
        ab = b - a
        length = np.linalg.norm(ab, axis=1)
        # Distance from the target's centre to each segment a-b: links farther than the reach cannot come close.
        s = np.clip(np.sum((centre - a) * ab, axis=1) / np.maximum(length * length, 1e-18), 0.0, 1.0)
        close = np.flatnonzero(np.linalg.norm(a + s[:, None] * ab - centre, axis=1) <= reach)
        if len(close) == 0:
            return out
        n = int(np.ceil(np.max(length[close]) / self.spacing)) + 1
        f = np.linspace(0.0, 1.0, max(n, 2))
        pts = a[close, None, :] + f[None, :, None] * ab[close, None, :]  # (C, S, 2)
        out[close] = self.clearance(pts.reshape(-1, 2)).reshape(len(close), -1).min(axis=1)
        return out


def transit_graph(visited: np.ndarray, radius: float, touching: np.ndarray | None = None,
                  keepout: Keepout | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Shortest retraced paths from the last visited position: (distance (K,), predecessor (K,)) over the graph
    linking consecutive visited positions and any two closer than ``radius`` (the gripper occupied both).
    Positions flagged in ``touching`` (K,) (reached in contact: pressed against an object) are left out, and so
    are the positions and links that enter the ``keepout``; the current position (the last) is always kept."""
    v = np.asarray(visited, dtype=np.float64).reshape(-1, 2)
    k = len(v)
    i = np.arange(k - 1)
    d = np.linalg.norm(v[:, None, :] - v[None, :, :], axis=-1)
    # Above the first superdiagonal: a consecutive pair is linked once (a link listed twice would be summed by
    # the sparse matrix, counting its length double).
    a, b = np.nonzero(np.triu(d < radius, 2))
    rows = np.concatenate([i, a])
    cols = np.concatenate([i + 1, b])
    t = np.zeros(k, dtype=bool) if touching is None else np.asarray(touching, dtype=bool).copy()
    if keepout is not None:
        clearance = keepout.clearance(v)
        t |= clearance < keepout.margin
    t[-1] = False  # where the gripper is now
    keep = ~t[rows] & ~t[cols]
    rows, cols = rows[keep], cols[keep]
    if keepout is not None and keepout.links:
        # Where the gripper is now may be within the margin (it has just backed off from a contact): a move
        # from there may keep its clearance but not come any closer.
        here = min(float(clearance[-1]), keepout.margin)
        need = np.where((rows == k - 1) | (cols == k - 1), here - 1e-3, keepout.margin)
        keep = keepout.link_clearance(v[rows], v[cols]) >= need
        rows, cols = rows[keep], cols[keep]
    w = np.maximum(d[rows, cols], 1e-9)
    g = coo_matrix((w, (rows, cols)), shape=(k, k)).tocsr()
    dist, pred = dijkstra(g, directed=False, indices=k - 1, return_predecessors=True)
    return dist, pred


def path_to(pred: np.ndarray, visited: np.ndarray, node: int) -> np.ndarray:
    """Visited positions (P, 2) from the last visited one (excluded) to ``node`` (included) along the shortest
    retraced path (``pred`` of :func:`transit_graph`)."""
    out = [node]
    while pred[out[-1]] >= 0:
        out.append(int(pred[out[-1]]))
    return visited[out[::-1]][1:] if len(out) > 1 else visited[[node]]


def grasp_transit(start: np.ndarray, pre: np.ndarray, scale: float, params: GraspParams = GraspParams()
                  ) -> np.ndarray:
    """Where the grasp script's move to its pre-grasp point takes the gripper, predicted open-loop: from
    ``start`` (2,) each move is ``pre - here`` clipped to ``scale`` (m) per axis (a diagonal first, then along one
    axis), until within ``reach_tolerance`` of ``pre`` or after ``max_moves``, as :func:`pipeline.grasp.grasp_with`
    commands it. Returns the positions (M + 1, 2), metres, ``start`` first."""
    here = np.asarray(start, dtype=np.float64).reshape(2).copy()
    pre = np.asarray(pre, dtype=np.float64).reshape(2)
    out = [here.copy()]
    for _ in range(params.max_moves):
        d = pre - here
        if math.hypot(*d) < params.reach_tolerance:
            break
        here = here + np.clip(d / scale, -1.0, 1.0) * scale
        out.append(here.copy())
    return np.array(out)


def _path_length(points: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1)))


def grasp_via(start: np.ndarray, pre: np.ndarray, keepout: Keepout, scale: float,
              radii: tuple[float, ...] = (0.05, 0.10, 0.15, 0.20, 0.25, 0.30, 0.35), directions: int = 16,
              params: GraspParams = GraspParams()) -> np.ndarray:
    """A waypoint for the grasp's move to its pre-grasp point when the straight move from ``start`` (2,) would
    come closer to the target than ``keepout.margin`` (it would push or turn it before the fingers close;
    docs/active.md, "The return and the grasp's move"). Candidates lie around ``pre`` (2,) at each of
    ``radii`` (m) in ``directions`` directions; both moves (:func:`grasp_transit` to the waypoint, then to ``pre``)
    must keep the margin, and the shortest such route wins (ties to the first candidate). A gripper that starts
    closer than the margin (the policy's return can end against the target) only has to move no closer on its first
    action. Returns the waypoints (V, 2), metres: none when the straight move keeps the margin or no candidate does."""
    start = np.asarray(start, dtype=np.float64).reshape(2)
    pre = np.asarray(pre, dtype=np.float64).reshape(2)
    first_need = min(keepout.margin, float(keepout.clearance(start[None, :])[0]))

    def clear(way: np.ndarray, from_start: bool = False) -> bool:
        if len(way) < 2:
            return True
        c = keepout.link_clearance(way[:-1], way[1:])
        if from_start:
            return bool(c[0] >= first_need and np.all(c[1:] >= keepout.margin))
        return bool(np.all(c >= keepout.margin))

    if clear(grasp_transit(start, pre, scale, params), True):
        return np.zeros((0, 2))
    angles = 2 * np.pi * np.arange(directions) / directions
    best, best_len = np.zeros((0, 2)), np.inf
    for r in radii:
        for a in angles:
            w = pre + r * np.array([math.cos(a), math.sin(a)])
            first = grasp_transit(start, w, scale, params)
            second = grasp_transit(first[-1], pre, scale, params)
            length = _path_length(first) + _path_length(second)
            if length < best_len and clear(first, True) and clear(second):
                best, best_len = w[None, :], length
    return best

