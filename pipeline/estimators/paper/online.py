"""The paper's pose estimation run the way the authors ran it: online, at every in-contact step (§V-C).

The authors' retrieval loop (docs/estimators.md) does not fit one pose to the final points. At
every step whose contact detector fired it takes the tracker's current points, segments them (Alg. 3), runs ICP
from 30 restarts on every segment and redoes the choice (lowest position variance picks the segment, least
penetration of the gripper positions visited *so far* then lowest ICP error picks the pose). Restart 0 of every
ICP starts from the best estimate so far (their ``best_tsf_guess``): the previous step's choice, and within a step
the choice among the segments already fitted in that step. The grasp goes to the estimate of the last in-contact
step. :func:`estimate_online` is that loop on the per-step segments that ``stucco track --every-step`` and
``stucco segment`` give, with this project's ICP, choice rule and confidence notes
(:mod:`pipeline.estimators.paper.choice`).

Cost: only the in-contact steps are fitted; the penetration, the most expensive score, is computed for a segment
only when it is chosen at a step, and for every segment at the last step (whose candidates are kept).
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.estimators.paper.choice import (
    Choice,
    Estimate,
    assemble,
    choose_segment,
    icp_segment,
    min_clearance,
    nonempty,
)
from pipeline.estimators.paper.icp import IcpResult
from pipeline.estimators.paper.icp_kernel import warm_up
from pipeline.estimators.params import RetrievalParams
from pipeline.estimators.target_model import model_normals, model_points
from pipeline.geometry import Primitive

__all__ = ["StepChoice", "visited_until", "online_protocol", "estimate_online"]

#: One in-contact step: (step, [(segment id, points (M, 2) world metres), ...]).
StepSegments = tuple[int, Sequence[tuple[int, np.ndarray]]]


@dataclass(frozen=True)
class StepChoice:
    """What the online protocol chose at one in-contact step.

    Attributes
    ----------
    step : int
        The in-contact step (action index).
    segment : int
        Chosen segment id at that step (-1: no segment).
    restart : int
        Chosen restart of that segment.
    pose : ndarray, shape (3,)
        Chosen pose (x m, y m, yaw rad), canonical under the target's symmetry.
    warm : ndarray, shape (3,) or None
        The world -> model transform restart 0 of the step's first segment started from (None at the first
        in-contact step).
    n_segments : int
    """

    step: int
    segment: int
    restart: int
    pose: np.ndarray
    warm: np.ndarray | None
    n_segments: int


def visited_until(ee: np.ndarray, steps: np.ndarray, step: int) -> np.ndarray:
    """Gripper positions visited up to the end of action ``step``: the start, then the end of every action whose
    step is <= ``step`` (``ee`` (K + 1, 2) and ``steps`` (K,) as :class:`~pipeline.estimators.run_info.RunInfo` holds
    them, steps non-decreasing). Returns (k + 1, 2)."""
    return np.asarray(ee, dtype=np.float64)[: int(np.searchsorted(steps, step, side="right")) + 1]


def _choose(target: Primitive, results: Sequence[IcpResult], pens: list[np.ndarray | None], params: RetrievalParams,
            penetration) -> Choice:
    """The paper's choice (:func:`~pipeline.estimators.paper.choice.choose_segment`) among ``results``, computing the
    penetration (``penetration(result) -> (B,)``) of the chosen segment only if ``pens`` does not hold it yet
    (the segment choice does not depend on it; only the restart's rank within the segment does)."""
    centres = [target.centre_world(r.poses) for r in results]
    rmse, valid = [r.rmse for r in results], [r.valid for r in results]

    def choose() -> Choice:
        filled = [np.zeros(len(r.rmse)) if p is None else p for r, p in zip(results, pens)]
        return choose_segment(centres, filled, rmse, valid, params.penetration_tolerance, params.segment_fit_gate,
                              params.agreement_tolerance)

    choice = choose()
    if choice.segment_index >= 0 and pens[choice.segment_index] is None:
        pens[choice.segment_index] = penetration(results[choice.segment_index])
        choice = choose()
    return choice


def online_protocol(history: Sequence[StepSegments], target: Primitive, ee: np.ndarray, ee_steps: np.ndarray,
                    sdf, params: RetrievalParams, rng_model: np.random.Generator,
                    rng_restarts: np.random.Generator) -> tuple[Estimate, list[StepChoice]]:
    """The authors' online estimation over the in-contact steps of one run.

    Parameters
    ----------
    history : sequence of (step, segments)
        Every in-contact step in increasing order, with the segments of the tracker's estimate after that step:
        (segment id, points (M, 2) world metres); empty segments are skipped.
    target : Primitive
    ee : ndarray, shape (K + 1, 2)
        Gripper positions (:attr:`RunInfo.ee`).
    ee_steps : ndarray, shape (K,)
        Step of each action (:attr:`RunInfo.steps`).
    sdf : GridSDF
        Gripper grid for pxpen.
    params : RetrievalParams
    rng_model, rng_restarts : numpy.random.Generator
        Model points (drawn once for the run), then every step's restarts in step and segment order.

    Returns
    -------
    estimate : Estimate
        The last in-contact step's choice, its candidates (every segment of that step) and notes, scored against
        the gripper positions visited up to that step; ``icp_s`` covers the whole loop. Without any in-contact
        step: the last gripper position, flagged ``no_points``.
    trail : list of StepChoice
        The choice at every in-contact step.
    """
    warm_up()  # compile or load the kernels before the clock starts (as the tracker does)
    t0 = time.perf_counter()
    model = model_points(target, params, rng_model)
    normals = model_normals(target, model)
    ee = np.asarray(ee, dtype=np.float64).reshape(-1, 2)
    ee_steps = np.asarray(ee_steps, dtype=np.int64)
    warm: np.ndarray | None = None  # the authors' best_tsf_guess: world -> model transform of the best so far
    trail: list[StepChoice] = []
    last = None
    for step, segments in history:
        segs = nonempty(segments)
        if not segs:
            continue
        visited = visited_until(ee, ee_steps, int(step))

        def penetration(res: IcpResult, visited: np.ndarray = visited) -> np.ndarray:
            """Penetration (B,) of a result's poses into the gripper positions visited up to this step."""
            return np.maximum(-min_clearance(sdf, model, res.poses, visited), 0.0)

        first_warm = warm
        results: list[IcpResult] = []
        pens: list[np.ndarray | None] = []
        for _, pts in segs:
            results.append(icp_segment(pts, model, normals, params, rng_restarts, warm))
            pens.append(None)
            # The authors update best_tsf_guess inside the segment loop: a later segment of the same step starts
            # from the best of the segments before it.
            c = _choose(target, results, pens, params, penetration)
            if c.segment_index >= 0:
                warm = results[c.segment_index].world_to_model[c.restart].copy()
        trail.append(StepChoice(int(step), segs[c.segment_index][0] if c.segment_index >= 0 else -1, c.restart,
                                target.canonical(results[c.segment_index].poses[c.restart])
                                if c.segment_index >= 0 else np.full(3, np.nan), first_warm, len(segs)))
        last = (segs, results, pens, penetration, visited)
    if last is None:
        return assemble([], [], [], choose_segment([], [], [], [], params.penetration_tolerance), target, ee, params,
                        t0), trail
    segs, results, pens, penetration, visited = last
    # The last step's candidates are kept for every segment: their penetration too.
    pens = [penetration(r) if p is None else p for r, p in zip(results, pens)]
    choice = _choose(target, results, pens, params, penetration)
    return assemble(segs, results, pens, choice, target, visited, params, t0), trail


def estimate_online(history: Sequence[StepSegments], target: Primitive, ee: np.ndarray, ee_steps: np.ndarray, sdf,
                    params: RetrievalParams, rng_model: np.random.Generator, rng_restarts: np.random.Generator
                    ) -> Estimate:
    """The estimate of :func:`online_protocol` (the grasp pose: the last in-contact step's choice)."""
    return online_protocol(history, target, ee, ee_steps, sdf, params, rng_model, rng_restarts)[0]
