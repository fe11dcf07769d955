"""The interface every contact tracker implements, so that `stucco track --method ...` treats all alike.

A tracker is fed one control step at a time, in order::

    tracker.update(x, dx, p)     # in contact: K >= 1 contact points observed during the step
    tracker.update(x, None, None)  # free space

and exposes its current estimate of every contact point seen so far, in the order they were observed
(several contacts of one step in their given order), plus a hard assignment of those points to objects.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class ContactTracker(Protocol):
    """Online estimator of contact point positions and their grouping into objects.

    Shapes: D is the point dimension (2 for the planar pipeline), K the number of contacts of one step, M the
    number of contact points observed so far. Units are metres.
    """

    def update(self, x: np.ndarray, dx: np.ndarray | None, p: np.ndarray | None) -> None:
        """Advance by one control step.

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


def params_from_dict(cls: type, values: dict[str, Any], method: str) -> Any:
    """Build the parameter dataclass ``cls`` of ``method`` from a mapping of overrides, refusing (ValueError, one
    line naming the parameter) unknown names and values of the wrong kind: a number where the default is a number
    (finite; an integer where the default is one), a flag where it is a flag. Ranges are the dataclass's own
    ``__post_init__`` checks."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - set(fields))
    if unknown:
        raise ValueError(f"unknown parameter(s) {', '.join(map(repr, unknown))} for method {method!r}; "
                         f"accepted: {', '.join(fields)}")
    for name, value in values.items():
        default = fields[name].default
        if isinstance(default, bool):
            ok = isinstance(value, bool)
            kind = "true or false"
        elif isinstance(default, int):
            ok = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
            kind = "an integer"
        elif isinstance(default, float):
            ok = isinstance(value, (int, float, np.number)) and not isinstance(value, bool) and math.isfinite(value)
            kind = "a finite number"
        else:
            continue
        if not ok:
            raise ValueError(f"parameter {name!r} of method {method!r} must be {kind}, got {value!r}")
    return cls(**values)
