"""Where grasps are lost: a ladder of grasp success from the true pose down to the tracker's points (``stucco bench
retrieval``).

For every run of an evaluation directory and every pose estimator, the simulated grasp (:mod:`pipeline.grasp`,
unchanged) is tried at poses that lose one piece of knowledge per rung:

1. ``true_pose``: the target's true final pose;
2. ``yaw+0.05`` ... ``pos-2cm_along``: the true pose turned by ±0.05, ±0.10, ±0.15 rad about the primitive's
   centre, or shifted by 1 or 2 cm in each of the four directions along (+x, -x) and across (+y, -y) the target's
   long axis, one rung each (the grasp's tolerance);
3. ``ideal_true_segment``: the estimator on ideal contact points of the target alone (the segment is known);
4. ``ideal_our_choice``: the estimator on ideal contact points of every body, one segment per body (it chooses);
5. ``tracker_our_choice``: the estimator on the tracker's final segments, as ``stucco evaluate`` runs it;
6. for an estimator with a ``motion`` parameter (pushtrack, docs/estimators.md): ``ideal_true_segment_static``,
   ``..._translate``, ``..._push``, ``tracker_our_choice_static``, ``..._translate``, ``..._push``: rungs 3 and 5
   again with the target held still between contacts (only the filter's noise), moved by the pusher without
   turning (the tracker's assumption), or pushed by the point pusher (the pushing model before the tipped box,
   here with the filter's default noise, not the 0.3 / 3.0 it had then) instead of the
   estimator's own pushing model.

The ideal segments also carry each contact where it was observed, at its own step (``Segment.observed``): the
estimators that read contacts at their own steps (pushtrack) get those, the others the contacts where they lie now.

An estimator that runs at every in-contact step (``paper``) gets the tracker's segments after each in-contact step
on the last rung, and on the ideal rungs the ideal points observed up to each step at their final positions
(:func:`~pipeline.estimators.estimate.history_from_final`: the ideal points do not move).

Ideal contact points are the run's recorded true contact of every action with a known body, carried with that
body from its pose after the action to its final pose: exactly where each contact lies now. The point is the
last one of the action's 8-step window that touches a body (``win_true_object``), and its body the one touched
there: the contact the isolation reports is the window's, whatever body the action's label names (12 of the 105
labelled actions of the four runs in ``data/regression`` end their window on another body than their label's,
among them IB's push of the box at action 12). An
action whose window touches nothing falls back to its last true contact (``true_contact_x_m``) and its label.
A lost grasp is
put down to ``wrong_segment`` (the estimate is more than 10 cm off, or its segment holds mostly other bodies'
points), ``yaw`` (more than ``YAW_TOL``), ``position`` (more than ``POSITION_TOL``) or, with a good pose,
``grasp_rule``.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from pipeline import registry, schema
from pipeline.estimators.estimate import Segment, estimate, history_from_final, needs_every_step
from pipeline.estimators.run_info import RunInfo, check_runs, load_run, retrieval_rng
from pipeline.estimators.target_model import pose_error
from pipeline.geometry import rotate
from pipeline.grasp import GraspParams, grasp_at
from pipeline.layout import partition
from pipeline.parallel import run_calls, single_threaded
from pipeline.retrieve.stage import contact_step_segments, tracking_robot
from pipeline.robot import load_robot
from pipeline.safe_open import regular_file
from pipeline.seeds import check_root_seed
from pipeline.segment import final_estimates

__all__ = ["PERTURBATIONS", "RUNGS", "MOTION_RUNGS", "LadderRow", "ideal_segments", "perturbed", "loss_reason",
           "run_ladder", "ladder_rows"]

#: (rung, yaw offset rad, offset along the long axis m, offset across m) of the perturbed true pose.
PERTURBATIONS = tuple((f"yaw{d:+.2f}", d, 0.0, 0.0) for a in (0.05, 0.10, 0.15) for d in (a, -a)) + tuple(
    (f"pos{sign}{cm}cm_{axis}", 0.0, s * cm / 100 if axis == "along" else 0.0,
     s * cm / 100 if axis == "across" else 0.0)
    for cm in (1, 2) for axis in ("along", "across") for sign, s in (("+", 1.0), ("-", -1.0)))
ESTIMATOR_RUNGS = ("ideal_true_segment", "ideal_our_choice", "tracker_our_choice")
#: (rung, the estimator rung it repeats, motion model) of an estimator with a ``motion`` parameter (pushtrack):
#: the same contacts without the pushing model or with the point pusher, so the ladder shows what the model adds.
MOTION_RUNGS = tuple((f"{base}_{m}", base, m) for base in ("ideal_true_segment", "tracker_our_choice")
                     for m in ("static", "translate", "push"))
RUNGS = ("true_pose",) + tuple(p[0] for p in PERTURBATIONS) + ESTIMATOR_RUNGS + tuple(r[0] for r in MOTION_RUNGS)
#: A pose farther than this from the truth is another object's (m).
WRONG_SEGMENT_TOL = 0.10
#: The grasp's tolerances measured at the true pose (docs/retrieval.md): 0.05 rad, 2 cm.
YAW_TOL = 0.05
POSITION_TOL = 0.02


@dataclass(frozen=True)
class LadderRow:
    """One grasp of the ladder.

    Attributes
    ----------
    scene, seed : str, int
        The run.
    estimator : str
        Pose estimator of an estimator rung; '' for the true-pose rungs, which use none.
    rung : str
        One of :data:`RUNGS`.
    success : bool
        The simulated grasp succeeded (:func:`pipeline.grasp.grasp_at`).
    reason : str
        Why it was lost (:func:`loss_reason`); '' on success.
    position_error_m, yaw_error_rad : float
        Error of the tried pose against the truth (:func:`pipeline.retrieve.pose_error`), m and rad.
    segment_purity : float
        Share of the chosen segment's points with a known label that are the target's (1 for the true-pose rungs,
        0 without a chosen segment, NaN when none of its points has a known label).
    outcome : str
        The grasp's outcome string.
    """

    scene: str
    seed: int
    estimator: str
    rung: str
    success: bool
    reason: str
    position_error_m: float
    yaw_error_rad: float
    segment_purity: float
    outcome: str


def ideal_segments(path: str | Path, info: RunInfo) -> list[Segment]:
    """Ideal contact points of a run: one segment per body touched, each point where its contact lies now.

    Parameters
    ----------
    path : str or Path
        The collected run file (``stucco collect``).
    info : RunInfo
        The same run, :func:`pipeline.retrieve.load_run`.

    Returns
    -------
    list of Segment
        Per body touched (segment id = body index in ``scene.body_names`` order): ``points`` (M, 2) m, the true
        contact of each action whose window ends on that body (the window's last point on a body; without any
        contact in the window, the action's last true contact, given to the action's label), expressed in the
        body's frame at its pose after the action and put back at its final pose; ``steps`` (M,) the action
        indices, increasing.
    """
    t = pq.read_table(regular_file(path, "the run file"),
                      columns=["step", "win_true_contact_m", "win_true_object", "true_contact_x_m",
                                     "true_contact_y_m", "object_id", "obj_pose"])
    steps = t.column("step").to_numpy()
    body = t.column("object_id").to_numpy()
    n = len(steps)
    win = np.asarray(t.column("win_true_contact_m").to_pylist(), dtype=np.float64).reshape(n, -1, 2)
    win_body = np.asarray(t.column("win_true_object").to_pylist(), dtype=np.int64).reshape(n, -1)
    last = np.array([np.nan if v is None else v for v in t.column("true_contact_x_m").to_pylist()]), \
        np.array([np.nan if v is None else v for v in t.column("true_contact_y_m").to_pylist()])
    poses = np.asarray(t.column("obj_pose").to_pylist(), dtype=np.float64).reshape(n, -1, 3)
    # The isolation reports the contact of the window's last in-contact step, so the ideal point is the window's
    # last true contact and its body the one touched there, not the action's label (the bucket rule of the
    # labels may name a body the gripper left before the window: IB's action 12 is labelled the tomato can while
    # its whole window is on the box, which moves 3 cm there).
    touched = (win_body >= 0) & np.isfinite(win).all(axis=2)
    k = win.shape[1] - 1 - np.argmax(touched[:, ::-1], axis=1)  # last window row that touches a body
    xy = np.where(touched.any(axis=1)[:, None], win[np.arange(n), k], np.nan)
    quiet = ~touched.any(axis=1)  # the window touched nothing: the last contact is the only one recorded
    body = np.where(quiet, body, win_body[np.arange(n), k])
    xy[quiet] = np.column_stack(last)[quiet]
    keep = (body >= 0) & np.isfinite(xy).all(axis=1)
    out = []
    for b in np.unique(body[keep]):
        m = keep & (body == b)
        at, final = poses[m, b], info.final_poses[b]
        local = rotate(xy[m] - at[:, :2], at[:, 2], inverse=True)
        out.append(Segment(int(b), rotate(local, float(final[2])) + final[:2], steps[m].astype(np.int64),
                           observed=xy[m]))
    return out


def tracker_segments(path: str | Path) -> tuple[list[Segment], dict[int, np.ndarray], list | None]:
    """The tracker's final segments of one run, and those of every in-contact step.

    Parameters
    ----------
    path : str or Path
        A segments table (``stucco segment``; one run).

    Returns
    -------
    segments : list of Segment
        The final estimate's segments (unassigned points, segment -1, left out): points (M, 2) m, steps (M,).
    labels : dict of int to ndarray
        Each segment's ground-truth object ids (M,), -1 unknown.
    history : list or None
        The segments of every in-contact step (:func:`~pipeline.retrieve.stage.contact_step_segments`); None if
        the table holds only the final estimate (tracked without ``--every-step``).
    """
    table = schema.read_segments(path)
    every = bool((schema.read_metadata(path).get("params") or {}).get("every_step"))
    history = next(iter(contact_step_segments(table).values()), []) if every else None
    final = final_estimates(table)
    seg = final.column("segment").to_numpy()
    xy = np.column_stack([final.column("x_m").to_numpy(), final.column("y_m").to_numpy()])
    step = final.column("step").to_numpy()
    oid = final.column("object_id").to_numpy() if "object_id" in final.column_names else np.full(len(seg), -1)
    segs = [Segment(int(s), xy[seg == s], step[seg == s]) for s in np.unique(seg) if s >= 0]
    return segs, {int(s): oid[seg == s] for s in np.unique(seg) if s >= 0}, history


def perturbed(target, pose: np.ndarray, dyaw: float, along: float, across: float) -> np.ndarray:
    """The true pose perturbed: turned about the primitive's centre and shifted along / across its long axis.

    Parameters
    ----------
    target : Primitive
        The target's primitive (:attr:`RunInfo.target`).
    pose : ndarray, shape (3,)
        COM pose (x m, y m, yaw rad).
    dyaw : float
        Turn about the primitive's centre, rad.
    along, across : float
        Shift of the centre along / across the long axis (a box's x axis when hx >= hy; a can's x axis), m.

    Returns
    -------
    ndarray, shape (3,)
        The perturbed COM pose.
    """
    centre = target.centre_world(pose)
    axis_yaw = float(pose[2]) + target.yaw
    if target.kind == "box" and target.half[1] > target.half[0]:
        axis_yaw += math.pi / 2
    shift = rotate(np.array([along, across]), axis_yaw)
    new_yaw = float(pose[2]) + dyaw
    xy = centre + shift - rotate(np.asarray(target.centre, dtype=np.float64), new_yaw)
    return np.array([xy[0], xy[1], new_yaw])


def loss_reason(success: bool, position_error: float, yaw_error: float, purity: float = 1.0) -> str:
    """Why a grasp was lost, in the order the causes act.

    Parameters
    ----------
    success : bool
        The grasp succeeded.
    position_error, yaw_error : float
        Pose error against the truth, m and rad.
    purity : float
        Share of the chosen segment's labelled points that are the target's (NaN: no label known).

    Returns
    -------
    str
        '' on success; ``wrong_segment`` (position error > :data:`WRONG_SEGMENT_TOL`, or purity < 0.5),
        ``yaw`` (> :data:`YAW_TOL`), ``position`` (> :data:`POSITION_TOL`), else ``grasp_rule``.
    """
    if success:
        return ""
    if position_error > WRONG_SEGMENT_TOL or purity < 0.5:
        return "wrong_segment"
    if yaw_error > YAW_TOL:
        return "yaw"
    if position_error > POSITION_TOL:
        return "position"
    return "grasp_rule"


def run_ladder(run_path: Path, segments_path: Path | None, estimators: Sequence[str], root_seed: int
               ) -> list[LadderRow]:
    """Every rung of one run (the estimator rungs once per estimator).

    Parameters
    ----------
    run_path : Path
        The collected run file.
    segments_path : Path or None
        The tracker's segments of the run; None skips ``tracker_our_choice`` (so does, for an estimator that runs
        at every in-contact step, a table holding only the final estimate).
    estimators : sequence of str
        Pose estimators (:func:`pipeline.registry.estimator_names`).
    root_seed : int
        Root seed of the estimators' random streams (:func:`pipeline.retrieve.retrieval_rng`).

    Returns
    -------
    list of LadderRow
        The true-pose rungs once (estimator ''), then the estimator rungs per estimator.
    """
    info = load_run(run_path)
    target, truth = info.target, info.true_pose
    # the gripper the segments were tracked with (their record; the Panda without segments or a record)
    sdf = load_robot((tracking_robot(segments_path) if segments_path is not None else None) or "panda")
    rows: list[LadderRow] = []

    def grasp(estimator: str, rung: str, pose: np.ndarray, purity: float = 1.0) -> None:
        g = grasp_at(info.scene, info.final_poses, info.final_ee, target.canonical(pose), GraspParams())
        pos, yaw = pose_error(target, pose, truth)
        rows.append(LadderRow(info.scene.name, info.seed, estimator, rung, bool(g.success),
                              loss_reason(bool(g.success), pos, yaw, purity), pos, yaw, purity, g.outcome))

    grasp("", "true_pose", truth)
    for name, dyaw, along, across in PERTURBATIONS:
        grasp("", name, perturbed(target, truth, dyaw, along, across))
    ideal = ideal_segments(run_path, info)
    tracked, labels, tracked_history = tracker_segments(segments_path) if segments_path is not None else ([], {}, None)
    for est in estimators:
        for rung, segs, purity_of in (
                ("ideal_true_segment", [s for s in ideal if s.id == info.target_id], lambda s: 1.0),
                ("ideal_our_choice", ideal, lambda s: float(s == info.target_id)),
                ("tracker_our_choice", tracked,
                 lambda s: _purity(labels.get(s), info.target_id))):
            if rung == "tracker_our_choice" and (segments_path is None or (
                    tracked_history is None and needs_every_step([est]))):
                continue
            history = tracked_history if rung == "tracker_our_choice" else history_from_final(segs)
            e = estimate(est, segs, info, sdf, retrieval_rng(root_seed, info.run), history=history)
            grasp(est, rung, e.pose, purity_of(e.segment) if e.segment >= 0 else 0.0)
            if not hasattr(registry.build_params(registry.estimator(est)), "motion"):
                continue
            for name, _, motion in (r for r in MOTION_RUNGS if r[1] == rung):
                e = estimate(est, segs, info, sdf, retrieval_rng(root_seed, info.run), own={"motion": motion})
                grasp(est, name, e.pose, purity_of(e.segment) if e.segment >= 0 else 0.0)
    return rows


def _purity(labels: np.ndarray | None, target_id: int) -> float:
    """Share of the known labels (>= 0) that are the target's; 0 without a segment, NaN without a known label."""
    if labels is None:
        return 0.0
    known = labels[labels >= 0]
    return float(np.mean(known == target_id)) if len(known) else math.nan


