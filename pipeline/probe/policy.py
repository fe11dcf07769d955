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
from collections.abc import Callable

import numpy as np
import pyarrow as pa

from pipeline.detection import window_force
from pipeline.estimators.segment_choice import target_mass
from pipeline.geometry import Primitive, primitive_of
from pipeline.probe.attribution import (
    bunched,
    current_set,
    give_way_at_budget,
    heavy_choices,
    mine_now,
    misfit,
    no_target,
    prior_for,
    required_contacts,
    set_from_steps,
    set_limits,
    set_share,
)
from pipeline.probe.belief import PoseSet, Sensing
from pipeline.probe.history import history_prior
from pipeline.probe.moves import BLOCK_RADIUS, Act, guarded_move, reaching, retrace, return_to_start, transit_limits
from pipeline.probe.params import ProbeLog, ProbeParams
from pipeline.probe.planning import ProbePlan, choose_probe, gripper_outline
from pipeline.probe.set_grasp import choose_grasp
from pipeline.probe.transit import grasp_transit

__all__ = ["ProbeParams", "ProbeLog", "probe_run", "next_probe", "run_policy", "recorder", "run_record",
           "required_contacts", "give_way_at_budget", "bunched", "guarded_move", "retrace", "prior_for"]


def probe_run(act: Act, table: Callable[[], pa.Table], run: str, root_seed: int, target: Primitive,
              start: np.ndarray, params: ProbeParams = ProbeParams(),
              grasp_path: Callable[[PoseSet], Callable[[np.ndarray], np.ndarray]] | None = None,
              grasp_share: Callable[[PoseSet], float] | None = None, mass: float = float("nan"),
              scene=None, action_limit: int | None = None) -> ProbeLog:
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
        (:mod:`pipeline.probe.history`). Its target region (:func:`pipeline.scenes.declared_region`) is where
        the no-segment prior puts its hypotheses.
    action_limit : int, optional
        Most actions of the probes (transits, steps, back-offs), checked before each probe (a probe under way
        ends; the return after the last probe is not counted): an explorer's action budget
        (:mod:`pipeline.probe.explore`). None: only ``params.budget`` probes limit them.

    Returns
    -------
    ProbeLog
    """
    rows = table()
    sensing = Sensing(run, root_seed, start, rows.num_rows, method=params.method, scene=scene)
    set_limits(sensing, params, mass)
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
    choices = heavy_choices(segments, target, sensing, root_seed, run, params, mass)
    rank = since = 0
    none = no_target(segments, params.prior_clear_of_others)
    choice = choices[0] if choices else none
    outline = gripper_outline(sensing.sdf, params.plan.outline_resolution)

    def light(row: dict) -> bool:  # what the recorded row will say of the action's force (Sensing.observe)
        return sensing.is_light(window_force(row["win_wrench"], sensing.detection))

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
        refuted = params.light_refutations > 0 and log.refuted >= params.light_refutations
        # Every probe sent to the set's object met another object: the set has nothing of the probes on it.
        unsupported = 0 < params.unsupported <= log.probes - since and not log.target_steps
        if choice.segment >= 0 and (stalled or refuted or unsupported or
                                    len(mine) >= 2 and misfit(target, belief, mine) > params.misfit_tolerance):
            # The probes' contacts do not lie on this segment's object, or none does, or they leave its set wide,
            # or what the set took for the target gave way at a few newtons: take the next-ranked segment (or none) and
            # attribute every probe contact afresh against its set.
            since = log.probes
            rank += 1
            choice = choices[rank] if rank < len(choices) else none
            log.switches += 1
            log.target_steps, log.other_steps = [], []
            belief = current_set(choice, target, sensing, root_seed, run, log,
                                 set_from_steps(choice, target, sensing, root_seed, run, []), params)
            log.refuted = 0  # the new segment is judged by the contacts sensed from now on
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
                since, gave_way, log.refuted = log.probes, True, 0
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
        spent = log.probes >= limit or action_limit is not None and log.actions >= action_limit
        plan = None if done or spent else next_probe(target, belief, sensing, outline, obstacles, log, short,
                                                     params)
        log.decision_s.append(time.perf_counter() - t0)
        log.share, log.agreed, log.segment = share, share >= params.plan.agree_share, belief.segment
        if plan is None:
            if not done:
                log.flagged = "budget_spent" if spent else "no_reachable_probe"
            if log.probes:
                # Back through visited space to where the grasp's move to its pre-grasp point (straight lines) keeps
                # clear of the target, else where the scripted part ended: from the far side it would sweep it.
                log.actions += return_to_start(
                    act, sensing, params, transit_limits(sensing, target, belief, outline, params.plan, returning=True),
                    grasp_path=None if grasp_path is None else grasp_path(belief))
            return log
        here = sensing.visited[-1]
        here, n, contact = retrace(act, here, plan.path, params.transit_step, params.backoff, light,
                                   params.push_through)
        log.actions += n
        if contact:
            # An object (often the target, pushed where the gripper once passed) lies across the retraced path:
            # the positions there are not free any more, or every later transit would stop at the same point.
            sensing.block_near(here, BLOCK_RADIUS)
        else:  # a contact during the transit is this probe's outcome (the policy goes on)
            here, n, contact, _ = guarded_move(act, here, plan.direction, plan.predicted, params, light)
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


def _quantiles(t: np.ndarray, w: np.ndarray) -> list[float]:
    """Weighted 10, 50 and 90 % quantiles of predicted travels (None: no contact)."""
    order = np.argsort(t)
    c = np.cumsum(w[order]) / np.sum(w)
    q = [t[order][min(np.searchsorted(c, x), len(t) - 1)] for x in (0.1, 0.5, 0.9)]
    return [float(v) if np.isfinite(v) else None for v in q]


def recorder(world, scale: float, rows: list, summarize: Callable) -> Act:
    """The ``act`` callback of a policy acting in ``world``: simulates one action (dx, dy), metres, appends its row
    (:func:`pipeline.collect.summarize_action`'s ``summarize``, plus the commanded action with ``scale`` metres per
    unit and the objects' poses and distances) to ``rows`` and returns it."""

    def act(dx: float, dy: float) -> dict:
        row = summarize(world.act(dx, dy))
        # object poses and distances are recorded for scoring only; the policy never reads them
        row.update(cmd_ux=dx / scale, cmd_uy=dy / scale, cmd_dx_m=dx, cmd_dy_m=dy, obj_pose=world.object_poses(),
                   obj_distance_m=world.object_distances())
        rows.append(row)
        return row

    return act


def run_policy(world, scene, seed: int, root_seed: int, rows: list, summarize: Callable, table: Callable,
               params: ProbeParams | None = None, action_limit: int | None = None) -> tuple[dict, list]:
    """The collect stage's hook: probe in ``world`` after the scripted actions of ``rows``.

    Each probe action is simulated by ``world.act`` (no replay noise), summarised by ``summarize`` (the collect
    stage's :func:`pipeline.collect.summarize_action`) and appended to ``rows`` with the columns the scripted
    actions have; ``table()`` builds the run's table from ``rows``; ``action_limit`` is :func:`probe_run`'s.
    Returns what the run file's metadata records under ``probe`` (the parameters and the :class:`ProbeLog` but its
    wall times) and those wall times (``decision_s``: a list; ``prior_s``; seconds).
    """
    params = params if params is not None else ProbeParams()
    scale = scene.action_scale
    act = recorder(world, scale, rows, summarize)
    tid = next(i for i, o in enumerate(scene.objects) if o.target)
    start = np.array([rows[0]["ee_start_x_m"], rows[0]["ee_start_y_m"]])
    prim = primitive_of(scene.objects[tid])

    def grasp_path(belief: PoseSet) -> Callable[[np.ndarray], np.ndarray]:
        pre = choose_grasp(scene, prim, belief.poses, belief.weights, belief.best).pregrasp
        return lambda at: grasp_transit(at, pre, scale)

    def grasp_share(belief: PoseSet) -> float:
        return choose_grasp(scene, prim, belief.poses, belief.weights, belief.best).share

    log = probe_run(act, table, f"{scene.name}/{seed}", root_seed, prim, start, params, grasp_path, grasp_share,
                    mass=target_mass(scene), scene=scene, action_limit=action_limit)
    return run_record(params, log), {"decision_s": log.decision_s, "prior_s": log.prior_s}


def run_record(params: ProbeParams, log: ProbeLog) -> dict:
    """What a run file's metadata records under ``probe``: the parameters and the :class:`ProbeLog` but its wall
    times, which would make the run file differ between identical runs."""
    meta = {"params": params.to_dict(), **log.to_dict()}
    for wall in ("decision_s", "prior_s"):
        meta.pop(wall)
    return meta
