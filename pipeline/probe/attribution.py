"""Which probe contacts are the target's, and the plausible set they make (docs/retrieval.md, "Active retrieval"):
the attribution of each probe contact to the target or to another object, tried again at later decisions, the set
fitted to the target's contacts with the pushes' prior, and the segment giving way at the end of the budget. The
probing policy (:mod:`pipeline.probe.policy`) asks these at every decision.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from functools import partial

import numpy as np

from pipeline.estimators.estimate import Segment
from pipeline.estimators.params import RetrievalParams
from pipeline.estimators.run_info import retrieval_rng
from pipeline.estimators.segment_choice import point_forces
from pipeline.geometry import Primitive, primitive_pose, primitive_sdf, rotate
from pipeline.probe.belief import (
    NO_TARGET,
    PoseSet,
    Sensing,
    TargetChoice,
    choose_target,
    explaining,
    pose_set,
    surface_distance,
)
from pipeline.probe.params import ProbeLog, ProbeParams
from pipeline.probe.planning import PlanParams, agreement

__all__ = ["light_limit", "set_limits", "heavy_choices", "no_target", "misfit", "current_set",
           "set_from_steps", "prior_for", "mine_now", "probe_points_at", "set_share", "bunched", "give_way_at_budget",
           "required_contacts"]


def light_limit(params: ProbeParams, mass: float,
                heavy_target_kg: float | None = RetrievalParams().heavy_target_kg, scripted: bool = False) -> float:
    """The force (N) below which a probe contact is another object's (``Sensing.light_n``): ``light_contact_n``
    (with ``scripted``, ``light_scripted_n``: the scripted part's tracked points) for a target whose known
    ``mass`` (kg) is at least ``heavy_target_kg`` (the segment choice's, by default), else 0 (no contact is
    light)."""
    heavy = heavy_target_kg is not None and bool(mass >= heavy_target_kg)
    return float(params.light_scripted_n if scripted else params.light_contact_n) if heavy else 0.0


def set_limits(sensing: Sensing, params: ProbeParams, mass: float) -> None:
    """Tell ``sensing`` what the probes' contacts mean before it observes them: the light limit
    (:func:`light_limit` for a target of known ``mass``, kg) and, with ``params.push_through``, that a probe's
    light contacts after its first are a carried object's and the contact that stops the push may be that object
    pinned (``params.pinned_within``)."""
    sensing.light_n = light_limit(params, mass)
    sensing.pushes.on, sensing.pushes.within = params.push_through > 0, float(params.pinned_within)


def heavy_choices(segments: list[Segment], target: Primitive, sensing: Sensing, root_seed: int, run: str,
                  params: ProbeParams, mass: float, upto: int | None = None) -> list[TargetChoice]:
    """The scripted part's segments ranked as the target's (:func:`pipeline.probe.belief.choose_target`, on the
    gripper's positions up to action ``upto``, all by default), with the light rule on the scripted part too: for a
    heavy target of known ``mass`` (kg), a tracked point whose action met less than ``params.light_scripted_n``
    (N, :func:`light_limit`) is the clutter's, as a light probe contact is. Such points leave every segment (a
    segment left empty cannot be the target), so the set is fitted to the segment's heavy points only; every other
    segment's points, light ones too, stay the choice's ``others`` (the sensed obstacles), while the chosen
    segment's own light points are dropped (the heavy target meets a few light contacts too: as obstacles they
    turned its sets on the training seeds). The tracker's own segmentation is unchanged."""
    visited = sensing.visited if upto is None else sensing.visited[:upto + 1]
    steps, forces = np.array(sensing.steps), np.array(sensing.forces)
    rank = partial(choose_target, target=target, ee=visited, sdf=sensing.sdf, rngs=retrieval_rng(root_seed, run),
                   steps=steps, force=forces, mass=mass)
    limit = light_limit(params, mass, scripted=True)
    if not (limit > 0 and segments):
        return rank(segments)
    heavy, light = [], []
    for seg in segments:
        keep = ~(point_forces(seg.steps, steps, forces) < limit)  # (a point without a measured force is not light)
        light.append(np.asarray(seg.points, dtype=np.float64).reshape(-1, 2)[~keep])
        if keep.any():
            heavy.append(Segment(seg.id, np.asarray(seg.points)[keep], np.asarray(seg.steps)[keep]))
    ids = [seg.id for seg in segments]
    return [TargetChoice(c.segment, c.points, c.steps,
                         np.vstack([c.others] + [lt for i, lt in zip(ids, light) if i != c.segment]), c.seeds,
                         c.resisted) for c in rank(heavy)]


def no_target(segments: list[Segment], clear_of_others: bool = True) -> TargetChoice:
    """The choice of no segment (its set: :func:`pipeline.probe.belief.prior_set` in the region, then the fit to
    the probes' contacts): with ``clear_of_others`` every segment's points, light ones too, are other objects'
    contacts, so the target's hypotheses keep clear of them and the planned grasp takes them as obstacles
    (``ProbeParams.prior_clear_of_others``); without, it has no others."""
    points = [np.asarray(s.points, dtype=np.float64).reshape(-1, 2) for s in segments] if clear_of_others else []
    return dataclasses.replace(NO_TARGET, others=np.vstack(points) if points else NO_TARGET.others)


