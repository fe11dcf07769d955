"""Each stage of one evaluation job, run as the CLI runs it, with its wall time kept beside its output.

Every function here calls the stage's ``<stage>_file`` function, the one its ``stucco`` command calls (so the
parameters, metadata and atomic writes are those of the CLI), with the root seed and the stage's partitions
(:mod:`pipeline.layout`) as files; a stored run (``--from-runs``) is copied instead of collected.

**Wall times**: each stage's wall time (seconds) goes to a ``_wall_s.json`` beside its file (ignored by pyarrow
datasets and by the stages, which only read ``*.parquet``), and the scores table gets ``stage_<name>_s`` columns
and ``wall_s`` = their sum, the time to produce the run from nothing (collect and isolate, shared by the methods
of a seed, are counted in each); docs/evaluation.md, "Wall times".
"""
from __future__ import annotations

import json
import math
import shutil
import time
from pathlib import Path

import pyarrow as pa

from pipeline.atomic import atomic_path, write_text
from pipeline.collect import collect_file, output_path
from pipeline.estimators.estimate import needs_every_step
from pipeline.evaluate.config import EvalConfig
from pipeline.grasp import GraspParams
from pipeline.isolate import isolate_file
from pipeline.layout import STAGE_KIND, STAGES, wall_path
from pipeline.retrieve import RetrievalParams, RetrieveConfig, retrieve_file
from pipeline.score import score_file
from pipeline.segment import segment_file

__all__ = ["STAGE_COLUMNS", "write_wall", "read_wall", "run_collect", "run_isolate", "run_track", "run_segment",
           "run_retrieve", "run_score", "with_stage_times"]

#: Columns the evaluation adds to the scores table (seconds of wall time per stage; null if unknown).
STAGE_COLUMNS = tuple(f"stage_{s}_s" for s in STAGES)


def write_wall(path: Path, seconds: float) -> None:
    """``{"wall_s": seconds}`` (rounded to the microsecond) into the ``_wall_s.json`` beside ``path``."""
    write_text(wall_path(path), json.dumps({"wall_s": round(float(seconds), 6)}))


def read_wall(path: Path) -> float | None:
    """The wall time (s) recorded beside ``path``; None if missing, unreadable or not finite."""
    try:
        v = json.loads(wall_path(path).read_text())["wall_s"]
        return float(v) if math.isfinite(float(v)) else None
    except (OSError, ValueError, KeyError, TypeError):
        return None


def run_collect(scene_name: str, seed: int, cfg: EvalConfig, dest: Path) -> None:
    """Collect the scripted run (or copy the stored one of ``cfg.source``) to ``dest``.

    A copied run has no wall time (its side file is removed): it was not produced here.
    """
    t0 = time.perf_counter()
    if cfg.source is not None:
        src = output_path(cfg.source, scene_name, seed)
        if not src.is_file():
            raise FileNotFoundError(f"{src}: no stored run for {scene_name} seed {seed}")
        with atomic_path(dest) as tmp:
            shutil.copyfile(src, tmp)
        from pipeline.probe.report import times_path  # imported here: only probing runs have a times file

        if times_path(src).is_file():  # the probing policy's decision times, kept beside the run
            with atomic_path(times_path(dest)) as tmp:
                shutil.copyfile(times_path(src), tmp)
        wall = None
    else:
        res = collect_file(cfg.scene(scene_name), seed, dest, root_seed=cfg.root_seed, policy=cfg.collect_policy,
                           max_actions=cfg.max_actions, keep_discarded=True)
        if res.probe_s is not None:
            from pipeline.probe.report import save_times  # imported here: only the probing policy times decisions

            save_times(dest, res.probe_s)
        wall = time.perf_counter() - t0
    if wall is None:
        wall_path(dest).unlink(missing_ok=True)
    else:
        write_wall(dest, wall)


def run_isolate(runs: Path, dest: Path, cfg: EvalConfig) -> None:
    """Isolate the contacts of one collected run file into ``dest`` (default detection and isolation)."""
    t0 = time.perf_counter()
    isolate_file([runs], dest, seed=cfg.root_seed)
    write_wall(dest, time.perf_counter() - t0)


def run_track(p: dict[str, Path], method: str, cfg: EvalConfig) -> None:
    """Track the contacts with ``method`` (default parameters) into the tracks and diagnostics partitions; the
    estimate after every step too when one of ``cfg.estimators`` needs it (the final estimate is the same)."""
    # Imported here: the trackers load numba's kernels (about a quarter of a second), which only the processes
    # that track need.
    from pipeline.track.stage import TrackConfig, track_file

    t0 = time.perf_counter()
    # An estimator that runs at every in-contact step (the paper's, online) reads the estimate after every step.
    config = TrackConfig(method=method, robot=cfg.robot, params={}, every_step=needs_every_step(cfg.estimators))
    track_file(p["contacts"], p["tracks"], config, seed=cfg.root_seed, jobs=1, diagnostics_path=p["diagnostics"])
    write_wall(p["tracks"], time.perf_counter() - t0)


def run_segment(p: dict[str, Path], cfg: EvalConfig) -> None:
    """Segment the tracks (``by="auto"``: Alg. 3's components for STUCCO, the tracker's own labels otherwise)."""
    t0 = time.perf_counter()
    segment_file(p["tracks"], p["segments"], seed=cfg.root_seed, by="auto")
    write_wall(p["segments"], time.perf_counter() - t0)


def run_retrieve(p: dict[str, Path], method: str, cfg: EvalConfig, estimator: str) -> None:
    """Estimate the target's pose with ``estimator`` (and simulate the grasp if ``cfg.grasp``) into the
    retrieval and candidates partitions of that estimator (``p`` from :func:`pipeline.layout.job_paths`)."""
    t0 = time.perf_counter()
    config = RetrieveConfig(method=method, estimator=estimator,
                            params=RetrievalParams(n_restarts=cfg.restarts, robot=cfg.robot), grasp=cfg.grasp,
                            grasp_params=GraspParams(), stream=cfg.estimator_stream)
    retrieve_file(p["segments"], p["runs"], p["retrieval"], p["candidates"], config, seed=cfg.root_seed, jobs=1)
    write_wall(p["retrieval"], time.perf_counter() - t0)


def run_score(p: dict[str, Path], cfg: EvalConfig) -> None:
    """Score one estimator's retrieval into its scores partition, with every stage's wall time
    (:func:`with_stage_times`)."""
    t0 = time.perf_counter()
    walls = {s: read_wall(p[k]) for s, k in STAGE_KIND.items() if s != "score"}

    def timed(table: pa.Table) -> pa.Table:
        walls["score"] = time.perf_counter() - t0
        return with_stage_times(table, walls)

    score_file(p["retrieval"], p["segments"], p["runs"], p["scores"], seed=cfg.root_seed,
               diagnostics_path=p["diagnostics"], amend=timed)


def with_stage_times(table: pa.Table, walls: dict[str, float | None]) -> pa.Table:
    """Scores + one ``stage_<name>_s`` column per stage (seconds, null if unknown); ``wall_s`` = the sum of the
    known ones."""
    n = table.num_rows
    for s in STAGES:
        v = walls.get(s)
        table = table.append_column(f"stage_{s}_s", pa.array([v] * n, pa.float64()))
    total = float(sum(v for v in walls.values() if v is not None))
    i = table.column_names.index("wall_s")
    return table.set_column(i, "wall_s", pa.array([total] * n, pa.float64()))
