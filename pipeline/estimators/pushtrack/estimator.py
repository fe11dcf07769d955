"""The ``pushtrack`` estimator: the paper's segment choice, then the target's pose tracked through its pushes.

The tracker's segments say which contact steps belong to the target (the segment the paper's choice picks, as the
plausible estimator does); the contacts themselves are taken at their own steps, where they were observed, not
where the tracker carried them (it moves old points by translation only, §VI-A). The run file gives each action's
isolated contact point (the same detection and isolation as ``stucco isolate``, with its defaults) and the
gripper's in-contact displacement; :func:`pipeline.estimators.pushtrack.filter.run_filter` tracks the pose over
the actions,
:func:`final_pose` refines the best particles at the end, and the final particles are the plausible set
(docs/estimators.md, "The pushtrack estimator").
"""
from __future__ import annotations

import copy
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline.contact_isolation import isolate_run, isolation_surface
from pipeline.detection import scene_detection
from pipeline.estimators.estimate import Segment, estimate_plausible, paper_segment
from pipeline.estimators.paper.choice import Estimate, confidence_notes
from pipeline.estimators.params import RetrievalParams
from pipeline.estimators.plausible.cost import refine
from pipeline.estimators.plausible.evidence import (
    cached_gripper_lattice,
    first_per_cell,
    free_space_points,
    target_reach,
)
from pipeline.estimators.plausible.params import PlausibleParams
from pipeline.estimators.pushtrack.filter import SLICE_MOTIONS, Actions, FilterResult, PushTrackParams, run_filter
from pipeline.estimators.pushtrack.kernel import near_points
from pipeline.estimators.pushtrack.slice_pusher import cached_gripper_slice
from pipeline.estimators.run_info import RunInfo
from pipeline.geometry import Primitive, apply_pose, com_pose, primitive_pose, primitive_sdf, rotate, wrap_symmetric
from pipeline.grasp_rule import own_grasp_shares
from pipeline.portable import argmin_tolerant, exp, logsumexp, tie_key
from pipeline.safe_open import regular_file
from pipeline.schema import step_bounds
from pipeline.schema.retrieval import run_candidates

__all__ = ["pushtrack_estimator", "pushtrack_set", "track_segment", "Tracked", "observed_actions", "free_space_of",
           "filter_from_best_start", "filter_islands", "pool_islands", "refine_final", "posterior_costs", "final_pose",
           "held_mean", "PLAUSIBLE_SET"]

#: Particles kept as the run's candidates (the plausible set): the highest weights.
PLAUSIBLE_SET = 64


