"""STUCCO soft tracking (paper §IV-B, Algorithm 1 with Algorithm 2), as a particle filter on whole arrays.

Each particle holds every contact point seen so far and the end-effector configuration it was observed at:
``points`` and ``configs`` of shape (N particles, M points, D). One control step does, on all particles at once:

1. *In contact* (K >= 1 contact points p_k with in-contact displacements dx_k): the new points enter at their
   pre-motion location (p_k - dx_k, config x - dx_k); every existing point is connected to its nearest new point
   with probability exp(-d^2 / l) (sampled independently per particle and point); connected points and their
   configs translate by that new point's dx (pxdyn, Eq. 2); the new points always move.
2. *Weighting*: epsilon_n = summed penetration of every point into every config of the particle (contact) or
   into the current config only (free space), each term min(0, sdf + tolerance); the log-likelihood is
   -epsilon^2 / l_p (``weighting="paper"``) or -(epsilon - max_n epsilon)^2 / l_p (``weighting="reference"``,
   the authors' code, which measures each particle against the least penetrating one).
3. *Resampling* (systematic) when the effective sample size drops below ``ess_threshold`` * N, followed by
   ReplaceInconsistentPoints (Alg. 2).

Only what changed is recomputed: penetration is kept per point (see :mod:`pipeline.track.kernels`), so a contact
step evaluates only pairs whose relative position changed and the new points' pairs, and a free-space step only
the current configuration against the points.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from pipeline.components import DEFAULT_ALPHA, DEFAULT_LENGTH, segment_points
from pipeline.constraints import Constraint, Params, integer, number, one_of
from pipeline.track import kernels, replacement, weights
from pipeline.track.base import StepResult
from pipeline.track.ordering import take_rows

WEIGHTINGS = ("reference", "paper")
REPLACE_MODES = ("after-resample", "every-step", "never")


#: Most particles a tracker holds: it keeps (particles, points, 2) float64 arrays, so 1e5 particles over 1,000
#: tracked points is already 1.6 GB of the machine's memory.
MAX_PARTICLES = 100_000


@dataclass(frozen=True)
class SoftTrackingParams(Params):
    """Parameters of STUCCO soft tracking; defaults are the paper's Table I (simulation) and the authors' code.

    Attributes
    ----------
    length : float
        Characteristic length l (m^2): connection probability exp(-d^2 / l). Table I: 0.02.
    penetration_length : float
        Penetration length l_p (m^2): observation likelihood exp(-epsilon^2 / l_p). Table I: 0.002.
    alpha : float
        Connection threshold for segmentation (Alg. 3). Table I: 0.4.
    n_particles : int
        N. Table I: 100.
    tolerance : float
        Penetration shallower than this is ignored (metres); the authors' sim value 0.002.
    ess_threshold : float
        Resample when ESS / N falls below this (the authors' code: 0.8).
    weighting : str
        "reference" (the authors' code: epsilon relative to the best particle) or "paper" (raw epsilon).
    replace : str
        When to run ReplaceInconsistentPoints: "after-resample" (the authors' code), "every-step" (Alg. 1 as
        printed) or "never".
    weight_floor : float
        Normalised weights are floored at this value before renormalising (the authors' code: 1e-15), so a
        particle that was unlucky once can recover; 0 disables the floor.
    """

    length: float = DEFAULT_LENGTH
    penetration_length: float = 0.002
    alpha: float = DEFAULT_ALPHA
    n_particles: int = 100
    tolerance: float = 0.002
    ess_threshold: float = 0.8
    weighting: str = "reference"
    replace: str = "after-resample"
    weight_floor: float = 1e-15
    constraints: ClassVar[dict[str, Constraint]] = {
        "length": number(0, lo_open=True), "penetration_length": number(0, lo_open=True),
        "alpha": number(0, 1, lo_open=True, hi_open=True),  # exp(-d^2/l) > alpha: 0 and 1 are degenerate (Alg. 3)
        # MAX_PARTICLES: (particles, points) arrays of a long run stay within the machine's memory.
        "n_particles": integer(1, MAX_PARTICLES), "tolerance": number(0), "ess_threshold": number(0, 1),
        "weight_floor": number(0, hi_of=lambda p: 1.0 / p.n_particles, hi_open=True, text="in [0, 1/N)"),
        "weighting": one_of(*WEIGHTINGS), "replace": one_of(*REPLACE_MODES)}


class SoftTracker:
    """STUCCO particle filter over contact points and their configurations.

    Parameters
    ----------
    robot : GridSDF
        The robot's signed distance grid (pxpen); see :mod:`pipeline.robot`.
    params : SoftTrackingParams
    rng : numpy.random.Generator
        Source of every random draw (adjacency sampling and resampling).

    Attributes (after updates)
    --------------------------
    points_ : ndarray, shape (M, D)
        Contact points of the MAP particle.
    log_weights_ : ndarray, shape (N,)
        Normalised log-weights.
    n_points_ : int
    last_step_ : StepResult or None
    """

    def __init__(self, robot, params: SoftTrackingParams | None = None, *, rng: np.random.Generator) -> None:
        if not isinstance(rng, np.random.Generator):
            raise TypeError("rng must be a numpy.random.Generator")
        self.robot = robot
        self.params = params if params is not None else SoftTrackingParams()
        self.rng = rng
        values, shape, strides, origin, resolution = robot.kernel_arrays()
        self._grid = (values, np.asarray(shape, np.int64), np.asarray(strides, np.int64),
                      np.asarray(origin, np.float64), 1.0 / float(resolution))
        self.dim = len(shape)
        lo, hi = robot.interior_bounds(-self.params.tolerance)
        # One cell of margin: a query within half a cell of an interior cell centre looks that cell up.
        self._lo = np.asarray(lo, np.float64) - resolution
        self._hi = np.asarray(hi, np.float64) + resolution
        n = self.params.n_particles
        self._capacity = 0
        self._m = 0
        self._P = np.zeros((n, 0, self.dim))
        self._C = np.zeros((n, 0, self.dim))
        self._colpen = np.zeros((n, 0))
        self._npen = np.zeros((n, 0), np.int32)
        self._order = np.zeros((n, 0), np.int32)  # points by first coordinate, per particle (kernels)
        self._all_rows = np.arange(n, dtype=np.int64)
        self._uniform_log_weights = np.full(n, -math.log(n))  # after resampling (copied)
        floor = float(self.params.weight_floor)
        # weights.reweight's arguments that the (frozen) parameters fix
        self._weighting = (self.params.weighting == "reference", float(self.params.penetration_length), floor,
                           math.log(floor) if floor > 0 else 0.0)
        self.log_weights_ = self._uniform_log_weights.copy()
        self._map_points = np.zeros((0, self.dim))
        self.last_step_: StepResult | None = None

    # ------------------------------------------------------------------ public state
    @property
    def n_points_(self) -> int:
        return self._m

    @property
    def points_(self) -> np.ndarray:
        """ndarray, shape (M, D): points of the MAP particle of the last update, taken before resampling (copy)."""
        return self._map_points.copy()

    @property
    def particle_points_(self) -> np.ndarray:
        """ndarray, shape (N, M, D): points of every particle (view; do not modify)."""
        return self._P[:, : self._m]

    @property
    def particle_configs_(self) -> np.ndarray:
        return self._C[:, : self._m]

    def penetration_(self) -> np.ndarray:
        """ndarray, shape (N,): summed penetration epsilon_n of each particle's points into its configs (<= 0)."""
        return self._colpen[:, : self._m].sum(axis=1)

    def labels(self) -> np.ndarray:
        """Alg. 3 on the MAP particle: object index of each point, shape (M,)."""
        return segment_points(self.points_, self.params.length, self.params.alpha)

    def warm_up_without_contacts(self, n_points: int = 8) -> None:
        """Compile (or load from numba's cache) every kernel of an update but the contact step's, on made-up
        points: the free-space step, the reweighting, systematic resampling, Alg. 2 and the row copies.

        ``make setup`` runs it in a second process while the first compiles the contact step's kernel (the
        slowest to compile by far), so the two halves compile side by side and the first process loads this half
        from the cache. The same calls as a real update makes, so the same specialisations. Leaves made-up
        points behind: for a throwaway tracker only."""
        n = self.params.n_particles
        self._ensure_capacity(n_points)
        self._m = n_points
        points = self.rng.uniform(-0.1, 0.1, (n, n_points, self.dim))
        self._P[:, :n_points] = points
        self._C[:, :n_points] = points
        self._order[:, :n_points] = np.argsort(points[:, :, 0], axis=1, kind="stable")
        self.update(np.zeros(self.dim))  # free space with points: the penetration kernel and the reweighting
        # One particle far ahead of the rest: the ESS falls below any threshold, so the step resamples and
        # (replace="after-resample") runs Alg. 2 on the distinct ancestors.
        self._reweight_and_resample(np.r_[0.0, np.full(n - 1, -1.0)])

    # ------------------------------------------------------------------ the filter
    def update(self, x, dx=None, p=None) -> StepResult:
        """One control step; see the module docstring.

        Parameters
        ----------
        x : array_like, shape (D,)
            End-effector position after the step (metres).
        dx : array_like, shape (K, D) or (D,), or None
            In-contact displacement for each of the K contacts of the step; None in free space.
        p : array_like, shape (K, D) or (D,), or None
            Contact points at the end of the step; None in free space.
        """
        # Fresh writable copies: numba compiles one specialisation per array flag, so read-only input (zero-copy
        # from Parquet) and writable input would each pay a compilation of the parallel kernels.
        x = np.array(x, dtype=np.float64).reshape(self.dim)
        if not np.isfinite(x).all():
            raise ValueError(f"x must be finite, got {x}")
        if (dx is None) != (p is None):
            raise ValueError("dx and p must both be given (contact) or both be None (free space)")
        if dx is not None:
            dx = np.array(dx, dtype=np.float64).reshape(-1, self.dim)
            p = np.array(p, dtype=np.float64).reshape(-1, self.dim)
            if dx.shape != p.shape:
                raise ValueError(f"dx {dx.shape} and p {p.shape} must have the same shape (K, {self.dim})")
            if not (np.isfinite(dx).all() and np.isfinite(p).all()):
                raise ValueError("dx and p must be finite")
        if dx is None or len(dx) == 0:
            if self._m == 0:
                self.last_step_ = StepResult(ess=1.0, resampled=False, n_replaced=0)
                return self.last_step_
            eps = kernels.free_space_penetration(self._P, self._m, x, *self._grid, self._lo, self._hi,
                                                 self.params.tolerance)
        else:
            eps = self._predict(x, dx, p)
        return self._reweight_and_resample(eps)

    def _ensure_capacity(self, m_needed: int) -> None:
        if m_needed <= self._capacity:
            return
        cap = max(16, 2 * self._capacity, m_needed)
        n = self.params.n_particles

        def grow(a, fill_dtype):
            out = np.zeros((n, cap) + a.shape[2:], dtype=fill_dtype)
            out[:, : self._m] = a[:, : self._m]
            return out

        self._P = grow(self._P, np.float64)
        self._C = grow(self._C, np.float64)
        self._colpen = grow(self._colpen, np.float64)
        self._npen = grow(self._npen, np.int32)
        self._order = grow(self._order, np.int32)
        self._capacity = cap

    def _predict(self, x: np.ndarray, dx: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Append the K new points (moved by their own dx) and move connected old points (pxdyn); returns each
        particle's summed penetration after the step (N,), as :meth:`penetration_` gives it."""
        m_old = self._m
        self._ensure_capacity(m_old + len(dx))
        u = self.rng.random((self.params.n_particles, m_old))
        eps = kernels.predict_and_update(self._P, self._C, self._order, u, p - dx, dx, x, p, m_old,
                                         self.params.length, self._colpen, self._npen, *self._grid, self._lo,
                                         self._hi, self.params.tolerance)
        self._m = m_old + len(dx)
        return eps

    def _snapshot_map(self, index: int) -> None:
        # The estimate is the MAP particle as weighted now, before resampling and replacement (as the authors'
        # code takes it): replacement can only move its points onto other points, and reading it afterwards was
        # never more accurate (README.md, STUCCO soft tracking).
        self._map_points = self._P[index, : self._m].copy()

    def _reweight_and_resample(self, eps: np.ndarray) -> StepResult:
        prm = self.params
        # Every particle explains the step equally well (typically free space with no point near the robot): the
        # normalised weights and the ESS are unchanged, and the ESS was at or above the threshold after the
        # previous step, so there is nothing to resample or replace (``skipped``). The estimate is still
        # refreshed: a contact step has moved and added points.
        may_skip = prm.replace != "every-step" and self.last_step_ is not None
        skipped, log_w, ess, map_index = weights.reweight(self.log_weights_, eps, may_skip, *self._weighting)
        self._snapshot_map(int(map_index))
        if skipped:
            self.last_step_ = StepResult(ess=self.last_step_.ess if not self.last_step_.resampled else 1.0,
                                         resampled=False, n_replaced=0)
            return self.last_step_
        ess = float(ess)
        resampled = ess < prm.ess_threshold
        n_replaced = 0
        replace = self._m > 0 and (prm.replace == "every-step" or (resampled and prm.replace == "after-resample"))
        arrays = (self._P, self._C, self._colpen, self._npen, self._order)
        if resampled:
            ancestors, distinct = weights.systematic_ancestors(log_w, self.rng.random())
            if replace:
                # Right after resampling, copies of one ancestor are identical, and Alg. 2 is deterministic: run it
                # once per distinct ancestor (in place, before the copies are made), then hand out the copies.
                n_rep = replacement.replace_inconsistent(self._P, self._C, self._order, distinct, self._m,
                                                         self._colpen, self._npen, *self._grid, self._lo, self._hi,
                                                         prm.tolerance)
                n_replaced = int(n_rep[ancestors].sum())
            take_rows(ancestors, self._m, *arrays)
            log_w = self._uniform_log_weights.copy()
        elif replace:
            n_replaced = int(replacement.replace_inconsistent(self._P, self._C, self._order, self._all_rows,
                                                              self._m, self._colpen, self._npen, *self._grid,
                                                              self._lo, self._hi, prm.tolerance).sum())
        self.log_weights_ = log_w
        self.last_step_ = StepResult(ess=ess, resampled=bool(resampled), n_replaced=n_replaced)
        return self.last_step_


def soft_tracker(params: SoftTrackingParams, robot, rng: np.random.Generator) -> SoftTracker:
    """The registry's factory of ``stucco`` (:mod:`pipeline.registry`): a fresh :class:`SoftTracker`."""
    return SoftTracker(robot, params, rng=rng)
