"""Pose estimators of the retrieve stage: the paper's ICP procedure, run online as the authors did, and the
plausible-set estimator, one call.

Both are registered in :mod:`pipeline.registry` (``paper_estimator``, ``plausible_estimator``: the registry's
factory signature); :func:`estimate` calls any registered estimator by name.

``paper`` is the procedure of the paper's §V-C as the authors ran it (:mod:`pipeline.estimators.paper.online`): at every
in-contact step, ICP from 30 restarts on every segment of the tracker's estimate after that step (restart 0 from the
best estimate so far), lowest position variance chooses the segment, least penetration then lowest ICP error chooses
the pose; the grasp goes to the last in-contact step's estimate. ``plausible`` keeps the paper's segment choice, made
once on the final tracked points (:func:`pipeline.estimators.paper.choice.estimate_run`; how often it picks the target's
segment: docs/experiments/plausible-defaults.md) and replaces the pose by the best of a plausible set
fitted to the known shape, the contact points weighted by recency and the gripper's free space
(:mod:`pipeline.estimators.plausible.fit`).
"""
from __future__ import annotations

import copy
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipeline import registry
from pipeline.constraints import plain
from pipeline.estimators.paper.choice import Estimate, confidence_notes, estimate_run
from pipeline.estimators.paper.online import estimate_online
from pipeline.estimators.params import RetrievalParams
from pipeline.estimators.plausible.evidence import (
    cached_gripper_lattice,
    free_space_points,
    recency_sigma,
    target_reach,
)
from pipeline.estimators.plausible.fit import COST_TIE, PlausibleParams, SegmentFit, fit_segment
from pipeline.estimators.run_info import RunInfo
from pipeline.estimators.segment_choice import resisting_choice
from pipeline.geometry import Primitive
from pipeline.portable import tie_key
from pipeline.schema.retrieval import run_candidates

__all__ = ["DEFAULT_ESTIMATOR", "Segment", "History", "estimate", "estimate_plausible", "paper_estimator",
           "paper_choice", "paper_segment", "plausible_estimator", "needs_every_step", "history_from_final",
           "retrieval_metadata", "plausible_notes", "parse_estimators"]

DEFAULT_ESTIMATOR = registry.DEFAULT_ESTIMATOR


def parse_estimators(text: str) -> tuple[str, ...]:
    """Estimator names from ``"plausible,paper"`` or ``"all"`` (every registered one); ValueError naming an
    unknown one (or none given)."""
    known = registry.estimator_names()
    names = tuple(n.strip() for n in str(text).split(",") if n.strip())
    if names == ("all",):
        return known
    bad = [n for n in names if n not in known]
    if bad or not names:
        raise ValueError(f"unknown estimator {bad[0] if bad else ''!r}; expected some of {', '.join(known)}")
    return names


@dataclass(frozen=True)
class Segment:
    """One segment of a run's final segmentation.

    Attributes
    ----------
    id : int
    points : ndarray, shape (M, 2), metres
        Final tracked positions.
    steps : ndarray, shape (M,), int
        Step (action index) at which each point was observed.
    observed : ndarray, shape (M, 2), metres, or None
        Each point where it was observed, at its own step (None: not given; the pushtrack estimator then
        re-isolates the contacts from the run file). The retrieval ladder's ideal contacts carry it.
    """

    id: int
    points: np.ndarray
    steps: np.ndarray
    observed: np.ndarray | None = None


#: The segments of every in-contact step of one run, in step order: (step, segments of the tracker's estimate after
#: that step). An in-contact step is one with a contact point observed at it (docs/tables.md, tracks).
History = Sequence[tuple[int, Sequence[Segment]]]


def needs_every_step(names: Sequence[str]) -> bool:
    """Whether any of the estimators ``names`` reads the segments of every in-contact step (registry ``needs``)."""
    return any("every_step" in registry.estimator(n).needs for n in names)


def history_from_final(segments: Sequence[Segment]) -> list[tuple[int, list[Segment]]]:
    """A :data:`History` made from final segments alone, for points that do not move (ideal contact points, carried
    to the final pose): at every step at which a point was observed, each segment's points observed up to it.
    Segments without such a point yet are left out."""
    steps = np.unique(np.concatenate([np.asarray(s.steps, dtype=np.int64) for s in segments] or [np.zeros(0, int)]))
    out = []
    for k in steps:
        segs = [Segment(s.id, s.points[s.steps <= k], s.steps[s.steps <= k]) for s in segments]
        out.append((int(k), [s for s in segs if len(s.steps)]))
    return out


