"""Which segment is the target's: the one whose contacts resisted the gripper's pushes most.

The paper's choice (§V-C: the segment whose ICP restarts agree best) cannot tell the target from an object of
similar size beside it: on a box task a can's few drifted points fit a box corner as well as the box's own.
What the gripper *felt* does tell them apart when the target is heavy, as in every task of the paper (the
authors raised the target's mass; docs/estimators.md, "Which segment resisted"): pushing an object takes a force
that grows with its mass, up to what the gripper's controller can exert, so the target's contacts meet large
forces while the household clutter moves away at a few newtons. The force of a contact is the sensed wrench's
in-plane magnitude over the sim steps isolation uses (:func:`pipeline.detection.contact_forces`), a measurement the
robot has, never the simulation's ground truth; the target's mass is part of its known model, like its shape.

:func:`resisting_segment` is the choice: among the segments that fit the target's shape (the paper's fit gate),
the one whose contacts' median force is largest, when the target's known mass is at least
``RetrievalParams.heavy_target_kg``; otherwise none (the paper's choice stands). The ``paper`` estimator never
uses it (it is the authors' procedure); ``plausible``, ``pushtrack`` and the probing policy do.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["target_mass", "applies", "segment_resistance", "point_forces", "resisting_segment", "segment_fits",
           "resisting_choice"]


def target_mass(scene) -> float:
    """The known mass (kg) of a scene's target object (NaN if the scene has none)."""
    return next((float(o.mass) for o in scene.objects if o.target), float("nan"))


def applies(force: np.ndarray | None, mass: float, heavy_target_kg: float | None) -> bool:
    """Whether the resistance rule applies: forces known and the target's ``mass`` (kg) at least
    ``heavy_target_kg`` (None: never)."""
    return force is not None and heavy_target_kg is not None and bool(mass >= heavy_target_kg)


def segment_resistance(segment_steps: Sequence[np.ndarray], steps: np.ndarray, force: np.ndarray) -> np.ndarray:
    """Median contact force (N) of each segment, shape (S,): over the actions its points were observed at.

    Parameters
    ----------
    segment_steps : sequence of ndarray, shape (M_s,)
        Observation steps of each segment's points.
    steps : ndarray, shape (K,); force : ndarray, shape (K,), N
        The run's action steps and the contact force each met (NaN: no contact detected).

    A segment with no finite force (every point at a step without a measured wrench) gets -inf: it never wins.
    """
    out = np.full(len(segment_steps), -np.inf)
    for i, s in enumerate(segment_steps):
        f = point_forces(s, steps, force)
        f = f[np.isfinite(f)]
        if len(f):
            out[i] = float(np.median(f))
    return out


def point_forces(point_steps: np.ndarray, steps: np.ndarray, force: np.ndarray) -> np.ndarray:
    """The contact force (N) the action of each point met, shape (M,): ``point_steps`` (M,) the points' observation
    steps, ``steps`` (K,) the run's action steps (strictly increasing, as a run file's) and ``force`` (K,) the force
    each met; NaN for a step not among them."""
    point_steps = np.asarray(point_steps, dtype=np.int64).reshape(-1)
    steps = np.asarray(steps, dtype=np.int64).reshape(-1)
    force = np.asarray(force, dtype=np.float64).reshape(-1)
    out = np.full(len(point_steps), np.nan)
    if len(steps):
        pos = np.minimum(np.searchsorted(steps, point_steps), len(steps) - 1)
        hit = steps[pos] == point_steps
        out[hit] = force[pos[hit]]
    return out


def resisting_segment(ids: Sequence[int], segment_steps: Sequence[np.ndarray], fits: Sequence[bool],
                      steps: np.ndarray, force: np.ndarray | None, mass: float, heavy_target_kg: float | None
                      ) -> int | None:
    """The segment the target is taken to be by the resistance its contacts met, or None to keep the paper's.

    Parameters
    ----------
    ids : sequence of int
        Segment ids, in the paper's ranking (its choice first): ties go to the earlier one.
    segment_steps : sequence of ndarray
        Observation steps of each segment's points.
    fits : sequence of bool
        Whether each segment passes the paper's fit gate (best ICP error below ``segment_fit_gate``); only those
        compete while one does (a wall pushed against resists too, and fits no box).
    steps, force : ndarray, shape (K,)
        The run's action steps and contact forces (N; :func:`pipeline.detection.contact_forces`); None: not known.
    mass : float, kg
        The target's known mass.
    heavy_target_kg : float or None, kg
        The rule applies when ``mass`` is at least this; None: never.
    """
    if not applies(force, mass, heavy_target_kg) or not len(ids):
        return None
    score = segment_resistance(segment_steps, steps, force)
    fits = np.asarray(fits, dtype=bool)
    if fits.any():
        score = np.where(fits, score, -np.inf)
    if not np.isfinite(score).any():
        return None
    return int(ids[int(np.argmax(score))])  # argmax: the first of equal scores, i.e. the paper's ranking


def segment_fits(candidates, ids: Sequence[int], gate: float) -> np.ndarray:
    """Whether each segment's best valid ICP restart (candidates table columns ``segment``, ``valid``,
    ``icp_rmse_m``) has an error within ``gate`` (m), shape (S,): the paper's fit gate."""
    seg = np.asarray(candidates["segment"])
    err = np.where(np.asarray(candidates["valid"], dtype=bool), np.asarray(candidates["icp_rmse_m"], dtype=float),
                   np.inf)
    return np.array([bool(np.min(err[seg == i], initial=np.inf) <= gate) for i in ids], dtype=bool)


def resisting_choice(segments: Sequence, paper_segment: int, candidates, steps: np.ndarray,
                     force: np.ndarray | None, mass: float, params) -> tuple[int, bool]:
    """The target's segment and whether the resistance decided it: :func:`resisting_segment` among ``segments``
    (objects with ``id`` and ``steps``), the paper's choice ``paper_segment`` first in the ranking, its ICP
    ``candidates`` for the fit gate; (the paper's choice, False) when the rule does not apply or nothing was
    measured (``params``: :class:`~pipeline.estimators.params.RetrievalParams`)."""
    ranked = sorted(segments, key=lambda s: s.id != paper_segment)  # stable: the paper's choice first
    ids = [int(s.id) for s in ranked]
    chosen = resisting_segment(ids, [s.steps for s in ranked], segment_fits(candidates, ids, params.segment_fit_gate),
                               steps, force, mass, params.heavy_target_kg)
    return (paper_segment, False) if chosen is None else (chosen, True)