def misfit(target: Primitive, belief: PoseSet, points: np.ndarray) -> float:
    """Median distance (m) of points (P, 2) to the surface of the set's estimate (0 without points)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(points) == 0:
        return 0.0
    pp = primitive_pose(target, belief.poses[belief.best])
    sd, _ = primitive_sdf(target, rotate(points - pp[:2], pp[2], inverse=True))
    return float(np.median(np.abs(sd)))


def current_set(choice: TargetChoice, target: Primitive, sensing: Sensing, root_seed: int, run: str,
                log: ProbeLog, previous: PoseSet | None, params: ProbeParams) -> PoseSet:
    """The plausible set now. Probe contacts not yet attributed are attributed with the previous set (the one
    the probe was planned with): to another object if none of its hypotheses explains them within
    ``attribute_tolerance`` with its surface facing the contact's sensed force (``attribute_angle_deg``,
    ``attribute_corner``; :func:`pipeline.probe.belief.explaining`), to the target if all of them do, and if only
    some do, to the target only when the set fitted with it as the target's costs less than ``clutter_cost``
    more than the set fitted with it as another object's (docs/active.md, "Whose contact
    (attribution)"). Every contact is the target's while no set exists or the set is the no-segment prior, but
    a light one (:meth:`Sensing.is_light`, under :func:`light_limit`), which is always another object's; an action
    with one the previous set explained counts once in ``log.refuted``. The target's contacts' steps go to
    ``log.target_steps``."""
    done = len(log.target_steps) + len(log.other_steps)
    fitted: dict[tuple, PoseSet] = {}  # the sets of this call by target steps (a fit is deterministic)

    def fit(steps: list) -> PoseSet:
        key = tuple(steps)
        if key not in fitted:
            fitted[key] = set_from_steps(choice, target, sensing, root_seed, run, steps)
        return fitted[key]

    def costs_little(step: int) -> bool:
        # the set fitted with the contact as the target's against the set fitted with it as another object's
        return fit(log.target_steps + [step]).cost - fit(log.target_steps).cost < params.clutter_cost

    earlier = list(log.other_steps)
    refuting: set[int] = set()  # actions that refuted the set: the contacts of one action (two pads) count once
    for q, step, f, fn, pinned in zip(sensing.probe_points[done:], sensing.probe_steps[done:],
                                      sensing.probe_forces[done:], sensing.probe_force_n[done:],
                                      sensing.probe_pinned[done:]):
        mine = True
        if pinned:
            mine = False  # a carried object pressed against something heavy: not the target's surface
        elif previous is not None and previous.segment >= 0:
            hit = explaining(target, previous.poses, q, params.attribute_tolerance, f, params.attribute_angle_deg,
                             params.attribute_corner)
            mine = bool(hit.any())
            if mine and sensing.is_light(fn):
                # the set put the target where something gave way at a few newtons
                log.refuted += int(step) not in refuting
                refuting.add(int(step))
                mine = False
            elif mine and not hit.all():
                mine = costs_little(int(step))
        elif sensing.is_light(fn):
            mine = False
        (log.target_steps if mine else log.other_steps).append(int(step))
    if params.reattribute != "off" and previous is not None and previous.segment >= 0 and earlier:
        _reattribute(target, sensing, log, earlier, previous, costs_little, spare=not fitted, params=params)
    return fit(log.target_steps)


def _reattribute(target: Primitive, sensing: Sensing, log: ProbeLog, earlier: list, previous: PoseSet,
                 costs_little: Callable[[int], bool], spare: bool, params: ProbeParams) -> None:
    """Try again the probe contacts of ``earlier`` (steps attributed to another object at earlier decisions)
    against ``previous``: the first set may have been wrong, and a set fitted with a contact as another object's
    keeps its surface away from it. One that every hypothesis explains becomes the target's; the one nearest the
    estimate's surface among the others is tried by the cost rule of :func:`current_set` (``costs_little``; with
    ``explained`` only if some hypothesis explains it), if ``spare`` (no fit beyond the set's own was made for
    this decision's contacts): one fit more per decision at most, for a decision must stay under half a second."""
    at = {int(st): (q, f, fn) for q, st, f, fn, pinned in zip(sensing.probe_points, sensing.probe_steps,
                                                               sensing.probe_forces, sensing.probe_force_n,
                                                               sensing.probe_pinned) if not pinned}
    best = previous.poses[previous.best]
    ranked = sorted((st for st in earlier if st in at),  # a pinned carried object's contact is never tried again
                    key=lambda st: float(surface_distance(target, best, at[st][0])[0]))
    for step in ranked:
        q, f, fn = at[step]
        if sensing.is_light(fn):
            continue
        hit = explaining(target, previous.poses, q, params.attribute_tolerance, f, params.attribute_angle_deg,
                         params.attribute_corner)
        if not hit.all():
            if not spare or params.reattribute == "explained" and not hit.any():
                continue
            spare = False
            if not costs_little(step):
                continue
        log.other_steps.remove(step)
        log.target_steps.append(step)


def set_from_steps(choice: TargetChoice, target: Primitive, sensing: Sensing, root_seed: int, run: str,
                   target_steps) -> PoseSet:
    """:func:`pipeline.probe.belief.pose_set` with the probe contacts of ``target_steps`` on the target and the
    others elsewhere (the stream of the fit's random starts: the estimator's, :func:`retrieval_rng`) and the
    pushes' prior where it is about ``choice``'s segment (:func:`prior_for`)."""
    steps = np.asarray(sensing.probe_steps, dtype=np.int64)
    pts = np.asarray(sensing.probe_points, dtype=np.float64).reshape(-1, 2)
    on = np.isin(steps, np.asarray(list(target_steps), dtype=np.int64))
    return pose_set(choice, target, sensing.visited, np.asarray(sensing.steps), sensing.sdf,
                    retrieval_rng(root_seed, run)[2], pts[on], steps[on], pts[~on],
                    prior=prior_for(sensing, choice, target), region=getattr(sensing, "region", None))


def prior_for(sensing: Sensing, choice: TargetChoice, target: Primitive) -> Callable[[np.ndarray], np.ndarray] | None:
    """The pushes' prior cost (COM poses (B, 3) -> (B,)) for a set fitted to ``choice``: ``sensing.prior``'s when
    it tracked that segment, None otherwise (after a switch to another segment the prior is about another
    object)."""
    prior = sensing.prior
    return partial(prior.cost, target) if prior is not None and prior.segment == choice.segment else None


def mine_now(sensing: Sensing, log: ProbeLog) -> np.ndarray:
    """The probe contacts (P, 2) attributed to the target so far."""
    return probe_points_at(sensing, log.target_steps)


def probe_points_at(sensing: Sensing, steps) -> np.ndarray:
    """The probe contacts (P, 2) of the actions ``steps``, in the order they were sensed."""
    return np.asarray(sensing.probe_points, dtype=np.float64).reshape(-1, 2)[
        np.isin(np.asarray(sensing.probe_steps, dtype=np.int64), np.asarray(list(steps), dtype=np.int64))]


def set_share(target: Primitive, belief: PoseSet, plan: PlanParams) -> float:
    """Likelihood share of the set within the grasp's tolerances of its estimate (:func:`agreement`)."""
    return agreement(target, belief.poses, belief.weights, belief.best, plan.yaw_tolerance, plan.position_tolerance)


def _span(points: np.ndarray) -> float:
    """Largest distance (m) between two of the points (0 for fewer than two)."""
    if len(points) < 2:
        return 0.0
    return float(np.max(np.linalg.norm(points[:, None, :] - points[None, :, :], axis=-1)))


def bunched(points: np.ndarray, target: Primitive, params: ProbeParams) -> bool:
    """Whether the target's probe contacts (P, 2), two or more, span less than ``min_span`` of a box's long side
    (never for a can)."""
    return len(points) >= 2 and _span(points) < params.min_span * (
        2 * max(target.half[:2]) if target.kind == "box" else 0.0)


def give_way_at_budget(choices: list[TargetChoice], choice: TargetChoice, belief: PoseSet, target: Primitive,
                       sensing: Sensing, root_seed: int, run: str, target_steps, params: ProbeParams
                       ) -> tuple[TargetChoice, list, list, PoseSet] | None:
    """At the end of the budget, the next-ranked segment when the set of ``choice`` never agreed and its probe
    contacts stayed bunched (:func:`bunched`) although the probes were spread across the target's length: then
    they lie on another, smaller object (docs/active.md, "Which segment", says how
    well that state tells a wrong segment). ``belief`` is the set of ``choice`` with the
    probe contacts of ``target_steps`` (:func:`set_from_steps`). Returns (choice, target steps, other steps, set)
    of that segment with every probe contact attributed afresh against its set (:func:`current_set`), or None to
    keep ``choice``. A segment that resisted the pushes as a heavy target does (``choice.resisted``) never gives
    way: its probe contacts are bunched because the set they were attributed with had drifted, not because they
    lie on a smaller object (docs/active.md, "Which segment")."""
    if choice.segment < 0 or choice.resisted:
        return None
    rank = next((i for i, c in enumerate(choices) if c.segment == choice.segment), len(choices))
    if set_share(target, belief, params.plan) >= params.plan.agree_share or rank + 1 >= len(choices) or \
            not bunched(probe_points_at(sensing, target_steps), target, params):
        return None
    nxt = choices[rank + 1]
    fresh = ProbeLog()
    belief = current_set(nxt, target, sensing, root_seed, run, fresh,
                         set_from_steps(nxt, target, sensing, root_seed, run, []), params)
    return nxt, fresh.target_steps, fresh.other_steps, belief


def required_contacts(target: Primitive, params: ProbeParams) -> int:
    """Probe contacts on the target the set must rest on before it is trusted: ``min_target_contacts`` for a box,
    one fewer for a can (no yaw to pin)."""
    return params.min_target_contacts if target.kind == "box" else max(params.min_target_contacts - 1, 0)