def observed_actions(info: RunInfo, sdf, table: pa.Table | None = None, near: Segment | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Contact point (K, 2) at the end of every action (NaN without) and the gripper's in-contact displacement
    (K, 2) (0 without), metres, re-isolated with the scene's detector from ``table`` (the run's
    ``sim_run`` rows; the run file's when None), or as a robot's log recorded them (``info.observed``).

    An action with several contacts (fingertip sensors, docs/simulation.md) keeps one: the one nearest to the
    points of ``near`` (the tracked segment) observed at that action, else its first (the pushes' model moves the
    target by one contact per action)."""
    if table is None and info.observed is not None:  # a robot's log: its contacts as it recorded them
        return info.observed[0].copy(), info.observed[1].copy()
    rows = pq.read_table(regular_file(info.path, "the run file")) if table is None else table
    cols, _, _ = isolate_run(rows, *isolation_surface(sdf), scene_detection(info.scene))
    inc = np.asarray(cols["in_contact"], dtype=bool)
    f = lambda k: np.array([v if v is not None else np.nan for v in cols[k]], dtype=np.float64)  # noqa: E731
    contact = np.column_stack([f("contact_x_m"), f("contact_y_m")])
    push = np.where(inc[:, None], np.column_stack([f("dx_m"), f("dy_m")]), 0.0)
    step = np.asarray(cols["step"], dtype=np.int64)
    first, ends = step_bounds(step)
    if len(first) < len(step):  # several contacts in some actions: one row per action, the one nearest the segment
        pick = first.copy()
        seg_steps = np.zeros(0, np.int64) if near is None else np.asarray(near.steps, np.int64)
        for a in np.flatnonzero(ends - first > 1):  # the few multi-contact actions
            rows_a = np.arange(first[a], ends[a])
            mine = near.points[seg_steps == step[first[a]]] if near is not None else np.zeros((0, 2))
            if len(mine) and inc[rows_a].all():
                d = np.min(np.hypot(*(contact[rows_a, None, :] - mine[None, :, :]).transpose(2, 0, 1)), axis=1)
                pick[a] = rows_a[int(np.argmin(d))]
        contact, push = contact[pick], push[pick]
    return contact, np.nan_to_num(push)


def free_space_of(actions: Actions, lattice: np.ndarray, params: PushTrackParams, radius: float):
    """``free_points(rows, centre)`` for :func:`~pipeline.estimators.pushtrack.filter.run_filter`: the world points
    (F, 2) of the gripper's slice (lattice (G, 2)) at the end of the actions ``rows`` and along those that did not
    touch the target (every ``sweep_spacing``), within ``radius`` of ``centre``, one per ``free_resolution`` cell."""
    reach = radius + (float(np.max(np.hypot(lattice[:, 0], lattice[:, 1]))) if len(lattice) else 0.0)
    # slice poses (P, 2) and lattice points (P, G, 2) of each action, made once: every start and island asks for them
    trails: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def free_points(rows: np.ndarray, centre: np.ndarray) -> np.ndarray:
        rows = np.asarray(rows, dtype=np.int64)
        # (a start's long prefix is not kept; a stretch of actions between touches is asked for by every filter)
        key = (int(rows[0]), int(rows[-1]), len(rows)) if len(rows) and (len(rows) == 1 or rows[0] > 0) else None
        if not params.free_in_contact:  # another segment's contact may be the target's, mis-segmented
            rows = rows[actions.touch[rows] | ~np.all(np.isfinite(actions.contact[rows]), axis=1)]
        if len(rows) == 0 or len(lattice) == 0:
            return np.zeros((0, 2))
        made = trails.get(key)
        if made is None:
            poses = actions.slice_poses(rows, params.sweep_spacing)
            made = np.ascontiguousarray(poses), np.ascontiguousarray(poses[:, None, :] + lattice[None, :, :])
            if key is not None:
                trails[key] = made
        pts = near_points(made[0], made[1], float(centre[0]), float(centre[1]), reach, radius)
        return first_per_cell(pts, params.free_resolution)

    return free_points


def filter_from_best_start(prim: Primitive, actions: Actions, free_points, params: PushTrackParams,
                           rng: np.random.Generator) -> tuple[FilterResult | None, Actions]:
    """:func:`~pipeline.estimators.pushtrack.filter.run_filter` started at each of the first ``params.starts`` touching
    actions, the earlier ones given to another object (no longer touching: they push nothing; ``free_points``
    decides what of them is free space, as for any action).

    Returns the filter of the highest evidence, each skipped contact charged ``outlier_sigmas``² / 2 nats (what the
    contact term costs a contact far off the surface) and any later start ``start_margin`` nats, the earliest start
    on a tie, and the actions it ran on (docs/estimators.md, "Where the filter starts"); (None, ``actions``) when no
    action touched the target.

    Every start draws from a copy of ``rng`` (common random numbers: the starts differ by their evidence, not by
    their draws), so ``starts`` 1 is :func:`run_filter` itself.
    """
    touched = np.flatnonzero(actions.touch)
    if len(touched) == 0:
        return None, actions
    best, kept = run_filter(prim, actions, free_points, params, copy.deepcopy(rng)), actions
    score = best.log_evidence
    for s in range(1, min(params.starts, len(touched))):
        charge = 0.5 * params.outlier_sigmas ** 2 * s + params.start_margin
        if score >= -charge:
            break  # the evidence is at most 0: this start and every later one cannot win
        touch = actions.touch.copy()
        touch[touched[:s]] = False
        act = replace(actions, touch=touch)
        # (a start wins only by more than the machines' last bits: docs/evaluation.md, "Same numbers on every
        # machine"; one that cannot win any more is given up, 1e-6 below the bar against round-off)
        result = run_filter(prim, act, free_points, params, copy.deepcopy(rng), score + charge - 1e-6)
        if result is not None and result.log_evidence - charge > score + 1e-9:
            best, kept, score = result, act, result.log_evidence - charge
    return best, kept


def filter_islands(prim: Primitive, actions: Actions, free_points, params: PushTrackParams, rng: np.random.Generator,
                   first: FilterResult) -> FilterResult:
    """``params.islands`` independent filters over ``actions`` pooled (:func:`pool_islands`): ``first`` is island 0
    (the filter :func:`filter_from_best_start` kept, drawn from a copy of ``rng``), island k draws from ``rng``'s
    bit generator jumped k times (independent streams; ``rng`` itself is not advanced). ``islands`` 1 returns
    ``first``."""
    if params.islands <= 1:
        return first
    results = [first] + [run_filter(prim, actions, free_points, params,
                                    np.random.Generator(copy.deepcopy(rng).bit_generator.jumped(k)))
                         for k in range(1, params.islands)]
    return pool_islands(results)


def pool_islands(results: Sequence[FilterResult]) -> FilterResult:
    """Filters run over the same actions (the same touching actions, so ``local`` and ``pushed`` line up) pooled
    into one: every island's particles, each island's normalised log-weights plus the log of its share of the
    islands' summed evidence (an island of -inf evidence, every particle inconsistent somewhere, gets none; when
    every island has -inf, they share equally). The pooled ``log_evidence`` is the log of the islands' mean
    evidence, ``n_resampled`` their sum. Log-weights stay finite and sum to one."""
    ev = np.array([r.log_evidence for r in results], dtype=np.float64)
    finite = np.isfinite(ev)
    if finite.any():
        keep = np.flatnonzero(finite)
        share = ev[keep] - logsumexp(ev[keep])
        mean_ev = float(logsumexp(ev[keep]) - math.log(len(results)))
    else:  # every island inconsistent somewhere: they share equally
        keep = np.arange(len(results))
        share = np.full(len(keep), -math.log(len(keep)))
        mean_ev = -math.inf
    log_w = np.concatenate([results[k].log_w + s for k, s in zip(keep, share)])
    log_w = log_w - logsumexp(log_w)
    first = results[int(keep[0])]
    return FilterResult(poses=np.concatenate([results[k].poses for k in keep]), log_w=log_w,
                        local=np.concatenate([results[k].local for k in keep]),
                        choice=np.concatenate([results[k].choice for k in keep]), pushed=first.pushed,
                        n_pushes=first.n_pushes, n_resampled=int(sum(r.n_resampled for r in results)),
                        log_evidence=mean_ev)


def refine_final(target: Primitive, result: FilterResult, free: np.ndarray, others: np.ndarray, own: PushTrackParams
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``own.n_refine`` highest-weight particles refined at the end (:class:`PushTrackParams`).

    Returns (indices (H,) of the refined particles, their refined COM poses (H, 3), their costs (H,) in squared
    contact sigmas: the plausible estimator's terms over the particle's carried contacts, the free space
    ``free`` (F, 2) after the last push and the other segments' points ``others`` (O, 2)).
    """
    order = np.lexsort((np.arange(len(result.log_w)), -tie_key(result.log_w, 1e-9)))
    # Resampled copies of one particle refine to the same pose: one of each.
    _, first = np.unique(np.round(result.poses[order], 9), axis=0, return_index=True)
    top = order[np.sort(first)][:own.n_refine]
    T = result.local.shape[1]
    sigma = own.contact_sigma * own.refine_growth ** (T - 1 - np.arange(T, dtype=np.float64))
    sigma = np.hypot(sigma, own.refine_spread * result.pushed)
    lm = PlausibleParams(contact_sigma=own.contact_sigma, free_tolerance=own.free_tolerance,
                         free_resolution=own.free_resolution)
    # each particle with its own carried contacts (H, T, 2), all H refined at once
    pts = apply_pose(result.poses[top], result.local[top])
    pose, terms = refine(target, primitive_pose(target, result.poses[top]), pts, sigma, free, others, lm)
    return top, com_pose(target, pose), terms.total


