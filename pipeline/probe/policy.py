"""The probing policy of the active protocol: after the scripted rummage, probe with guarded moves until the
plausible set agrees on the target's pose or the budget is spent (docs/active.md).

Between probes the policy runs the pipeline on everything sensed so far (:mod:`pipeline.probe.belief`: isolation,
tracking, segmentation, the plausible estimator), plans the next guarded move (:mod:`pipeline.probe.planning`) and
executes it through the ``act`` callback of the collect stage, which simulates and records each action, so the
probe's contacts are real and in the run file. It never reads the simulation's ground truth: only each action's
detector verdict (``in_contact``, from the contact wrench as in the run's data) and the recorded rows.

A probe is one guarded move: retrace visited positions to the line's start, then advance along the line in steps
of ``coarse_step`` until ``slow_zone`` before the earliest predicted contact and of ``fine_step`` after, stop at
the first action detected in contact (or ``max_travel`` past the start, or ``overshoot`` past the latest predicted
contact) and back off by ``backoff``. A contact during the transit ends the probe the same way.
"""
from __future__ import annotations

import time
from functools import partial
from typing import Callable

import numpy as np
import pyarrow as pa

from pipeline.geometry import Primitive, primitive_of
from pipeline.probe.belief import (NO_TARGET, PoseSet, Sensing, TargetChoice, choose_target, explaining, misfit,
                                   pose_set, surface_distance)
from pipeline.probe.history import history_prior
from pipeline.probe.moves import BLOCK_RADIUS, Act, guarded_move, reaching, retrace, return_to_start, transit_limits
from pipeline.probe.params import ProbeLog, ProbeParams
from pipeline.probe.planning import PlanParams, ProbePlan, agreement, choose_probe, gripper_outline
from pipeline.probe.set_grasp import choose_grasp
from pipeline.probe.transit import grasp_transit
from pipeline.estimators.segment_choice import target_mass
from pipeline.estimators.run_info import retrieval_rng

__all__ = ["ProbeParams", "ProbeLog", "probe_run", "next_probe", "run_policy", "required_contacts",
           "give_way_at_budget", "bunched", "guarded_move", "retrace", "prior_for"]


