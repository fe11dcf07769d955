"""The interface every contact tracker implements, so that `stucco track --method ...` treats all alike.

A tracker is fed one control step at a time, in order::

    tracker.update(x, dx, p)     # in contact: K >= 1 contact points observed during the step
    tracker.update(x, None, None)  # free space

and exposes its current estimate of every contact point seen so far, in the order they were observed
(several contacts of one step in their given order), plus a hard assignment of those points to objects.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

__all__ = ["ContactTracker", "StepResult"]


@dataclass(frozen=True)
class StepResult:
    """What one :meth:`ContactTracker.update` did, one row of the diagnostics table.

    Attributes
    ----------
    ess : float
        Effective sample size / N after weighting, before resampling (1.0 for a tracker without particles).
    resampled : bool
        Whether the step resampled.
    n_replaced : int
        Points replaced over all particles (ReplaceInconsistentPoints, Alg. 2).
    """

    ess: float = 1.0
    resampled: bool = False
    n_replaced: int = 0


@runtime_checkable
class ContactTracker(Protocol):
    """Online estimator of contact point positions and their grouping into objects.

    Shapes: D is the point dimension (2 for the planar pipeline), K the number of contacts of one step, M the
    number of contact points observed so far. Units are metres.
    """

    params: Any
    """The tracker's full parameter dataclass (recorded in the output metadata)."""

    def update(self, x: np.ndarray, dx: np.ndarray | None, p: np.ndarray | None) -> StepResult:
        """Advance by one control step; returns what the step did (:class:`StepResult`).

        Parameters
        ----------
        x : ndarray, shape (D,)
            End-effector position after the step.
        dx : ndarray, shape (K, D), or None
            End-effector displacement while in contact during the step, one row per contact; None out of contact.
        p : ndarray, shape (K, D), or None
            Contact points observed at the end of the step (after the motion); None out of contact.
        """

    @property
    def points_(self) -> np.ndarray:
        """ndarray, shape (M, D): current estimate of every contact point, in observation order."""

    def labels(self) -> np.ndarray:
        """ndarray, shape (M,), int64: hard object assignment of :attr:`points_` (0..n_objects-1)."""