def posterior_costs(result: FilterResult, top: np.ndarray, costs: np.ndarray) -> np.ndarray:
    """Posterior cost (H,) of the refined particles ``top`` (H,) of costs ``costs`` (H,) (:func:`refine_final`):
    the cost minus the particle's log-weight and the log prior of its pushed-or-left choices."""
    return costs - result.log_w[top] - result.choice[top]


def final_pose(prim: Primitive, result: FilterResult, free: np.ndarray, others: np.ndarray,
               params: PushTrackParams, scene=None) -> tuple[np.ndarray, int]:
    """The estimate of a filtered run: (COM pose (3,), index of the particle it comes from). The highest-weight
    particle without refinement (``n_refine`` 0), otherwise, by ``params.select``, the refined particle of lowest
    cost ("cost"), of lowest posterior cost (its cost minus its log-weight and the log prior of its pushed-or-left
    choices: "posterior"), or, for the grasp plan of ``scene``, the one whose paper grasp holds the largest share of
    the refined set weighted by exp(-posterior cost) ("mode", the lowest posterior cost among equals), or of
    lowest posterior cost among the particles that grasp holds ("grasp"), or the posterior mean of those of them
    whose yaw agrees with that one's (:func:`held_mean`, "held_mean")."""
    order = np.lexsort((np.arange(len(result.log_w)), -tie_key(result.log_w, 1e-9)))
    if not params.n_refine:
        return result.poses[order[0]], int(order[0])
    top, refined, costs = refine_final(prim, result, free, others, params)
    if params.select == "cost":
        k = argmin_tolerant(costs, 1e-9)
        return refined[k], int(top[k])
    post = posterior_costs(result, top, costs)
    if params.select in ("grasp", "mode", "held_mean"):
        if scene is None:
            raise ValueError(f"select={params.select!r} needs the scene (its grasp plan)")
        # The Bayes decision for the grasp script: the posterior over yaw is often flat on the boxes, and its
        # lowest cost is then an arbitrary member of the set (docs/estimators.md). The grasp aimed at `mode` holds
        # the largest share; "mode" reports that particle, "grasp" the most probable particle that grasp holds
        # (whose own grasp may hold less of the set).
        share, held = own_grasp_shares(scene, prim, refined, exp(-(post - np.min(post))))
        mode = int(np.lexsort((np.arange(len(post)), tie_key(post, 1e-9), -tie_key(share, 1e-9)))[0])
        k = mode if params.select == "mode" else argmin_tolerant(np.where(held[mode], post, np.inf), 1e-9)
        if params.select == "held_mean":
            return held_mean(prim, refined, post, held[mode], k, params.mean_yaw), int(top[k])
        return refined[k], int(top[k])
    k = argmin_tolerant(post, 1e-9)
    return refined[k], int(top[k])


