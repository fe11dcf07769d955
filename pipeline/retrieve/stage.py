"""The ``retrieve`` stage: a segments table and the collected runs in, the retrieval and candidates tables out."""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Collection
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from pipeline import registry, schema
from pipeline.atomic import all_or_none
from pipeline.constraints import Params
from pipeline.estimators.estimate import (
    DEFAULT_ESTIMATOR,
    History,
    Segment,
    estimate,
    needs_every_step,
    retrieval_metadata,
)
from pipeline.estimators.params import RetrievalParams
from pipeline.estimators.run_info import RunInfo, check_runs, load_run, retrieval_rng, run_files_by_name
from pipeline.estimators.target_model import pose_error
from pipeline.grasp import GraspParams, grasp_at
from pipeline.parallel import run_calls
from pipeline.robot import load_robot
from pipeline.schema.retrieval import candidates_table, retrieval_table
from pipeline.seeds import check_stream
from pipeline.segment import final_estimates, recorded_tracking

__all__ = ["RetrieveConfig", "final_segments_by_run", "contact_step_segments", "retrieve", "retrieve_file",
           "retrieve_one", "retrieve_runs", "read_segments_for", "write_retrieval_tables", "LOG_SCENE"]

#: The ``scene`` of a retrieval row made from a robot's log (no scene).
LOG_SCENE = "log"


@dataclass(frozen=True)
class RetrieveConfig(Params):
    """What `stucco retrieve` was asked to do; recorded in the output metadata (:meth:`metadata`).

    Attributes
    ----------
    method : str or None
        Tracking method that made the segments, recorded in the output; None: the one the segments file records
        (:func:`retrieve_file`; the first registered method for :func:`retrieve` on a table).
    estimator : str
        A registered pose estimator (:func:`pipeline.registry.estimator_names`).
    params : RetrievalParams
        The paper's estimation parameters, shared by every estimator.
    estimator_params : dataclass instance, dict or None
        The estimator's own parameters (e.g. :class:`~pipeline.estimators.plausible.params.PlausibleParams`), a dict of
        overrides, or None for its defaults; held as the built instance (None for an estimator without any).
    grasp : bool
        Simulate the grasp at the estimate (:func:`pipeline.grasp.grasp_at`).
    grasp_params : GraspParams
    stream : int
        The estimator's random stream (:func:`pipeline.estimators.run_info.retrieval_rng`): 0, the default; k >= 1 an
        independent rerun of a stochastic estimator. Recorded in the metadata when not 0.
    """

    method: str | None = None
    estimator: str = DEFAULT_ESTIMATOR
    params: RetrievalParams = RetrievalParams()
    estimator_params: Any = None
    grasp: bool = True
    grasp_params: GraspParams = GraspParams()
    stream: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "stream", check_stream(self.stream))
        if self.method is not None:
            registry.tracker(self.method)  # ValueError naming the registered methods
        spec = registry.estimator(self.estimator)
        object.__setattr__(self, "estimator_params", registry.build_params(spec, self.estimator_params))
        super().__post_init__()

    def metadata(self) -> dict:
        """The provenance ``params`` of the retrieval and candidates tables."""
        # (the stream only when not 0: tables of the default stream keep the bytes they always had)
        extra = {"stream": self.stream} if self.stream else {}
        return retrieval_metadata(self.estimator, self.params, self.estimator_params, method=self.method,
                                  grasp=self.grasp, grasp_params=self.grasp_params if self.grasp else None, **extra)


def final_segments_by_run(segments: pa.Table) -> dict[str, list[Segment]]:
    """Run -> its segments (id, final tracked points (M, 2), observation steps (M,)) of the final estimate of each
    run (unassigned points, segment -1, are left out)."""
    final = final_estimates(segments)
    out: dict[str, list[Segment]] = {}
    if final.num_rows == 0:
        return out
    run = np.asarray(final.column("run").to_pylist(), dtype=object)
    seg = final.column("segment").to_numpy()
    step = final.column("step").to_numpy()
    xy = np.column_stack([final.column("x_m").to_numpy(), final.column("y_m").to_numpy()])
    for r in dict.fromkeys(run):
        m = run == r
        out[r] = [Segment(int(s), xy[m & (seg == s)], step[m & (seg == s)]) for s in np.unique(seg[m]) if s >= 0]
    return out