def retrieval_metadata(estimator: str, params: RetrievalParams, own=None, **extra) -> dict:
    """What the retrieval and candidates tables record of their parameters: every field of the parameters the
    estimator used (the paper's ICP parameters for every estimator; the estimator's own parameters ``own``, e.g.
    the plausible ones, under its registry ``meta_key``, by default its name)."""
    spec = registry.estimator(estimator)
    meta = dict(params.to_dict(), estimator=estimator)
    own = registry.build_params(spec, own)
    if own is not None:
        meta[spec.meta_key or spec.name] = plain(own)
    for k, v in extra.items():
        meta[k] = plain(v) if hasattr(v, "__dataclass_fields__") else v
    return meta


def estimate(name: str, segments: Sequence[Segment], info: RunInfo, sdf, rngs: Sequence[np.random.Generator],
             params: RetrievalParams = RetrievalParams(), own=None, history: History | None = None) -> Estimate:
    """The target pose of one run by the registered estimator ``name`` (:func:`pipeline.registry.estimator`).

    ``rngs``: (model points, ICP restarts, hypotheses) generators (:func:`pipeline.estimators.run_info.retrieval_rng`);
    ``own``: the estimator's own parameters (an instance, a dict of overrides, or None for its defaults);
    ``history``: the segments of every in-contact step (:data:`History`), passed to an estimator that needs them
    (registry ``needs=("every_step",)``; ValueError if it is None for one).
    """
    spec = registry.estimator(name)
    extra = {}
    if "every_step" in spec.needs:
        if history is None:
            raise ValueError(f"estimator {name!r} needs the segments of every in-contact step (tracks written with "
                             "`stucco track --every-step`)")
        extra["history"] = history
    result = registry.resolve(spec.factory)(segments, info, sdf, rngs, params, registry.build_params(spec, own),
                                            **extra)
    if not isinstance(result, Estimate):
        raise TypeError(f"estimator {name!r} must return an Estimate (pipeline.estimators.paper.choice), got "
                        f"{type(result).__name__}")
    run_candidates(**result.candidates)  # the candidates table's columns, checked here once for every estimator
    return result


def paper_estimator(segments: Sequence[Segment], info: RunInfo, sdf, rngs: Sequence[np.random.Generator],
                    params: RetrievalParams, own: None = None, *, history: History) -> Estimate:
    """The paper's procedure as the authors ran it, at every in-contact step of ``history``
    (:func:`pipeline.estimators.paper.online.estimate_online`), the registry's factory; ``segments`` (the final ones)
    are not used: the grasp goes to the last in-contact step's estimate."""
    return estimate_online([(k, [(s.id, s.points) for s in segs]) for k, segs in history], info.target, info.ee,
                           info.steps, sdf, params, rngs[0], rngs[1])


#: (key, estimate) of the last :func:`paper_choice` in this process.
_LAST_PAPER: list = []


def paper_choice(segments: Sequence[Segment], info: RunInfo, sdf, params: RetrievalParams,
                rngs: Sequence[np.random.Generator]) -> Estimate:
    """:func:`~pipeline.estimators.paper.choice.estimate_run` of a run (the paper's choice of segment on the final
    points), computed once for the estimators of a job that start from it, with the same inputs and generators (a copy
    is returned; the generators are not advanced on a repeat, and no estimator draws from them afterwards)."""
    key = (info.run, str(info.path), repr(info.target), np.asarray(info.ee).tobytes(), params, sdf.digest,
           tuple((s.id, np.asarray(s.points, dtype=np.float64).tobytes()) for s in segments),
           repr(rngs[0].bit_generator.state), repr(rngs[1].bit_generator.state))
    if _LAST_PAPER and _LAST_PAPER[0][0] == key:
        return copy.deepcopy(_LAST_PAPER[0][1])
    est = estimate_run([(s.id, s.points) for s in segments], info.target, info.ee, sdf, params, rngs[0], rngs[1])
    _LAST_PAPER[:] = [(key, copy.deepcopy(est))]
    return est


def paper_segment(segments: Sequence[Segment], info: RunInfo, sdf, params: RetrievalParams,
                  rngs: Sequence[np.random.Generator], t0: float) -> tuple[Estimate, Segment | None]:
    """The paper's choice (:func:`paper_choice`) and the target's segment (the paper's, or the one that resisted
    the pushes most for a heavy target: :func:`~pipeline.estimators.segment_choice.resisting_choice`), or (the paper's
    estimate, its ``icp_s`` counted from ``t0``, None) when no segment fits: the start of every estimator that
    refines the paper's choice."""
    paper = paper_choice(segments, info, sdf, params, rngs)
    if paper.segment < 0:
        paper.icp_s = time.perf_counter() - t0
        return paper, None
    chosen, _ = resisting_choice(segments, paper.segment, paper.candidates, info.steps, info.contact_force,
                                 info.target_mass_kg, params)
    return paper, next(s for s in segments if s.id == chosen)