def probe_run(act: Act, table: Callable[[], pa.Table], run: str, root_seed: int, target: Primitive,
              start: np.ndarray, params: ProbeParams = ProbeParams(),
              grasp_path: Callable[[PoseSet], Callable[[np.ndarray], np.ndarray]] | None = None,
              grasp_share: Callable[[PoseSet], float] | None = None, mass: float = float("nan"),
              scene=None) -> ProbeLog:
    """Probe until the plausible set agrees or the budget is spent.

    Parameters
    ----------
    act : callable (dx, dy) -> dict
        Simulates and records one action of the gripper (metres); returns its row of the ``sim_run`` table
        (``ee_x_m``, ``ee_y_m``, ``in_contact`` are read).
    table : callable () -> pyarrow.Table
        The run's ``sim_run`` table so far (scripted actions and the probes' own).
    run : str
        Run name; ``root_seed`` the root seed of the later stages (tracker and estimator streams).
    target : Primitive
        The target's known shape.
    start : ndarray, shape (2,)
        Gripper position before the run's first action.
    grasp_path : callable, optional
        The final set -> where the grasp chosen for it will move the gripper to its pre-grasp point from a start
        (2,) (positions (M, 2)): the return then ends where that move keeps clear of the target
        (:func:`pipeline.probe.moves.return_to_start`).
    grasp_share : callable, optional
        A set -> the likelihood share of it that the grasp chosen for it holds
        (:func:`pipeline.probe.set_grasp.choose_grasp`): the policy also stops once that share reaches
        ``agree_share``, for what the probes must settle is the grasp, not the pose.
    mass : float, kg
        The target's known mass: a heavy target's segment is the one that resisted the pushes
        (:func:`pipeline.probe.belief.choose_target`).
    scene : pipeline.scenes.Scene, optional
        The run's scene (its geometry, not its state); needed with ``params.history`` "pushtrack": the pushtrack
        estimator's set after the scripted part is then the prior of every set fitted to the segment it tracked
        (:mod:`pipeline.probe.history`).

    Returns
    -------
    ProbeLog
    """
    rows = table()
    sensing = Sensing(run, root_seed, start, rows.num_rows, method=params.method)
    sensing.observe(rows)
    seen = rows.num_rows
    log = ProbeLog()
    segments = sensing.segments()  # the scripted part's: the tracker is never fed the probes
    if params.history == "pushtrack":
        if scene is None:
            raise ValueError("the pushes' prior (ProbeParams.history 'pushtrack') needs the run's scene; pass "
                             "scene= or history='off'")
        t0 = time.perf_counter()
        sensing.prior = history_prior(rows, segments, scene, run, root_seed, sensing.sdf, params)
        log.prior_s = time.perf_counter() - t0
    t0 = time.perf_counter()  # the first decision includes the segment choice
    choices = choose_target(segments, target, sensing.visited, sensing.sdf, retrieval_rng(root_seed, run),
                            steps=np.array(sensing.steps), force=np.array(sensing.forces), mass=mass)
    rank = since = 0
    choice = choices[0] if choices else NO_TARGET
    outline = gripper_outline(sensing.sdf, params.plan.outline_resolution)
    need = required_contacts(target, params)
    belief = None
    limit, gave_way = params.budget, False  # the limit is raised once, when the segment gives way
    while True:
        if log.probes:
            t0 = time.perf_counter()
            rows = table()
            sensing.observe(rows.slice(seen))
            seen = rows.num_rows
        belief = current_set(choice, target, sensing, root_seed, run, log, belief, params)
        mine = mine_now(sensing, log)
        stalled = log.probes - since >= params.stall and set_share(target, belief, params.plan) < \
            params.plan.agree_share and rank + 1 < len(choices)
        if choice.segment >= 0 and (stalled or len(mine) >= 2 and misfit(target, belief, mine) >
                                    params.misfit_tolerance):
            # The probes' contacts do not lie on this segment's object, or they leave its set wide: take the
            # next-ranked segment (or none) and attribute every probe contact afresh against its set.
            since = log.probes
            rank += 1
            choice = choices[rank] if rank < len(choices) else NO_TARGET
            log.switches += 1
            log.target_steps, log.other_steps = [], []
            belief = current_set(choice, target, sensing, root_seed, run, log,
                                 set_from_steps(choice, target, sensing, root_seed, run, []), params)
        share = set_share(target, belief, params.plan)
        log.history.append({"rows": int(seen), "segment": int(choice.segment), "share": float(share),
                            "target_steps": list(log.target_steps)})
        held = grasp_share(belief) if grasp_share is not None else 0.0
        done, short = _stops(target, belief, sensing, log, need, max(share, held), params)
        log.history[-1].update(stop=bool(done), held=float(held))
        if not done and log.probes >= limit and not gave_way:
            given = give_way_at_budget(choices, choice, belief, target, sensing, root_seed, run, log.target_steps,
                                       params)
            if given is not None:
                # The budget is spent on another object: the segment taken gets probes of its own.
                choice, log.target_steps, log.other_steps, belief = given
                rank = next(i for i, c in enumerate(choices) if c.segment == choice.segment)
                since, gave_way = log.probes, True
                limit = log.probes + params.switch_probes
                log.switches += 1
                share = set_share(target, belief, params.plan)
                log.history[-1] = {"rows": int(seen), "segment": int(choice.segment), "share": float(share),
                                   "target_steps": list(log.target_steps)}
                held = grasp_share(belief) if grasp_share is not None else 0.0
                done, short = _stops(target, belief, sensing, log, need, max(share, held), params)
                log.history[-1].update(stop=bool(done), held=float(held))
        obstacles = np.vstack([choice.others, np.asarray([q for q, st in zip(sensing.probe_points, sensing.probe_steps)
                                                          if st in log.other_steps]).reshape(-1, 2)])
        plan = None if done or log.probes >= limit else next_probe(target, belief, sensing, outline, obstacles, log,
                                                                   short, params)
        log.decision_s.append(time.perf_counter() - t0)
        log.share, log.agreed, log.segment = share, share >= params.plan.agree_share, belief.segment
        if plan is None:
            if not done:
                log.flagged = "budget_spent" if log.probes >= limit else "no_reachable_probe"
            if log.probes:
                # Back through visited space to where the grasp's move to its pre-grasp point (straight lines) keeps
                # clear of the target, else where the scripted part ended: from the far side it would sweep it.
                log.actions += return_to_start(
                    act, sensing, params, transit_limits(sensing, target, belief, outline, params.plan, returning=True),
                    grasp_path=None if grasp_path is None else grasp_path(belief))
            return log
        here = sensing.visited[-1]
        here, n, contact = retrace(act, here, plan.path, params.transit_step, params.backoff)
        log.actions += n
        if contact:
            # An object (often the target, pushed where the gripper once passed) lies across the retraced path:
            # the positions there are not free any more, or every later transit would stop at the same point.
            sensing.block_near(here, BLOCK_RADIUS)
        else:  # a contact during the transit is this probe's outcome (the policy goes on)
            here, n, contact, _ = guarded_move(act, here, plan.direction, plan.predicted, params)
            log.actions += n
        log.probes += 1
        log.contacts.append(bool(contact))
        log.lines.append([*map(float, plan.start), *map(float, plan.direction),
                          *_quantiles(plan.predicted, belief.weights), plan.mode == "spread"])