def contact_step_segments(segments: pa.Table) -> dict[str, History]:
    """Run -> the segments of every in-contact step, in step order: (step, its segments), the estimate made after
    a step at which a contact point was observed (a row with ``step == estimate_step``). A table written without
    ``--every-step`` holds only the final estimate, which is such a step only if the run's last step touched.
    Unassigned points (segment -1) are left out; a run without any contact is absent."""
    out: dict[str, History] = {}
    if segments.num_rows == 0:
        return out
    run = np.asarray(segments.column("run").to_pylist(), dtype=object)
    est = segments.column("estimate_step").to_numpy()
    step = segments.column("step").to_numpy()
    seg = segments.column("segment").to_numpy()
    xy = np.column_stack([segments.column("x_m").to_numpy(), segments.column("y_m").to_numpy()])
    for r in dict.fromkeys(run):
        mine = np.flatnonzero(run == r)
        contact = np.unique(est[mine][step[mine] == est[mine]])
        hist = []
        for k in contact:
            rows = mine[est[mine] == k]
            ids = np.unique(seg[rows])
            hist.append((int(k), [Segment(int(s), xy[rows[seg[rows] == s]], step[rows[seg[rows] == s]])
                                  for s in ids if s >= 0]))
        out[r] = hist
    return out


@dataclass
class RunOutput:
    row: dict[str, Any]
    candidates: dict[str, np.ndarray]


def retrieve_one(info: RunInfo, segs: list[Segment], config: RetrieveConfig, root_seed: int,
                  history: History | None = None) -> RunOutput:
    method, estimator = config.method, config.estimator
    est = estimate(estimator, segs, info, load_robot(config.params.robot),
                   retrieval_rng(root_seed, info.run, config.stream), config.params, config.estimator_params,
                   history=history)
    truth = info.true_pose  # None for a robot's log: no ground truth, nothing to grasp
    pos_err, yaw_err = pose_error(info.target, est.pose, truth) if truth is not None else (None, None)
    row = dict(run=info.run, scene=info.scene.name if info.scene is not None else LOG_SCENE, seed=info.seed,
               method=method, estimator=estimator,
               target=info.target.name,
               x_m=float(est.pose[0]), y_m=float(est.pose[1]), yaw_rad=float(est.pose[2]), segment=est.segment,
               n_points=est.n_points, n_segments=est.n_segments,
               position_var_m2=est.position_var if math.isfinite(est.position_var) else None,
               icp_rmse_m=est.rmse if math.isfinite(est.rmse) else None, penetration_m=est.penetration,
               low_confidence=est.low_confidence, notes=",".join(est.notes),
               true_x_m=None if truth is None else float(truth[0]),
               true_y_m=None if truth is None else float(truth[1]),
               true_yaw_rad=None if truth is None else float(truth[2]),
               position_error_m=pos_err, yaw_error_rad=yaw_err, grasp_success=None, grasp_outcome="",
               grasp_attempts=None, grasp_success_any=None, icp_s=est.icp_s, grasp_s=None)
    own = registry.policy(info.policy).retrieval if info.policy in registry.policy_names() else None
    if own is not None:
        # A run of the active protocol ends with its own pose and its grasp for the whole plausible set, whatever
        # the estimator (docs/active.md); the estimator's candidates are kept.
        row.update(registry.resolve(own)(info, method, root_seed, config.grasp, config.grasp_params))
    elif config.grasp and info.scene is not None:
        g = grasp_at(info.scene, info.final_poses, info.final_ee, est.pose, config.grasp_params, info.final_tilted)
        row.update(grasp_success=g.success, grasp_outcome=g.outcome, grasp_s=g.wall_s)
    cand = dict(est.candidates)
    cand["run"] = np.full(len(cand["segment"]), info.run, dtype=object)
    return RunOutput(row, cand)


