"""Alg. 3's connection graph: tracked points whose connection probability exp(-d^2 / l) exceeds alpha belong to one
object (the paper's Algorithm 3), and the defaults of l and alpha (Table I).

Two points are connected when exp(-d^2 / l) > alpha, i.e. when d^2 < l * ln(1 / alpha); objects are the connected
components of that graph (a true connected-components search, unlike the authors' one-pass grouping). The test
is done on squared distances, so tiny ``l`` or ``alpha`` never underflow an exponential. Both STUCCO's tracker
(:mod:`pipeline.track.soft`, its labels) and the segment stage (:mod:`pipeline.segment`) use it.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from pipeline.labels import canonical_labels

__all__ = ["DEFAULT_LENGTH", "DEFAULT_ALPHA", "connection_radius", "segment_points"]

#: Characteristic length l (m^2) of the connection probability exp(-d^2 / l), the paper's Table I (simulation).
#: One fact for both users: STUCCO's tracker connects points with it (Alg. 1) and segmentation thresholds the same
#: probability (Alg. 3), so :class:`pipeline.track.soft.SoftTrackingParams` takes its default from here.
DEFAULT_LENGTH = 0.02
#: Connection threshold alpha of segmentation (Alg. 3), the paper's Table I.
DEFAULT_ALPHA = 0.4


def connection_radius(length: float, alpha: float) -> float:
    """Distance below which two points are connected: sqrt(l ln(1/alpha)) (metres); 0 if alpha >= 1, inf if <= 0."""
    if alpha >= 1.0:
        return 0.0
    if alpha <= 0.0:
        return np.inf
    return math.sqrt(length * math.log(1.0 / alpha))


def segment_points(points: np.ndarray, length: float, alpha: float) -> np.ndarray:
    """Connected components of the graph exp(-d^2/l) > alpha over the points (Alg. 3).

    Parameters
    ----------
    points : ndarray, shape (M, D)
        Tracked contact points (metres).
    length : float
        Characteristic length l (m^2, as in exp(-d^2/l)).
    alpha : float
        Connection probability threshold.

    Returns
    -------
    labels : ndarray, shape (M,), int64
        Object index of each point, numbered 0..k-1 in order of first appearance.
    """
    points = np.asarray(points, dtype=np.float64)
    m = len(points)
    if m == 0:
        return np.zeros(0, dtype=np.int64)
    radius = connection_radius(length, alpha)
    if radius == np.inf:
        return np.zeros(m, dtype=np.int64)
    if radius == 0.0:
        return np.arange(m, dtype=np.int64)
    pairs = cKDTree(points).query_pairs(r=radius, output_type="ndarray")
    if len(pairs):
        d2 = np.sum((points[pairs[:, 0]] - points[pairs[:, 1]]) ** 2, axis=1)
        pairs = pairs[d2 < radius * radius]  # the paper's test is strict
    graph = coo_matrix((np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(m, m))
    _, labels = connected_components(graph, directed=False)
    return canonical_labels(labels)