def next_probe(target: Primitive, belief: PoseSet, sensing: Sensing, outline: np.ndarray, obstacles: np.ndarray,
               log: ProbeLog, short: bool, params: ProbeParams) -> ProbePlan | None:
    """The next guarded move (:func:`pipeline.probe.planning.choose_probe`; None: none can be reached), planned
    under the strictest transit limit that reaches some visited position (:func:`pipeline.probe.moves.reaching`)
    and, where that one leaves no probe, under each laxer one in turn: a gripper walled in by the keep-out
    around a wrong estimate would otherwise stop probing with the set still wide (docs/active.md, "The return and the
    grasp's move"). When none leaves a probe, once more with no keep-out and only the positions a
    probe reached in contact left out, not those ``blocked`` near a transit's contact (docs/active.md, "The return and
    the grasp's move"). With ``short`` (the target's probe contacts are bunched) after a probe that was
    not a spread probe, the line is the one whose contact lies farthest from them."""
    lines = np.asarray([ln[:4] for ln in log.lines], dtype=np.float64).reshape(-1, 4)
    spread = mine_now(sensing, log) if short and log.lines and not log.lines[-1][-1] else None
    limits = reaching(sensing, transit_limits(sensing, target, belief, outline, params.plan), params.plan.link_radius)
    if any(sensing.blocked):
        # Last resort: the positions near a transit's contact were left out on suspicion (the object met may lie
        # across some of them only); a gripper walled in by them would stop probing with the set still wide.
        limits.append((np.asarray(sensing.touching, dtype=bool), None, None))
    for touching, keepout, graph in limits:
        plan = choose_probe(target, belief.poses, belief.weights, belief.best, sensing.visited, outline, params.plan,
                            obstacles, lines, spread, touching=touching, keepout=keepout, graph=graph)
        if plan is not None:
            return plan
    return None


def _stops(target: Primitive, belief: PoseSet, sensing: Sensing, log: ProbeLog, need: int, share: float,
           params: ProbeParams) -> tuple[bool, bool]:
    """(whether the policy stops, whether the target's probe contacts are bunched): it stops once ``share`` (the
    set's agreement, or the share of it one grasp holds) reaches ``agree_share`` on enough target contacts
    (``min_probes`` made) that span the box (:func:`bunched`)."""
    settled = share >= params.plan.agree_share and log.probes >= params.min_probes and \
        len(log.target_steps) >= min(need, params.budget)
    # Contacts bunched on a short stretch may all be on another, smaller object: probe across the length.
    short = bunched(mine_now(sensing, log), target, params)
    return settled and not short, short


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
    they lie on another, smaller object (docs/active.md, "Which segment", says how well that state tells a wrong
    segment). ``belief`` is the set of ``choice`` with the
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


