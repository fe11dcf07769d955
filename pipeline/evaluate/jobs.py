"""One cell of the grid brought up to date: a (scene, seed)'s run and contacts, then a job's stale stages in order.

Jobs are pure functions of (root seed, scene, seed, method, :class:`~pipeline.evaluate.EvalConfig`), so they can
run in any process and any order (docs/evaluation.md, "What a job does"). The driver decides what is stale (one
pass over the files, :mod:`pipeline.evaluate.freshness`) and hands it to the functions here with the job's paths;
they return what they ran and every stage's wall time, in memory.
"""
from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.evaluate.config import EvalConfig, Job
from pipeline.evaluate.freshness import Digests, job_stale_stages, shared_stale_stages
from pipeline.evaluate.parallel import single_threaded
from pipeline.evaluate.stages import (
    StageTimes,
    run_collect,
    run_isolate,
    run_retrieve,
    run_score,
    run_segment,
    run_track,
    stored_stage_s,
)
from pipeline.layout import JobPaths, job_paths, run_paths, stage_spec

__all__ = ["JobResult", "PreparedRun", "prepare_run", "prepare_one", "run_job"]


@dataclass
class JobResult:
    """What a job did: the stages it (re)ran, in order (empty: skipped, already up to date), its wall time in
    seconds, and per pose estimator the wall time (s) of every stage its scores record (``stage_s[estimator]
    [stage]``; None or absent: unknown; empty for a skipped job)."""

    job: Job
    ran: tuple[str, ...]
    wall_s: float
    stage_s: dict[str, StageTimes] = field(default_factory=dict)


@dataclass(frozen=True)
class PreparedRun:
    """What :func:`prepare_one` did for one (scene, seed): the shared stages run and their wall times (s; collect
    None for a copied run)."""

    scene: str
    seed: int
    ran: tuple[str, ...]
    stage_s: StageTimes


def _prepare(out: Path, scene: str, seed: int, cfg: EvalConfig, todo: Sequence[str] | None) -> PreparedRun:
    out = Path(out)
    if todo is None:
        todo = shared_stale_stages(out, scene, seed, Digests(), cfg.source, cfg.root_seed, cfg)
    paths = run_paths(out, scene, seed)
    times: StageTimes = {}
    if "collect" in todo:
        times["collect"] = run_collect(paths, cfg)
    if todo:  # a new run, or contacts not up to date with it
        with single_threaded():
            times["isolate"] = run_isolate(paths, cfg)
    return PreparedRun(scene, seed, tuple(times), times)


def prepare_run(out: str | Path, scene: str, seed: int, cfg: EvalConfig,
                todo: Sequence[str] | None = None) -> tuple[str, ...]:
    """Collect and isolate one (scene, seed) unless up to date (``todo``: the stale shared stages, as
    :func:`~pipeline.evaluate.freshness.shared_stale_stages` gives them; checked here when None); returns the
    stages run."""
    return _prepare(Path(out), scene, seed, cfg, todo).ran


def prepare_one(out: Path, scene: str, seed: int, cfg: EvalConfig,
                todo: Sequence[str] | None = None) -> PreparedRun:
    """:func:`prepare_run` with the wall times; an error says which run it came from (a worker's traceback does
    not)."""
    try:
        return _prepare(Path(out), scene, seed, cfg, todo)
    except Exception as e:
        e.add_note(f"in evaluation run {scene}/{seed} ({out})")
        raise


def run_job(out: str | Path, job: Job, cfg: EvalConfig, todo: Sequence[str] | None = None,
            paths: JobPaths | None = None, known_s: Mapping[str, float | None] | None = None) -> JobResult:
    """Bring one job up to date: run its stale stages in order.

    Parameters
    ----------
    out : path
        The evaluation directory.
    job : Job
    cfg : EvalConfig
    todo : sequence of str or None
        The stale stages (:func:`~pipeline.evaluate.freshness.job_stale_stages`, as the driver computed them);
        None: checked here.
    paths : JobPaths or None
        The job's files for ``cfg.estimators`` (:func:`pipeline.layout.job_paths`); None: made here.
    known_s : mapping or None
        Stage -> wall time (s) of stages not in ``todo`` that the caller knows (the shared collect and isolate of
        this call); the other stages not rerun take the times the job's stored scores record.

    Returns
    -------
    JobResult
        With the stages run and, per estimator, every stage's wall time (s) written into its scores.
    """
    out = Path(out)
    t0 = time.perf_counter()
    paths = job_paths(out, job, cfg.estimators) if paths is None else paths
    todo = job_stale_stages(paths, Digests()) if todo is None else tuple(todo)
    if not todo:
        return JobResult(job, (), 0.0)
    walls = _earlier_times(paths, todo, known_s or {})
    try:
        with single_threaded():
            for stage in todo:
                if stage == "collect":
                    if not paths["runs"].is_file():
                        _for_all(walls, stage, run_collect(paths, cfg))
                elif stage == "isolate":
                    _for_all(walls, stage, run_isolate(paths, cfg))
                elif stage == "track":
                    _for_all(walls, stage, run_track(paths, job.method, cfg))
                elif stage == "segment":
                    _for_all(walls, stage, run_segment(paths, cfg))
                elif stage == "retrieve":
                    for est in paths.estimators:
                        walls[est]["retrieve"] = run_retrieve(paths, job.method, cfg, est)
                else:
                    for est in paths.estimators:
                        run_score(paths, cfg, est, walls[est])
    except Exception as e:
        e.add_note(f"in evaluation job {job} ({out})")
        raise
    return JobResult(job, todo, time.perf_counter() - t0, walls)


def _earlier_times(paths: JobPaths, todo: Sequence[str], known_s: Mapping[str, float | None]
                   ) -> dict[str, StageTimes]:
    """Estimator -> stage -> wall time (s) of the stages not in ``todo``: ``known_s``, else what the job's stored
    scores record (each estimator's own, else any estimator's for the stages they share); read before the job
    rewrites its scores."""
    own = {e: stored_stage_s([paths.of("scores", e)]) for e in paths.estimators}
    shared = next((t for t in own.values() if t), {})
    walls = {}
    for e in paths.estimators:
        w = {s: v for s, v in shared.items() if not stage_spec(s).per_estimator}
        w.update(own[e])
        w.update(known_s)
        walls[e] = {s: v for s, v in w.items() if s not in todo}
    return walls


def _for_all(walls: dict[str, StageTimes], stage: str, seconds: float | None) -> None:
    """Set one stage's wall time for every estimator (the stages before retrieve are shared by them)."""
    for w in walls.values():
        w[stage] = seconds