def _run_pair(out: Path, scene: str, seed: int, estimators: Sequence[str], method: str, root_seed: int
              ) -> list[LadderRow]:
    runs = partition(out, "runs", scene, seed)
    if not runs.is_file():
        raise FileNotFoundError(f"{runs}: no collected run for {scene} seed {seed}; run `stucco evaluate` first")
    check_root_seed(runs, schema.read_metadata(runs), root_seed, "; run `stucco --seed {seed} bench retrieval` on it")
    seg = partition(out, "segments", scene, seed, method)
    if seg.is_file():
        check_segments_of_run(seg, runs, f"{scene}/{seed}")
    with single_threaded():
        return run_ladder(runs, seg if seg.is_file() else None, estimators, root_seed)


def check_segments_of_run(segments_path: Path, run_path: Path, run: str) -> None:
    """ValueError (one line) unless the segments file holds the segments of ``run`` only and were made from the run
    file ``run_path`` (its root seed, steps and digest: :func:`~pipeline.estimators.run_info.check_runs`, the check
    ``retrieve`` and ``score`` make)."""
    table = schema.read_segments(segments_path)
    others = sorted(set(table.column("run").to_pylist()) - {run})
    if others:
        raise ValueError(f"{segments_path}: holds segments of run {others[0]!r}, not only of {run!r} ({run_path})")
    check_runs(segments_path, table, {run: run_path})


def ladder_rows(runs_from: Path, pairs: Sequence[tuple[str, int]], estimators: Sequence[str], method: str,
                root_seed: int, jobs: int = 1, progress: Callable | None = None) -> list[LadderRow]:
    """The ladder of every (scene, seed) of an evaluation directory (``stucco evaluate`` layout), in grid order.

    ``progress`` wraps the iterable of finished runs (``progress(iterable, total=)``).
    """
    args = [(Path(runs_from), sc, int(s), tuple(estimators), method, root_seed) for sc, s in pairs]
    results = run_calls(_run_pair, args, jobs)
    if progress is not None:
        results = progress(results, total=len(args))
    return [r for chunk in results for r in chunk]