def held_mean(prim: Primitive, poses: np.ndarray, post: np.ndarray, held: np.ndarray, k: int,
              yaw_window: float) -> np.ndarray:
    """The posterior mean COM pose (3,) of the refined particles ``poses`` (H, 3) that one grasp holds (``held``
    (H,) bool, ``k`` among them) and whose primitive yaw is within ``yaw_window`` (radians, modulo the shape's
    symmetry; any yaw for a can) of particle k's, weighted by exp(-``post``) (H,): centre and yaw averaged in the
    primitive's frame, yaw as k's plus the mean wrapped difference. Where the refined particles split into groups
    of equal cost a grasp-width apart, the mean sits between them and the grasp aimed at it holds both
    (docs/estimators.md, "The estimate: the posterior mean of what the grasp holds")."""
    pp = primitive_pose(prim, np.asarray(poses, dtype=np.float64).reshape(-1, 3))
    dy = wrap_symmetric(pp[:, 2] - pp[k, 2], prim.symmetry)
    near = np.asarray(held, dtype=bool) & (np.abs(dy) <= yaw_window)
    near[k] = True
    w = np.where(near, exp(-(post - np.min(post[near]))), 0.0)
    w = w / np.sum(w)
    centre = np.sum(pp[:, :2] * w[:, None], axis=0)
    return com_pose(prim, np.array([centre[0], centre[1], pp[k, 2] + np.sum(dy * w)]))


