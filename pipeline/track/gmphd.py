"""The GM-PHD tracking baseline (paper §V-A): its model, the filter state, and its labeller for the hard tracker.

The model and the target extraction are those of the authors' GM-PHD baseline:

* state = a 2-D point, F = I (static targets), Q = q·I, H = I, R = r·I, survival p_S, no spawning;
* birth intensity = a ``birth_grid`` × ``birth_grid`` grid of N(grid point, birth_variance·I) over ``bounds``,
  total weight ``birth``;
* clutter intensity κ = ``clutter`` / area of ``bounds``;
* pruning after every update (truncate, merge, cap), keeping the pre-prune total weight;
* targets by the integral of the weights: n = round(bias · Σ w), repeatedly take the heaviest component and
  subtract 1 from its weight.

The mixture maths (Vo & Ma 2006) is :mod:`pipeline.track.gaussian_mixture`; :class:`GMPHDFilter` is a thin holder
of the mixture. As tracking baseline the filter sits inside the hard-tracking wrapper of
:mod:`pipeline.track.cluster`: :class:`GMPHDLabeller` feeds each step's new contact points (at their pre-motion
locations) as the measurement set and labels every stored point by its nearest extracted target. As in the
authors' wrapper, the mixture itself is never translated by the pushes: targets are static (F = I) and only the
stored points move.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.spatial import cKDTree

from pipeline.constraints import Constraint, Params, integer, number, rule
from pipeline.track.gaussian_mixture import extract_targets, predict, prune, update

__all__ = [
    "GMPHDParams",
    "GMPHDFilter",
    "GMPHDLabeller",
    "birth_components",
    "nearest_labels",
]


@dataclass(frozen=True)
class GMPHDParams(Params):
    """GM-PHD model and pruning parameters (defaults: the authors', tuned for BOR in simulation).

    Attributes
    ----------
    birth : float
        Total weight of the birth intensity (expected number of new targets per update).
    detection : float
        Detection probability p_D, in (0, 1].
    q, r : float
        Process and measurement noise variances, m² (Q = q·I, R = r·I).
    bias : float
        Target-count bias of the extraction: n = round(bias · Σ w).
    survival : float
        Survival probability p_S, in (0, 1].
    bounds : tuple of 4 floats
        (x_min, y_min, x_max, y_max) of the workspace, metres: birth grid and clutter density.
    birth_grid : int
        Birth components per axis (birth_grid² in all).
    birth_variance : float
        Variance of each birth component, m².
    clutter : float
        Expected number of clutter measurements over ``bounds``; clutter intensity = clutter / area.
    truncation : float
        Components with weight <= truncation are dropped when pruning.
    merge_threshold : float
        Squared Mahalanobis distance (in the candidate's covariance) under which components are merged.
    max_components : int
        At most this many components are kept after pruning.

    The authors' tuning on the training set (paper §V-B) is :meth:`training_set` (q = r = 0.1, bias 1).
    """

    birth: float = 0.001
    detection: float = 0.3
    q: float = 5e-5
    r: float = 5e-5
    bias: float = 4.0
    survival: float = 0.95
    bounds: tuple[float, float, float, float] = (-1.0, -1.0, 1.0, 1.0)
    birth_grid: int = 20
    birth_variance: float = 1e-3
    clutter: float = 3.0
    truncation: float = 1e-6
    merge_threshold: float = 0.005
    max_components: int = 10
    constraints: ClassVar[dict[str, Constraint]] = {
        "birth": number(0, lo_open=True), "detection": number(0, 1, lo_open=True), "q": number(0),
        "r": number(0, lo_open=True), "bias": number(0, lo_open=True), "survival": number(0, 1, lo_open=True),
        "bounds": rule("(x_min, y_min, x_max, y_max) with x_min < x_max and y_min < y_max",
                       lambda b: len(b) == 4 and b[0] < b[2] and b[1] < b[3]),
        # birth_grid: birth_grid² birth components join every update (100 is already 10,000).
        "birth_grid": integer(1, 100, whole=True), "birth_variance": number(0, lo_open=True), "clutter": number(0),
        "truncation": number(0), "merge_threshold": number(0), "max_components": integer(1, whole=True)}

    def __post_init__(self) -> None:
        object.__setattr__(self, "bounds", tuple(float(b) for b in self.bounds))
        super().__post_init__()

    @classmethod
    def training_set(cls) -> GMPHDParams:
        """The authors' tuning on the training set, paper §V-B (birth 0.001, detection 0.3, q = r = 0.1, bias 1)."""
        return cls(q=0.1, r=0.1, bias=1.0)

    @property
    def clutter_intensity(self) -> float:
        """κ, clutter measurements per m²."""
        x0, y0, x1, y1 = self.bounds
        return self.clutter / ((x1 - x0) * (y1 - y0))


def birth_components(params: GMPHDParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Birth intensity: a grid over ``params.bounds``.

    Returns
    -------
    log_w : ndarray, shape (B,)   each log(birth / B), B = birth_grid²
    means : ndarray, shape (B, 2), metres
    covs : ndarray, shape (B, 2, 2), m²
    """
    x0, y0, x1, y1 = params.bounds
    n = int(params.birth_grid)
    gx, gy = np.meshgrid(np.linspace(x0, x1, n), np.linspace(y0, y1, n), indexing="xy")
    means = np.column_stack([gx.ravel(), gy.ravel()])
    b = len(means)
    log_w = np.full(b, math.log(params.birth / b))
    covs = np.broadcast_to(params.birth_variance * np.eye(2), (b, 2, 2)).copy()
    return log_w, means, covs


def nearest_labels(points: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Label of each point = index of its nearest target. points (M, D), targets (T, D), T >= 1 -> (M,) int64."""
    if len(points) == 0:
        return np.empty(0, dtype=np.int64)
    _, idx = cKDTree(targets).query(points, k=1)
    return np.asarray(idx, dtype=np.int64)


# ---------------------------------------------------------------------------------------------------------------
# thin state
# ---------------------------------------------------------------------------------------------------------------
class GMPHDFilter:
    """Holds the Gaussian mixture and applies predict + birth, update and prune per measurement set.

    Attributes
    ----------
    log_weights_ : ndarray, shape (J,)
    means_ : ndarray, shape (J, 2), metres
    covariances_ : ndarray, shape (J, 2, 2), m²
    """

    def __init__(self, params: GMPHDParams | None = None) -> None:
        self.params = params if params is not None else GMPHDParams()
        self._birth = birth_components(self.params)
        self.log_weights_ = np.empty(0)
        self.means_ = np.empty((0, 2))
        self.covariances_ = np.empty((0, 2, 2))

    def step(self, z: np.ndarray) -> None:
        """One filter cycle with measurement set z, shape (K, 2), metres."""
        prm = self.params
        z = np.asarray(z, dtype=float).reshape(-1, 2)
        lw, m, p = predict(self.log_weights_, self.means_, self.covariances_, prm.survival, prm.q)
        blw, bm, bp = self._birth
        lw, m, p = np.concatenate([lw, blw]), np.concatenate([m, bm]), np.concatenate([p, bp])
        lw, m, p = update(lw, m, p, z, prm.detection, prm.r, prm.clutter_intensity)
        self.log_weights_, self.means_, self.covariances_ = prune(
            lw, m, p, prm.truncation, prm.merge_threshold, prm.max_components)

    def targets(self) -> np.ndarray:
        """ndarray, shape (T, 2): extracted target positions (T >= 1 once the mixture is non-empty)."""
        return self.means_[extract_targets(self.log_weights_, self.params.bias)]


class GMPHDLabeller:
    """Point labeller for :class:`pipeline.track.cluster.HardTrackingWrapper` backed by a GM-PHD filter.

    At each contact step the new points (last ``n_new`` rows, at their pre-motion locations) are the measurement
    set; every stored point is then labelled by its nearest extracted target.
    """

    def __init__(self, params: GMPHDParams | None = None) -> None:
        self.params = params if params is not None else GMPHDParams()
        self.filter_ = GMPHDFilter(self.params)

    def fit_labels(self, points: np.ndarray, n_new: int) -> np.ndarray:
        """points (M, 2) with the n_new newest last -> labels (M,) int64 (never -1)."""
        if points.shape[1] != 2:
            raise ValueError(f"GM-PHD baseline is planar: points must have 2 columns, got {points.shape[1]}")
        self.filter_.step(points[len(points) - n_new:])
        return self.final_labels(points)

    def final_labels(self, points: np.ndarray) -> np.ndarray:
        """points (M, 2) -> labels (M,) int64 by nearest extracted target of the current mixture."""
        if len(points) == 0 or len(self.filter_.log_weights_) == 0:
            return np.zeros(len(points), dtype=np.int64)
        return nearest_labels(points, self.filter_.targets())
