"""The plane as a grid of square cells, and the shortest path over its free cells (the planned grasp's way in:
:mod:`pipeline.probe.grasp_plan`). Arrays: cells (C,), points (N, 2) metres."""
from __future__ import annotations

import math

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

__all__ = ["PlaneGrid", "simplify_path"]


class PlaneGrid:
    """The plane around the gripper and the set as cells of side ``cell``; which the gripper may occupy."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, cell: float) -> None:
        self.cell = cell
        self.lo = np.floor(lo / cell) * cell
        self.shape = tuple(int(v) for v in np.ceil((hi - self.lo) / cell).astype(int) + 1)
        ix, iy = np.meshgrid(np.arange(self.shape[0]), np.arange(self.shape[1]), indexing="ij")
        self.centres = self.lo + cell * np.column_stack([ix.ravel(), iy.ravel()])

    def index(self, points: np.ndarray) -> np.ndarray:
        """Cell (N,) of each point (N, 2), clipped to the grid."""
        ij = np.rint((np.asarray(points).reshape(-1, 2) - self.lo) / self.cell).astype(int)
        ij = np.clip(ij, 0, np.array(self.shape) - 1)
        return ij[:, 0] * self.shape[1] + ij[:, 1]

    def graph(self, free: np.ndarray, weight: np.ndarray, source: int):
        """Dijkstra from ``source`` over 8-connected free cells (the source itself always usable); edge cost =
        length x the mean ``weight`` of its two cells. Returns (cost (C,), predecessor (C,))."""
        nx, ny = self.shape
        usable = free.copy()
        usable[source] = True
        ids = np.arange(nx * ny).reshape(nx, ny)
        rows, cols, costs = [], [], []
        for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
            a = ids[max(0, -dx):nx - max(0, dx), max(0, -dy):ny - max(0, dy)].ravel()
            b = ids[max(0, dx):nx - max(0, -dx) or None, max(0, dy):ny - max(0, -dy) or None].ravel()
            ok = usable[a] & usable[b]
            length = self.cell * math.hypot(dx, dy)
            rows.append(a[ok])
            cols.append(b[ok])
            costs.append(length * 0.5 * (weight[a[ok]] + weight[b[ok]]))
        r, c, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(costs)
        g = coo_matrix((np.r_[w, w], (np.r_[r, c], np.r_[c, r])), shape=(nx * ny, nx * ny)).tocsr()
        return dijkstra(g, indices=source, return_predecessors=True)


def simplify_path(path: np.ndarray, free_at, weight_at=None, slack: float = 0.02) -> np.ndarray:
    """Waypoints (W, 2) of a grid path (P, 2): the farthest point in sight of each, greedily.

    ``free_at(points (N, 2))`` says which points the gripper may occupy. With ``weight_at`` (the path cost per
    metre at each point, as :meth:`PlaneGrid.graph` weighs cells), a shortcut is taken only if it costs at most
    the grid path it replaces plus ``slack`` (metres of visited space): the gripper follows the way the search
    priced, and a straight line between two points of a path that went round a sensed object does not cut
    through it."""
    step = 0.005
    if weight_at is not None:
        seg = np.hypot(*np.diff(path, axis=0).T)
        mid = 0.5 * (path[1:] + path[:-1])
        along = np.r_[0.0, np.cumsum(seg * weight_at(mid))]  # the grid path's cost from its start to each point
    out, i = [], 0
    while i < len(path) - 1:
        j = len(path) - 1
        while j > i + 1:
            length = math.hypot(*(path[j] - path[i]))
            n = max(2, int(np.ceil(length / step)))
            line = path[i] + np.linspace(0.0, 1.0, n)[:, None] * (path[j] - path[i])
            if np.all(free_at(line)) and (
                    weight_at is None
                    or length * float(np.mean(weight_at(0.5 * (line[1:] + line[:-1])))) <= along[j] - along[i] + slack):
                break
            j -= 1
        out.append(path[j])
        i = j
    return np.array(out or [path[-1]]).reshape(-1, 2)  # at least the goal: a path of one cell still moves there