@dataclass
class Tracked:
    """One run's filter over the chosen segment (:func:`track_segment`).

    Attributes
    ----------
    segment : Segment
        The segment the paper's choice picked.
    contact : ndarray, shape (K, 2)
        Every action's isolated contact point (NaN without), metres.
    touch : ndarray, shape (K,), bool
        The actions the filter took as touching the target.
    points : ndarray, shape (T, 2)
        The target's contacts (the segment's points when none was isolated).
    result : FilterResult
    free, others : ndarray, shape (F, 2), (O, 2)
        The free space after the last push and the other segments' points near the target, for the refinement
        (empty with ``n_refine`` 0).
    """

    segment: Segment
    contact: np.ndarray
    touch: np.ndarray
    points: np.ndarray
    result: FilterResult
    free: np.ndarray
    others: np.ndarray


def track_segment(segments: Sequence[Segment], info: RunInfo, sdf, rngs: Sequence[np.random.Generator],
                  params: RetrievalParams, own: PushTrackParams, table: pa.Table | None = None
                  ) -> tuple[Estimate | None, Tracked | None]:
    """The paper's segment choice, then the particle filter over its contacts at their own steps.

    ``table``: the run's ``sim_run`` rows (read from ``info.path`` when None; the active protocol passes the
    scripted part's). Returns (None, the filter), or (the estimate to report instead, None): the paper's when no
    segment is chosen, the plausible estimator's when the segment has no isolated contact in the rows.
    """
    t0 = time.perf_counter()
    paper, seg = paper_segment(segments, info, sdf, params, rngs, t0)
    if seg is None:
        return paper, None
    target = info.target
    contact, push = observed_actions(info, sdf, table, seg)
    if seg.observed is not None:  # the contacts given where they were observed (the ladder's ideal ones)
        # (the other actions keep their isolated contacts: another segment's contact may push the target)
        contact[np.searchsorted(info.steps, np.asarray(seg.steps))] = np.asarray(seg.observed, dtype=np.float64)
    touch = np.isin(info.steps, np.asarray(seg.steps)) & np.all(np.isfinite(contact), axis=1)
    actions = Actions(ee_start=info.ee[:-1], ee_end=info.ee[1:], touch=touch, contact=contact, push=push,
                      gripper=cached_gripper_slice(sdf) if own.motion in SLICE_MOTIONS else None)
    pts = contact[touch] if touch.any() else np.asarray(seg.points, dtype=np.float64).reshape(-1, 2)
    _, radius = target_reach(target, pts)
    lattice = cached_gripper_lattice(sdf, own.free_resolution)
    free_points = free_space_of(actions, lattice, own, radius)
    result, actions = filter_from_best_start(target, actions, free_points, own, rngs[2])
    touch = actions.touch  # the contacts before the filter's start are another object's
    if result is None:
        est = estimate_plausible(segments, info, sdf, params, PlausibleParams(), rngs)
        est.icp_s = time.perf_counter() - t0
        return est, None
    result = filter_islands(target, actions, free_points, own, rngs[2], result)
    free = others = np.zeros((0, 2))
    if own.n_refine:
        centre = np.mean(pts, axis=0)
        free = free_space_points(lattice, actions.ee_start, actions.ee_end, info.steps,
                                 int(info.steps[np.flatnonzero(touch)[-1]]), PlausibleParams(
                                     free_resolution=own.free_resolution, sweep_spacing=own.sweep_spacing),
                                 centre, radius)
        others = np.vstack([s.points for s in segments if s.id != seg.id] or [np.zeros((0, 2))])
        others = others[np.hypot(*(others - centre).T) <= radius]
    return None, Tracked(seg, contact, touch, pts, result, free, others)