def retrieve(segments: pa.Table, run_dir: str | Path, config: RetrieveConfig | None = None, *,
             root_seed: int = 0, jobs: int = 1, progress: Callable | None = None,
             segments_path: str = "<segments>", runs: Collection[str] | None = None) -> tuple[pa.Table, pa.Table]:
    """The ``retrieve`` stage: a segments table and the collected runs in, retrieval and candidates tables out.

    Every run of ``runs`` (the runs the segments were tracked from, as their file records them; None: every run
    file in ``run_dir``, or the one run file it names) gets one row: a run absent from the segments table had no
    tracked contact (an empty segmentation) and is estimated as such (flagged ``no_points``). Run files of
    ``run_dir`` outside ``runs`` were not tracked into these segments and get no row. A run of the segments table
    or of ``runs`` without a run file is an error.

    Parameters
    ----------
    segments : pyarrow.Table
        A validated segments table: its final estimate per run, and for an estimator that needs them (``paper``)
        its estimates after every in-contact step (:func:`contact_step_segments`).
    run_dir : path
        Directory of ``stucco collect`` files, or one of them.
    config : RetrieveConfig
        Method, estimator and parameters.
    root_seed : int
    jobs : int
        Runs processed in parallel processes.
    progress : callable, optional
        Wraps the iterable of finished runs (``progress(iterable, total=)``).
    segments_path : str
        Named in errors.

    Returns
    -------
    retrieval, candidates : pyarrow.Table
    """
    config = config or RetrieveConfig()
    if config.method is None:
        config = dataclasses.replace(config, method=registry.tracker_names()[0])
    files = run_files_by_name(run_dir)
    by_run = final_segments_by_run(segments)
    wanted = list(files) if runs is None else list(dict.fromkeys([*runs, *by_run]))
    missing = [r for r in [*by_run, *wanted] if r not in files]
    if missing:
        raise ValueError(f"{segments_path}: run {missing[0]!r} has no collected run file in {run_dir} "
                         f"({len(files)} run file(s) there)")
    order = {r: k for k, r in enumerate(files)}  # the run files' order, as without ``runs``
    return retrieve_runs([load_run(files[r]) for r in sorted(wanted, key=order.__getitem__)], segments, config,
                         root_seed, jobs, progress)


def retrieve_runs(infos: list[RunInfo], segments: pa.Table, config: RetrieveConfig, root_seed: int, jobs: int,
                  progress: Callable | None) -> tuple[pa.Table, pa.Table]:
    """Every run of ``infos`` estimated (and grasped, as ``config`` says) from its segments in ``segments`` (none:
    estimated as such), the runs in parallel processes; the retrieval and candidates tables. The one loop of both
    routes of the stage (simulated runs, a robot's log)."""
    by_run = final_segments_by_run(segments)
    steps = contact_step_segments(segments) if needs_every_step([config.estimator]) else None
    args = [(info, by_run.get(info.run, []), config, root_seed, None if steps is None else steps.get(info.run, []))
            for info in infos]
    results = run_calls(retrieve_one, args, jobs)
    if progress is not None:
        results = progress(results, total=len(args))
    outs = list(results)
    return retrieval_table([o.row for o in outs]), candidates_table([o.candidates for o in outs])