def plausible_estimator(segments: Sequence[Segment], info: RunInfo, sdf, rngs: Sequence[np.random.Generator],
                        params: RetrievalParams, own: PlausibleParams) -> Estimate:
    """:func:`estimate_plausible` in the registry's factory signature."""
    return estimate_plausible(segments, info, sdf, params, own, rngs)


def plausible_notes(points: np.ndarray, fit: SegmentFit, n_free: int, target: Primitive, params: RetrievalParams,
                    plausible: PlausibleParams) -> list[str]:
    """Low-confidence reasons of a plausible-set estimate.

    ``few_points`` and ``collinear`` as the paper's estimator; ``poor_fit`` (more than half of the points
    farther from the surface than ``outlier_sigmas`` of their sigma: the shape does not explain them);
    ``penetrating`` (the pose puts the target deeper than ``free_tolerance`` plus one lattice cell into the
    gripper's free space); ``no_free_space`` (the gripper never came near after the last contact: nothing
    bounds the pose from outside); ``ambiguous_yaw`` (less than ``min_share`` of the plausible set agrees with
    the estimate's yaw within ``yaw_agreement``; a box only); ``wide_set`` (the agreeing poses spread more
    than ``max_spread``).
    """
    notes = [n for n in confidence_notes(points, 0.0, 0.0, params) if n in ("few_points", "collinear")]
    c = fit.chosen
    if fit.outlier_fraction[c] > 0.5:
        notes.append("poor_fit")
    if fit.penetration[c] > plausible.free_tolerance + plausible.free_resolution:
        notes.append("penetrating")
    if n_free == 0:
        notes.append("no_free_space")
    if target.symmetry != 0.0 and fit.share < plausible.min_share:
        notes.append("ambiguous_yaw")
    if fit.spread > plausible.max_spread:
        notes.append("wide_set")
    return notes


def estimate_plausible(segments: Sequence[Segment], info: RunInfo, sdf, params: RetrievalParams,
                       plausible: PlausibleParams, rngs: Sequence[np.random.Generator]) -> Estimate:
    """The plausible-set estimate of one run: the paper's segment choice, then the best pose of the plausible set
    of that segment (contacts weighted by recency, the gripper's free space after its last contact, the other
    segments' points outside the target).

    Returns an :class:`Estimate` whose candidates are the chosen segment's hypotheses (``restart`` = hypothesis,
    ``icp_rmse_m`` = RMS distance of the points to the surface, ``valid`` = in the plausible set,
    ``position_var_m2`` = squared spread of the agreeing poses, ``rank`` by cost).
    """
    t0 = time.perf_counter()
    paper, seg = paper_segment(segments, info, sdf, params, rngs, t0)
    if seg is None:
        return paper
    target = info.target
    pts = np.asarray(seg.points, dtype=np.float64).reshape(-1, 2)
    centre, radius = target_reach(target, pts)
    lattice = cached_gripper_lattice(sdf, plausible.free_resolution)
    free = free_space_points(lattice, info.ee[:-1], info.ee[1:], info.steps, int(np.max(seg.steps)), plausible, centre,
                             radius)
    others = np.vstack([s.points for s in segments if s.id != seg.id] or [np.zeros((0, 2))])
    others = others[np.linalg.norm(others - centre, axis=1) <= radius]
    icp = paper.candidates
    mine = (icp["segment"] == seg.id) & icp["valid"] if plausible.icp_seeds else np.zeros(0, dtype=bool)
    seeds = np.column_stack([icp["x_m"][mine], icp["y_m"][mine], icp["yaw_rad"][mine]]) if mine.any() else None
    fit = fit_segment(target, pts, recency_sigma(seg.steps, plausible), free, others, plausible, rngs[2], seeds)
    c = fit.chosen
    B = len(fit.poses)
    order = np.lexsort((np.arange(B), tie_key(fit.terms.total, COST_TIE)))  # last-bit ties: by index
    rank = np.empty(B, dtype=np.int64)
    rank[order] = np.arange(B)
    candidates = run_candidates(
        segment=np.full(B, seg.id), restart=np.arange(B), n_points=np.full(B, len(pts)),
        x_m=fit.poses[:, 0], y_m=fit.poses[:, 1], yaw_rad=fit.poses[:, 2], icp_rmse_m=fit.rms,
        penetration_m=fit.penetration, valid=fit.plausible, position_var_m2=np.full(B, fit.spread ** 2),
        rank=rank, segment_chosen=np.ones(B, dtype=bool), chosen=np.arange(B) == c,
    )
    notes = plausible_notes(pts, fit, len(free), target, params, plausible)
    return Estimate(pose=target.canonical(fit.poses[c]), segment=seg.id, n_points=len(pts),
                    n_segments=len(segments), position_var=fit.spread ** 2, rmse=float(fit.rms[c]),
                    penetration=float(fit.penetration[c]), notes=notes, candidates=candidates,
                    icp_s=time.perf_counter() - t0)
