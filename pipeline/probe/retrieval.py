"""The active protocol's retrieval of one run file: the policy's last belief recomputed from the file, the grasp
for the set, simulated (docs/active.md).

The belief depends only on the run's recorded actions and on which probe contacts the policy attributed to the
target (the run's metadata, ``probe.target_steps``), so this is the set the policy stopped on.
"""
from __future__ import annotations

import hashlib
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pyarrow as pa

from pipeline import schema
from pipeline.estimators.estimate import Segment
from pipeline.estimators.run_info import RunInfo
from pipeline.estimators.segment_choice import target_mass
from pipeline.estimators.target_model import pose_error
from pipeline.grasp import GraspParams
from pipeline.grasp_judge import GRASP_STEP_M
from pipeline.probe.attribution import (
    current_set,
    give_way_at_budget,
    heavy_choices,
    no_target,
    set_from_steps,
    set_limits,
    set_share,
)
from pipeline.probe.belief import PoseSet, Sensing, TargetChoice
from pipeline.probe.grasp_attempts import NO_REACHABLE_GRASP, Attempts, attempt_grasps
from pipeline.probe.grasp_plan import PlannedGrasp, PlanningParams, Surroundings, plan_grasp
from pipeline.probe.history import HistoryPrior, history_prior
from pipeline.probe.params import ProbeLog, ProbeParams
from pipeline.probe.planning import PlanParams, gripper_outline

__all__ = ["ActiveResult", "ActiveState", "active_set", "active_state", "active_grasp", "active_row",
           "recorded_prior"]


@dataclass
class ActiveResult:
    """The active protocol's outcome for one run.

    Attributes
    ----------
    pose : ndarray, shape (3,)
        The set's estimate (COM pose, canonical under the target's symmetry).
    belief : PoseSet
    grasp : PlannedGrasp
        The first attempt's grasp (the plan when not simulated).
    result : Attempts or None
        The simulated attempts (None when not simulated).
    probes : int
        Probes the policy made (0 for a run without probes).
    notes : list of str
        ``wide_set`` when the set does not agree and no grasp holds ``agree_share`` of it (the grasp went ahead
        anyway), ``no_segment``, ``no_reachable_grasp`` when no planned grasp could be reached.
    """

    pose: np.ndarray
    belief: PoseSet
    grasp: PlannedGrasp
    result: Attempts | None
    probes: int
    notes: list


def _probe_meta(info: RunInfo) -> dict:
    """The run's probe log, checked against its rows (:func:`pipeline.schema.probe_record`); {} without one."""
    return schema.probe_record(info.path)


class ActiveState(NamedTuple):
    """What the active protocol holds when it grasps (:func:`active_state`).

    Attributes
    ----------
    belief : PoseSet
        The plausible set.
    meta : dict
        The run's ``probe`` metadata ({} if it has none).
    around : Surroundings
        What the robot sensed around the target (:func:`surroundings_of`).
    next_set : callable
        ``next_set(k)``: (set, surroundings) of the ``k``-th segment ranked after the set's (k >= 1), its probe
        contacts attributed afresh against it, or None when there is no such segment; the grasp's attempts turn
        to it when a grasp the set was sure of finds no target (:func:`pipeline.probe.grasp_attempts.attempt_grasps`).
    """

    belief: PoseSet
    meta: dict
    around: Surroundings
    next_set: Callable[[int], tuple[PoseSet, Surroundings] | None]


def active_set(info: RunInfo, root_seed: int, method: str = "stucco", decision: int | None = None,
               budget_end: ProbeParams | None = None) -> tuple[PoseSet, dict]:
    """The policy's last plausible set and the run's ``probe`` metadata (:func:`active_state`)."""
    state = active_state(info, root_seed, method, decision, budget_end)
    return state.belief, state.meta


def _recorded_params(recorded: dict) -> ProbeParams:
    """The probing policy's parameters a run recorded (its ``probe.params``: the scalar ones; the defaults for the
    rest, and for a key a run file written before it existed, but the light-contact rules and the no-segment prior's
    others: off for such a run)."""
    names = [f.name for f in fields(ProbeParams) if f.name != "plan"]
    # a run probed before light contacts were told apart (the probes', then the scripted part's) was probed without
    # (and before the no-segment prior kept clear of the other segments)
    before = {"light_contact_n": 0.0, "light_refutations": 0, "light_scripted_n": 0.0,
              "prior_clear_of_others": False} if recorded else {}
    return ProbeParams(**{**before, **{k: recorded[k] for k in names if k in recorded}})