def pushtrack_set(segments: Sequence[Segment], info: RunInfo, sdf, rngs: Sequence[np.random.Generator],
                  params: RetrievalParams, own: PushTrackParams, table: pa.Table | None = None
                  ) -> tuple[np.ndarray, np.ndarray, int] | None:
    """The filter's refined set at the end of the rows (:func:`refine_final`): COM poses (H, 3), their posterior
    weights (H,) (exp(-posterior cost), summing to 1) and the segment tracked, or None when the filter does not run
    (no segment chosen, or none of its contacts isolated). The active protocol's prior over the target's pose after
    the scripted part (docs/active.md, "What the pushes said: a prior from pushtrack")."""
    own = replace(own, n_refine=max(own.n_refine, 1))
    _, tracked = track_segment(segments, info, sdf, rngs, params, own, table)
    if tracked is None:
        return None
    top, refined, costs = refine_final(info.target, tracked.result, tracked.free, tracked.others, own)
    post = posterior_costs(tracked.result, top, costs)
    w = exp(-(post - np.min(post)))
    return refined, w / np.sum(w), int(tracked.segment.id)


def pushtrack_estimator(segments: Sequence[Segment], info: RunInfo, sdf, rngs: Sequence[np.random.Generator],
                        params: RetrievalParams, own: PushTrackParams) -> Estimate:
    """The registry's factory (:class:`pipeline.registry.EstimatorSpec`): the paper's segment choice, then the
    final pose of the particle filter over the chosen segment's contacts at their own steps (:func:`track_segment`).

    Falls back to the plausible estimator when the chosen segment has no isolated contact in the run file (a
    segmentation made from other contacts). Candidates: the :data:`PLAUSIBLE_SET` highest-weight particles, before
    the refinement (``restart`` = particle, ``icp_rmse_m`` = distance of the last target contact to the surface,
    ``valid`` = weight within e^-2 of the best, ``position_var_m2`` = weighted variance of the particles' centres,
    ``chosen`` = the particle whose refinement is the estimate, when among them).
    """
    t0 = time.perf_counter()
    fallback, tracked = track_segment(segments, info, sdf, rngs, params, own)
    if tracked is None:
        return fallback
    target, seg, contact, touch, pts = info.target, tracked.segment, tracked.contact, tracked.touch, tracked.points
    result, free, others = tracked.result, tracked.free, tracked.others
    plan_scene = info.scene if info.scene is not None else info.grasp_scene  # a log's stand-in for its grasp plan
    best_pose, best = final_pose(target, result, free, others, own, plan_scene)
    order = np.lexsort((np.arange(len(result.log_w)), -tie_key(result.log_w, 1e-9)))[:PLAUSIBLE_SET]
    poses, log_w = result.poses[order], result.log_w[order]
    B = len(order)
    last = contact[np.flatnonzero(touch)[-1]]
    q = rotate(last - target.centre_world(poses), poses[:, 2] + target.yaw, inverse=True)
    rms = np.abs(primitive_sdf(target, q)[0])
    share = log_w - log_w.max()
    centres = target.centre_world(result.poses)
    wlin = exp(result.log_w)
    mean = np.sum(centres * wlin[:, None], axis=0)
    var = float(np.sum(wlin * np.sum((centres - mean) ** 2, axis=1)))
    candidates = run_candidates(
        segment=np.full(B, seg.id), restart=order.astype(np.int64), n_points=np.full(B, int(touch.sum())),
        x_m=poses[:, 0], y_m=poses[:, 1], yaw_rad=poses[:, 2], icp_rmse_m=rms, penetration_m=np.zeros(B),
        valid=share >= -2.0, position_var_m2=np.full(B, var), rank=np.arange(B),
        segment_chosen=np.ones(B, dtype=bool), chosen=order == best)
    notes = [n for n in confidence_notes(pts, 0.0, 0.0, params) if n in ("few_points", "collinear")]
    return Estimate(pose=target.canonical(best_pose), segment=seg.id, n_points=int(touch.sum()),
                    n_segments=len(segments), position_var=var, rmse=float(rms[0]), penetration=0.0, notes=notes,
                    candidates=candidates, icp_s=time.perf_counter() - t0)