def current_set(choice: TargetChoice, target: Primitive, sensing: Sensing, root_seed: int, run: str,
                log: ProbeLog, previous: PoseSet | None, params: ProbeParams) -> PoseSet:
    """The plausible set now. Probe contacts not yet attributed are attributed with the previous set (the one
    the probe was planned with): to another object if none of its hypotheses explains them within
    ``attribute_tolerance`` with its surface facing the contact's sensed force (``attribute_angle_deg``,
    ``attribute_corner``; :func:`pipeline.probe.belief.explaining`), to the target if all of them do, and if only
    some do, to the target only when the set fitted with it as the target's costs less than ``clutter_cost``
    more than the set fitted with it as another object's (docs/active.md, "Whose contact (attribution)"). Every contact
    is the target's while no set exists or the set is the no-segment prior.
    The target's contacts' steps go to ``log.target_steps``."""
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
    for q, step, f in zip(sensing.probe_points[done:], sensing.probe_steps[done:], sensing.probe_forces[done:]):
        mine = True
        if previous is not None and previous.segment >= 0:
            hit = explaining(target, previous.poses, q, params.attribute_tolerance, f, params.attribute_angle_deg,
                             params.attribute_corner)
            mine = bool(hit.any())
            if mine and not hit.all():
                mine = costs_little(int(step))
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
    at = {int(st): (q, f) for q, st, f in zip(sensing.probe_points, sensing.probe_steps, sensing.probe_forces)}
    best = previous.poses[previous.best]
    ranked = sorted(earlier, key=lambda st: float(surface_distance(target, best, at[st][0])[0]))
    for step in ranked:
        q, f = at[step]
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
                    prior=prior_for(sensing, choice, target))


def prior_for(sensing: Sensing, choice: TargetChoice, target: Primitive) -> Callable[[np.ndarray], np.ndarray] | None:
    """The pushes' prior cost (COM poses (B, 3) -> (B,)) for a set fitted to ``choice``: ``sensing.prior``'s when
    it tracked that segment, None otherwise (after a switch to another segment the prior is about another
    object)."""
    prior = sensing.prior
    return partial(prior.cost, target) if prior is not None and prior.segment == choice.segment else None


def _quantiles(t: np.ndarray, w: np.ndarray) -> list[float]:
    """Weighted 10, 50 and 90 % quantiles of predicted travels (None: no contact)."""
    order = np.argsort(t)
    c = np.cumsum(w[order]) / np.sum(w)
    q = [t[order][min(np.searchsorted(c, x), len(t) - 1)] for x in (0.1, 0.5, 0.9)]
    return [float(v) if np.isfinite(v) else None for v in q]



def run_policy(world, scene, seed: int, root_seed: int, rows: list, summarize: Callable, table: Callable,
               params: ProbeParams | None = None) -> tuple[dict, list]:
    """The collect stage's hook: probe in ``world`` after the scripted actions of ``rows``.

    Each probe action is simulated by ``world.act`` (no replay noise), summarised by ``summarize`` (the collect
    stage's :func:`pipeline.collect.summarize_action`) and appended to ``rows`` with the columns the scripted
    actions have; ``table()`` builds the run's table from ``rows``. Returns what the run file's metadata records
    under ``probe`` (the parameters and the :class:`ProbeLog` but its wall times) and those wall times
    (``decision_s``: a list; ``prior_s``; seconds).
    """
    params = params if params is not None else ProbeParams()
    scale = scene.action_scale

    def act(dx: float, dy: float) -> dict:
        row = summarize(world.act(dx, dy))
        # object poses and distances are recorded for scoring only; the policy never reads them
        row.update(cmd_ux=dx / scale, cmd_uy=dy / scale, cmd_dx_m=dx, cmd_dy_m=dy, obj_pose=world.object_poses(),
                   obj_distance_m=world.object_distances())
        rows.append(row)
        return row

    tid = next(i for i, o in enumerate(scene.objects) if o.target)
    start = np.array([rows[0]["ee_start_x_m"], rows[0]["ee_start_y_m"]])
    prim = primitive_of(scene.objects[tid])

    def grasp_path(belief: PoseSet) -> Callable[[np.ndarray], np.ndarray]:
        pre = choose_grasp(scene, prim, belief.poses, belief.weights, belief.best).pregrasp
        return lambda at: grasp_transit(at, pre, scale)

    def grasp_share(belief: PoseSet) -> float:
        return choose_grasp(scene, prim, belief.poses, belief.weights, belief.best).share

    log = probe_run(act, table, f"{scene.name}/{seed}", root_seed, prim, start, params, grasp_path, grasp_share,
                    mass=target_mass(scene), scene=scene)
    meta = {"params": params.to_dict(), **log.to_dict()}
    for wall in ("decision_s", "prior_s"):
        meta.pop(wall)  # wall times would make the run file differ between identical runs
    return meta, {"decision_s": log.decision_s, "prior_s": log.prior_s}
