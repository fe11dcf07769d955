"""Hard-tracking baselines: one estimate of every contact point, clustered at each contact step (paper §V-A).

As in the authors' baseline wrapper: at a contact step each new point enters at its pre-motion location (p - dx),
all points are (re)clustered, and every point in a cluster that contains a new point is translated by the mean dx
of the new points in that cluster. Noise labels (-1, DBSCAN) are never moved, and become singleton objects in
:meth:`HardTrackingWrapper.labels`. Free-space steps change nothing.

The clustering is a small *labeller* object (:class:`PointLabeller`), so the same wrapper serves BIRCH, DBSCAN,
the growing k-means and the GM-PHD filter of :mod:`pipeline.track.gmphd`. Build a tracker by name with
:func:`pipeline.track.stage.build_tracker` (the names and factories are in :mod:`pipeline.registry`).
"""
from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import numpy as np
from sklearn.cluster import DBSCAN, Birch, KMeans
from sklearn.exceptions import ConvergenceWarning

from pipeline.constraints import Constraint, Params, integer, number
from pipeline.labels import canonical_labels
from pipeline.track.base import StepResult
from pipeline.track.gmphd import GMPHDLabeller, GMPHDParams

__all__ = [
    "BirchParams",
    "DBSCANParams",
    "KMeansParams",
    "GMPHDParams",
    "PointLabeller",
    "RefitLabeller",
    "GrowingKMeansLabeller",
    "HardTrackingWrapper",
    "compact_labels",
    "birch_tracker",
    "dbscan_tracker",
    "kmeans_tracker",
    "gmphd_tracker",
]


# ---------------------------------------------------------------------------------------------------------------
# parameters
# ---------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BirchParams(Params):
    """``sklearn.cluster.Birch(threshold, branching_factor, n_clusters=None)``; threshold in metres (tuned 0.08)."""

    threshold: float = 0.08
    branching_factor: int = 50
    constraints: ClassVar[dict[str, Constraint]] = {"threshold": number(0, lo_open=True),
                                                    "branching_factor": integer(2, whole=True)}


@dataclass(frozen=True)
class DBSCANParams(Params):
    """``sklearn.cluster.DBSCAN(eps, min_samples)``; eps in metres (tuned 0.05; 0.1 on the real robot)."""

    eps: float = 0.05
    min_samples: int = 1
    constraints: ClassVar[dict[str, Constraint]] = {"eps": number(0, lo_open=True),
                                                    "min_samples": integer(1, whole=True)}


@dataclass(frozen=True)
class KMeansParams(Params):
    """k-means starting at k = 1 and growing k by one when inertia(k+1) < inertia_ratio · inertia(k).

    Attributes
    ----------
    inertia_ratio : float
        Growth needs this relative inertia drop (0.2 = a 5x improvement; 0.1 on the real robot).
    min_points_to_grow : int
        k grows only once at least this many points are stored (the authors' ``delay_new_clusters_until``).
    n_init : int
        k-means restarts per fit (set explicitly: sklearn's default changed across versions).
    min_inertia : float
        m²; k does not grow while inertia(k) <= min_inertia. Pushing the same spot repeatedly piles stored
        points onto each other, so inertia(k) can be pure round-off (~1e-33 m² on the anchor streams) and a 5x
        "drop" of round-off is no evidence of a new object. Not in the authors' code; 0 restores their rule.
    """

    inertia_ratio: float = 0.2
    min_points_to_grow: int = 5
    n_init: int = 10
    min_inertia: float = 1e-10
    constraints: ClassVar[dict[str, Constraint]] = {
        "inertia_ratio": number(0, 1, lo_open=True), "min_points_to_grow": integer(2, whole=True),
        # n_init: k-means restarts per fit and per step; beyond 1000 a run never ends.
        "n_init": integer(1, 1000, whole=True), "min_inertia": number(0)}