def active_state(info: RunInfo, root_seed: int, method: str = "stucco", decision: int | None = None,
                 budget_end: ProbeParams | None = None) -> ActiveState:
    """The policy's last plausible set for a run file, or the one of its ``decision``-th decision (0: after the
    scripted part, before any probe), and the run's ``probe`` metadata ({} if it has none).

    With ``budget_end`` (the policy's parameters), the ``decision``-th decision is where a policy with that
    budget stops: the segment gives way there as the policy's would (:func:`give_way_at_budget`).

    With a tracking method other than the policy's, the segments are that method's and the probes' contacts
    are attributed as the policy attributed them, to the best-ranked segment.

    Also returns what the robot sensed around the target then (:func:`surroundings_of`), for the planned grasp, and
    the sets of the segments ranked after the one taken (:class:`ActiveState`)."""
    table = schema.read_run(info.path)
    meta = _probe_meta(info)
    n_scripted = table.num_rows
    if "probe" in table.column_names:
        flags = np.asarray(table.column("probe").to_numpy(zero_copy_only=False), dtype=bool)
        n_scripted = int(np.argmax(flags)) if flags.any() else table.num_rows
    history = meta.get("history") or []
    state = history[min(decision, len(history) - 1)] if decision is not None and history else \
        {"rows": table.num_rows, "segment": meta.get("segment"), "target_steps": meta.get("target_steps", [])}
    params = _recorded_params(meta.get("params") or {})
    sensing = Sensing(info.run, root_seed, info.ee[0], n_scripted, method=method, scene=info.scene)
    set_limits(sensing, params, target_mass(info.scene))
    sensing.observe(table.slice(0, int(state["rows"])))
    segments = sensing.segments()  # the scripted part's: the tracker is never fed the probes
    sensing.prior = recorded_prior(info, table.slice(0, n_scripted), segments, sensing.sdf, root_seed, method,
                                   (meta.get("params") or {}))
    choices = heavy_choices(segments, info.target, sensing, root_seed, info.run, params, target_mass(info.scene),
                            upto=n_scripted)
    same = method == (meta.get("params") or {}).get("method", "stucco") and state["segment"] is not None
    segment = int(state["segment"]) if same else (choices[0].segment if choices else -1)
    choice = next((c for c in choices if c.segment == segment), no_target(segments, params.prior_clear_of_others))
    belief = set_from_steps(choice, info.target, sensing, root_seed, info.run, state["target_steps"])
    steps = state["target_steps"]
    if budget_end is not None and decision is not None:
        given = give_way_at_budget(choices, choice, belief, info.target, sensing, root_seed, info.run,
                                   state["target_steps"], budget_end)
        if given is not None:
            choice, steps, belief = given[0], given[1], given[3]
    # none after a set of no segment, or of one the ranking does not hold (the policy moved past its last one)
    rank = next((i for i, c in enumerate(choices) if c.segment == choice.segment), len(choices))
    later = choices[rank + 1:] if choice.segment >= 0 else []

    def next_set(k: int) -> tuple[PoseSet, Surroundings] | None:
        if not 1 <= k <= len(later):
            return None
        nxt, fresh = later[k - 1], ProbeLog()
        found = current_set(nxt, info.target, sensing, root_seed, info.run, fresh,
                            set_from_steps(nxt, info.target, sensing, root_seed, info.run, []), params)
        return found, surroundings_of(sensing, nxt, fresh.target_steps, info.scene)

    return ActiveState(belief, meta, surroundings_of(sensing, choice, steps, info.scene), next_set)


def surroundings_of(sensing: Sensing, choice: TargetChoice, target_steps, scene) -> Surroundings:
    """What the robot sensed around the target (:class:`pipeline.probe.grasp_plan.Surroundings`): its trail, the
    other segments' points and the probes' contacts not attributed to the target as obstacles, the scene's static
    walls; the gripper's outline for transit."""
    probes = [pt for pt, st in zip(sensing.probe_points, sensing.probe_steps) if st not in set(target_steps)]
    obstacles = np.vstack([np.asarray(choice.others, dtype=np.float64).reshape(-1, 2),
                           np.asarray(probes, dtype=np.float64).reshape(-1, 2)])
    walls = [(np.asarray(w.position, dtype=np.float64), np.asarray(w.size[:2], dtype=np.float64) / 2, float(w.yaw))
             for w in scene.walls]
    visited = sensing.visited
    return Surroundings(visited[-1].copy(), visited, obstacles, walls, gripper_outline(sensing.sdf))


#: (key, prior) of the last :func:`recorded_prior` in this process (``stucco bench probe`` asks again per decision).
_LAST_PRIOR: list = []


