"""One cell of the grid brought up to date: a (scene, seed)'s run and contacts, then a job's stale stages in order.

Jobs are pure functions of (root seed, scene, seed, method, :class:`~pipeline.evaluate.EvalConfig`), so they can
run in any process and any order (docs/evaluation.md, "What a job does").
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from pipeline.evaluate.config import EvalConfig, Job
from pipeline.evaluate.freshness import Digests, stale_stages, up_to_date
from pipeline.evaluate.parallel import single_threaded
from pipeline.evaluate.stages import run_collect, run_isolate, run_retrieve, run_score, run_segment, run_track
from pipeline.layout import job_paths, partition

__all__ = ["JobResult", "prepare_run", "prepare_one", "run_job"]


@dataclass
class JobResult:
    """What a job did: the stages it (re)ran, in order (empty: skipped, already up to date), and its wall time
    in seconds."""

    job: Job
    ran: tuple[str, ...]
    wall_s: float


def prepare_run(out: str | Path, scene: str, seed: int, cfg: EvalConfig) -> tuple[str, ...]:
    """Collect and isolate one (scene, seed) unless up to date; returns the stages run."""
    out = Path(out)
    runs = partition(out, "runs", scene, seed)
    contacts = partition(out, "contacts", scene, seed)
    ran: list[str] = []
    if not runs.is_file():
        run_collect(scene, seed, cfg, runs)
        ran.append("collect")
    if ran or not up_to_date(contacts, {"part": runs}, Digests()):
        with single_threaded():
            run_isolate(runs, contacts, cfg)
        ran.append("isolate")
    return tuple(ran)


def prepare_one(out: Path, scene: str, seed: int, cfg: EvalConfig) -> tuple[str, int, tuple[str, ...]]:
    """:func:`prepare_run` as ``(scene, seed, stages run)``; an error says which run it came from (a worker's
    traceback does not)."""
    try:
        return scene, seed, prepare_run(out, scene, seed, cfg)
    except Exception as e:
        e.add_note(f"in evaluation run {scene}/{seed} ({out})")
        raise


def run_job(out: str | Path, job: Job, cfg: EvalConfig) -> JobResult:
    """Bring one job up to date: run its stale stages in order (:func:`~pipeline.evaluate.stale_stages`)."""
    out = Path(out)
    t0 = time.perf_counter()
    todo = stale_stages(out, job, cfg.estimators)
    if not todo:
        return JobResult(job, (), 0.0)
    p = job_paths(out, job)
    try:
        with single_threaded():
            for stage in todo:
                if stage == "collect":
                    if not p["runs"].is_file():
                        run_collect(job.scene, job.seed, cfg, p["runs"])
                elif stage == "isolate":
                    run_isolate(p["runs"], p["contacts"], cfg)
                elif stage == "track":
                    run_track(p, job.method, cfg)
                elif stage == "segment":
                    run_segment(p, cfg)
                elif stage == "retrieve":
                    for est in cfg.estimators:
                        run_retrieve(job_paths(out, job, est), job.method, cfg, est)
                else:
                    for est in cfg.estimators:
                        run_score(job_paths(out, job, est), cfg)
    except Exception as e:
        e.add_note(f"in evaluation job {job} ({out})")
        raise
    return JobResult(job, tuple(todo), time.perf_counter() - t0)