# ---------------------------------------------------------------------------------------------------------------
# labellers
# ---------------------------------------------------------------------------------------------------------------
class PointLabeller(Protocol):
    """What :class:`HardTrackingWrapper` asks of a clustering method."""

    def fit_labels(self, points: np.ndarray, n_new: int) -> np.ndarray:
        """Cluster at a contact step. points (M, D), the n_new newest last -> labels (M,) int, -1 = noise."""

    def final_labels(self, points: np.ndarray) -> np.ndarray:
        """Labels reported for the current points (M, D) -> (M,) int, -1 = noise."""


class RefitLabeller:
    """Refit an sklearn clusterer on all points at every call (BIRCH, DBSCAN: ``fit_predict`` both times)."""

    def __init__(self, factory: Callable[[], Any]) -> None:
        self.factory = factory

    def fit_labels(self, points: np.ndarray, n_new: int) -> np.ndarray:
        return np.asarray(self.factory().fit_predict(points), dtype=np.int64)

    def final_labels(self, points: np.ndarray) -> np.ndarray:
        if len(points) == 0:
            return np.empty(0, dtype=np.int64)
        return np.asarray(self.factory().fit_predict(points), dtype=np.int64)


class GrowingKMeansLabeller:
    """k-means whose k starts at 1 and only grows (the authors' ``OnlineSklearnFixedClusters``, paper §V-A).

    Attributes
    ----------
    n_clusters_ : int
        Current k.
    model_ : sklearn.cluster.KMeans or None
        Last accepted fit; :meth:`final_labels` is its ``predict`` on the current (moved) points.
    """

    def __init__(self, params: KMeansParams, random_state: int) -> None:
        self.params = params
        self.random_state = int(random_state)
        self.n_clusters_ = 1
        self.model_: KMeans | None = None

    def _fit(self, points: np.ndarray, k: int) -> KMeans:
        with warnings.catch_warnings():
            # Coincident points can leave fewer distinct points than k once points have moved together.
            warnings.simplefilter("ignore", ConvergenceWarning)
            return KMeans(n_clusters=k, n_init=self.params.n_init, random_state=self.random_state).fit(points)

    def fit_labels(self, points: np.ndarray, n_new: int) -> np.ndarray:
        k = self.n_clusters_
        model = self._fit(points, k)
        if (len(points) >= self.params.min_points_to_grow and model.inertia_ > self.params.min_inertia
                and k + 1 <= len(np.unique(points, axis=0))):
            bigger = self._fit(points, k + 1)
            if bigger.inertia_ < self.params.inertia_ratio * model.inertia_:
                model, self.n_clusters_ = bigger, k + 1
        self.model_ = model
        return np.asarray(model.labels_, dtype=np.int64)

    def final_labels(self, points: np.ndarray) -> np.ndarray:
        if len(points) == 0 or self.model_ is None:
            return np.zeros(len(points), dtype=np.int64)
        return np.asarray(self.model_.predict(points), dtype=np.int64)


# ---------------------------------------------------------------------------------------------------------------
# the wrapper
# ---------------------------------------------------------------------------------------------------------------
def compact_labels(labels: np.ndarray) -> np.ndarray:
    """Noise (-1) to singletons, then relabel 0..k-1 in order of first appearance. (M,) int -> (M,) int64."""
    labels = np.asarray(labels, dtype=np.int64).copy()
    noise = labels == -1
    if noise.any():
        top = labels.max(initial=-1)
        labels[noise] = top + 1 + np.arange(noise.sum())
    return canonical_labels(labels)


#: The step result of a tracker without particles.
_NO_PARTICLES = StepResult()