def recorded_prior(info: RunInfo, scripted: pa.Table, segments: Sequence[Segment], sdf, root_seed: int,
                   method: str, recorded: dict) -> HistoryPrior | None:
    """The prior the policy put on its sets (:mod:`pipeline.probe.history`), recomputed from the run's scripted
    rows ``scripted`` and the tracker's ``segments`` of them (robot ``sdf``), as the run's recorded probe
    parameters ``recorded`` say (``history``; none for a run file written before the policy had one). With the
    policy's tracking method it is the policy's prior, bit for bit; with another method (``method``, a baseline
    through the same policy) it is the prior that method's own segments give, as for the rest of its set."""
    if recorded.get("history", "off") != "pushtrack":
        return None
    params = _recorded_params(recorded)  # (the prior reads its history_* fields)
    digest = hashlib.sha256(Path(info.path).read_bytes()).digest() if info.path is not None else None
    key = (str(info.path), digest, scripted.num_rows, method, root_seed, params)
    if not (_LAST_PRIOR and _LAST_PRIOR[0][0] == key):
        found = history_prior(scripted, segments, info.scene, info.run, root_seed, sdf, params)
        _LAST_PRIOR[:] = [(key, found)]
    return _LAST_PRIOR[0][1]


def active_grasp(info: RunInfo, root_seed: int, grasp: bool = True, params: GraspParams = GraspParams(),
                 method: str = "stucco", plan: PlanParams = PlanParams(),
                 planning: PlanningParams = PlanningParams()) -> ActiveResult:
    """The set of :func:`active_set`, the grasp planned for it as sensed (:func:`plan_grasp`) and, with
    ``grasp``, its attempts in the run's final state, re-planned after each felt miss (:func:`attempt_grasps`)."""
    belief, meta, around, next_set = active_state(info, root_seed, method)
    if grasp:
        attempts = attempt_grasps(info.scene, info.final_poses, info.final_ee, info.target, belief.poses,
                                  belief.weights, belief.best, around, planning, params, next_set=next_set,
                                  tilted=info.final_tilted)
        g = attempts.attempts[0].grasp
    else:
        attempts = None
        g = plan_grasp(info.target, GRASP_STEP_M, belief.poses, belief.weights, belief.best, around,
                       planning, params)
    wide = set_share(info.target, belief, plan) < plan.agree_share and g.share < plan.agree_share
    notes = list(belief.notes) + (["wide_set"] if wide else []) + ([] if g.reachable else [NO_REACHABLE_GRASP])
    return ActiveResult(pose=info.target.canonical(belief.poses[belief.best]), belief=belief, grasp=g,
                        result=attempts, probes=int(meta.get("probes", 0)), notes=notes)


#: (key, row) of the last :func:`active_row` in this process.
_LAST_ROW: list = []


def active_row(info: RunInfo, method: str, root_seed: int, grasp: bool, params: GraspParams) -> dict:
    """The retrieval-table fields the active protocol sets for one run (the ``active`` hook of
    :func:`pipeline.retrieve.stage.retrieve`): the set's estimate and its errors, the set grasp's outcome, and in
    ``notes`` ``probes=N`` plus ``wide_set`` / ``no_segment`` (then ``low_confidence``).

    The same for every pose estimator of a job, so computed once per process for the same run file (by its
    bytes), method, seed and grasp parameters; a repeat's ``grasp_s`` is the time of the look-up."""
    t0 = time.perf_counter()
    key = (str(info.path), hashlib.sha256(Path(info.path).read_bytes()).digest(), method, root_seed, grasp, params)
    if _LAST_ROW and _LAST_ROW[0][0] == key:
        row = dict(_LAST_ROW[0][1])
        if row.get("grasp_s") is not None:
            row["grasp_s"] = time.perf_counter() - t0
        return row
    row = _active_row(info, method, root_seed, grasp, params)
    _LAST_ROW[:] = [(key, dict(row))]
    return row


def _active_row(info: RunInfo, method: str, root_seed: int, grasp: bool, params: GraspParams) -> dict:
    r = active_grasp(info, root_seed, grasp, params, method)
    pos_err, yaw_err = pose_error(info.target, r.pose, info.true_pose)
    row = dict(x_m=float(r.pose[0]), y_m=float(r.pose[1]), yaw_rad=float(r.pose[2]), position_error_m=pos_err,
               yaw_error_rad=yaw_err, notes=",".join([f"probes={r.probes}", *r.notes]), low_confidence=bool(r.notes))
    if r.result is not None:
        # Table II's column is the first attempt; the attempts and their final outcome beside it.
        row.update(grasp_success=r.result.first_success, grasp_outcome=r.result.outcome, grasp_s=r.result.wall_s,
                   grasp_attempts=len(r.result.attempts), grasp_success_any=r.result.success)
    return row