def retrieve_file(segments_path: str | Path, run_dir: str | Path, out_path: str | Path,
                  candidates_path: str | Path, config: RetrieveConfig, *, seed: int, jobs: int = 1,
                  progress: Callable | None = None) -> tuple[pa.Table, pa.Table]:
    """The `retrieve` stage on files: read and validate a segments table, :func:`retrieve` its runs (files in
    ``run_dir``), and write the candidates and retrieval tables (with provenance metadata:
    :func:`~pipeline.estimators.estimate.retrieval_metadata`, the segments file as input), both or neither
    (:func:`pipeline.atomic.all_or_none`; the retrieval is renamed last). Returns (retrieval, candidates).

    ``config.grasp_params`` is used and recorded when ``config.grasp``; ``config.method`` None takes the tracking
    method the segments file records (ValueError if it is not registered); ``seed`` is the root seed.
    """
    segments, config = read_segments_for(segments_path, config)
    check_runs(segments_path, segments, run_files_by_name(run_dir))
    # the runs the segments were tracked from, when the file records them (provenance): no other run of run_dir
    recorded = schema.read_metadata(segments_path).get("runs") or None
    table, candidates = retrieve(segments, run_dir, config, root_seed=seed, jobs=jobs, progress=progress,
                                 segments_path=str(segments_path), runs=None if recorded is None else list(recorded))
    write_retrieval_tables(table, candidates, out_path, candidates_path, config.metadata(), seed,
                           {"segments": str(segments_path)})
    return table, candidates


def tracking_robot(segments_path: str | Path) -> str | None:
    """The robot a segments file's points were tracked with (its ``params.tracking``, docs/tables.md), or None
    when it does not record one."""
    robot = (recorded_tracking(schema.read_metadata(segments_path)).get("params") or {}).get("robot")
    return str(robot) if robot is not None else None


def read_segments_for(segments_path: str | Path, config: RetrieveConfig) -> tuple[pa.Table, RetrieveConfig]:
    """A validated segments table and ``config`` with its tracking method (the one the file records when
    ``config.method`` is None); ValueError (one line) when the method is not registered or the estimator needs
    every step and the file holds only the final estimate."""
    segments = schema.read_segments(segments_path)
    meta = schema.read_metadata(segments_path)
    params = meta.get("params") or {}
    recorded = params.get("method")
    if config.method is None:
        try:
            config = dataclasses.replace(config, method=str(recorded or registry.tracker_names()[0]))
        except ValueError as e:
            raise ValueError(f"{segments_path}: the tracking method it records: {e}; pass --method") from None
    elif recorded and str(recorded) != config.method:
        raise ValueError(f"{segments_path}: tracked by method {recorded!r}, not {config.method!r} (--method): its "
                         f"rows would be reported as another method's")
    tracker = recorded_tracking(meta).get("params") or {}
    robot = tracker.get("robot")
    if robot is not None and str(robot) != config.params.robot:
        # the same gripper may be spelled otherwise (disc:0.03, disc:0.030): its grid's digest decides when recorded
        recorded_digest = tracker.get("robot_digest")
        if recorded_digest is None or load_robot(config.params.robot).digest != recorded_digest:
            raise ValueError(f"{segments_path}: its points were tracked with robot {robot!r}, not "
                             f"{config.params.robot!r} (--robot): the free space is the trail of the gripper that "
                             "made them")
    if needs_every_step([config.estimator]) and not params.get("every_step"):
        raise ValueError(f"{segments_path}: holds only the final estimate of each run; --estimator "
                         f"{config.estimator} runs at every in-contact step: track with `stucco track --every-step`, "
                         f"then segment")
    return segments, config


def write_retrieval_tables(table: pa.Table, candidates: pa.Table, out_path: str | Path,
                           candidates_path: str | Path, meta: dict, seed: int, inputs: dict) -> None:
    """The retrieve stage's two tables, with provenance (``meta`` its parameters, ``inputs`` role -> path), both or
    neither (:func:`pipeline.atomic.all_or_none`; the retrieval is renamed last)."""
    with all_or_none([candidates_path, out_path]) as (cand_tmp, retrieval_tmp):
        schema.write_table(candidates, cand_tmp, stage="retrieve", params=meta, seed=seed, inputs=inputs,
                           kind="candidates")
        schema.write_table(table, retrieval_tmp, stage="retrieve", params=meta, seed=seed, inputs=inputs,
                           kind="retrieval")