class HardTrackingWrapper:
    """Contact tracker that keeps one estimate per contact point and moves whole clusters (paper §V-A).

    Implements :class:`pipeline.track.base.ContactTracker`.

    Parameters
    ----------
    labeller : PointLabeller
        The clustering method; stateful labellers (k-means, GM-PHD) belong to this tracker alone.
    params : dataclass instance or None
        The method's full parameter set, kept only to be recorded in output metadata
        (``tracker.params.to_dict()``).

    Attributes
    ----------
    labeller : PointLabeller
    params : dataclass instance or None
    """

    def __init__(self, labeller: PointLabeller, params: Any = None) -> None:
        self.labeller = labeller
        self.params = params
        self._points: np.ndarray | None = None
        self._dim: int | None = None

    def update(self, x: np.ndarray, dx: np.ndarray | None, p: np.ndarray | None) -> StepResult:
        """Advance by one control step (see :meth:`pipeline.track.base.ContactTracker.update`).

        x (D,), dx (K, D) | None, p (K, D) | None, metres. K = 0 is treated as free space. Returns the
        defaults of :class:`~pipeline.track.base.StepResult` (no particles: ESS 1, nothing resampled).
        """
        x = np.asarray(x, dtype=float)
        if x.ndim != 1:
            raise ValueError(f"x must have shape (D,), got {x.shape}")
        if self._dim is None:
            self._dim = x.shape[0]
        elif x.shape[0] != self._dim:
            raise ValueError(f"x has dimension {x.shape[0]}, earlier steps had {self._dim}")
        if dx is None and p is None:
            return _NO_PARTICLES
        if dx is None or p is None:
            raise ValueError("dx and p must both be None (free space) or both be arrays of shape (K, D)")
        dx = np.asarray(dx, dtype=float)
        p = np.asarray(p, dtype=float)
        if dx.ndim != 2 or dx.shape != p.shape or dx.shape[1] != self._dim:
            raise ValueError(f"dx and p must both have shape (K, {self._dim}), got {dx.shape} and {p.shape}")
        if len(p) == 0:
            return _NO_PARTICLES
        if not (np.isfinite(dx).all() and np.isfinite(p).all()):
            raise ValueError("dx and p must be finite")

        k = len(p)
        new = p - dx
        points = new.copy() if self._points is None else np.concatenate([self._points, new])
        labels = np.asarray(self.labeller.fit_labels(points, k), dtype=np.int64)
        new_labels = labels[-k:]
        for lab in np.unique(new_labels):
            if lab == -1:
                continue
            points[labels == lab] += dx[new_labels == lab].mean(axis=0)
        self._points = points
        return _NO_PARTICLES

    @property
    def points_(self) -> np.ndarray:
        """ndarray, shape (M, D): current estimate of every contact point, in observation order (a copy)."""
        if self._points is None:
            return np.empty((0, self._dim if self._dim is not None else 2))
        return self._points.copy()

    def labels(self) -> np.ndarray:
        """ndarray, shape (M,), int64: object of each point, 0..n_objects-1 in order of first appearance."""
        if self._points is None:
            return np.empty(0, dtype=np.int64)
        return compact_labels(self.labeller.final_labels(self._points))


# ---------------------------------------------------------------------------------------------------------------
# factory
# ---------------------------------------------------------------------------------------------------------------
# The registry's factories (:mod:`pipeline.registry`): ``factory(params, robot, rng)``; the robot is not used.
def birch_tracker(params: BirchParams, robot, rng: np.random.Generator) -> HardTrackingWrapper:
    """BIRCH refitted at every contact step (deterministic: draws nothing)."""
    return HardTrackingWrapper(RefitLabeller(
        lambda: Birch(threshold=params.threshold, branching_factor=params.branching_factor, n_clusters=None)),
        params=params)


def dbscan_tracker(params: DBSCANParams, robot, rng: np.random.Generator) -> HardTrackingWrapper:
    """DBSCAN refitted at every contact step (deterministic: draws nothing)."""
    return HardTrackingWrapper(RefitLabeller(lambda: DBSCAN(eps=params.eps, min_samples=params.min_samples)),
                               params=params)


def kmeans_tracker(params: KMeansParams, robot, rng: np.random.Generator) -> HardTrackingWrapper:
    """The growing k-means; its ``random_state`` is one integer drawn from ``rng`` here."""
    return HardTrackingWrapper(GrowingKMeansLabeller(params, random_state=int(rng.integers(0, 2**31 - 1))),
                               params=params)


def gmphd_tracker(params: GMPHDParams, robot, rng: np.random.Generator) -> HardTrackingWrapper:
    """The GM-PHD filter as a labeller (:mod:`pipeline.track.gmphd`; deterministic: draws nothing)."""
    return HardTrackingWrapper(GMPHDLabeller(params), params=params)
