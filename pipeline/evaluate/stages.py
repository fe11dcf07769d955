"""Each stage of one evaluation job, run as the CLI runs it, returning its wall time.

Every function here calls the stage's ``<stage>_file`` function, the one its ``stucco`` command calls (so the
parameters, metadata and atomic writes are those of the CLI), with the root seed and the files its
:class:`~pipeline.layout.StageSpec` declares, taken from the job's :class:`~pipeline.layout.JobPaths`; a stored
run (``--from-runs``) is copied instead of collected.

**Wall times**: each function returns its stage's wall time (seconds) to the caller, which hands them on in
memory; the scores table gets ``stage_<name>_s`` columns and ``wall_s`` = their sum, the time to produce the run
from nothing (collect and isolate, shared by the methods of a seed, are counted in each; docs/evaluation.md,
"Wall times"). The scores are the only place they persist: a later call that reruns part of a job takes the
times of the stages it does not rerun from the job's stored scores (:func:`stored_stage_s`).
"""
from __future__ import annotations

import math
import shutil
import time
from collections.abc import Iterable, Mapping
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from pipeline import registry
from pipeline.atomic import all_or_none
from pipeline.collect import collect_file, output_path
from pipeline.estimators.estimate import needs_every_step
from pipeline.evaluate.config import EvalConfig
from pipeline.grasp import GraspParams
from pipeline.isolate import isolate_file
from pipeline.layout import STAGES, JobPaths, stage_spec
from pipeline.retrieve import RetrievalParams, RetrieveConfig, retrieve_file
from pipeline.safe_open import optional_file, regular_file
from pipeline.score import score_file
from pipeline.segment import segment_file

__all__ = ["STAGE_COLUMNS", "StageTimes", "run_collect", "run_isolate", "run_track", "run_segment", "run_retrieve",
           "run_score", "with_stage_times", "stored_stage_s"]

#: Columns the evaluation adds to the scores table (seconds of wall time per stage; null if unknown).
STAGE_COLUMNS = tuple(f"stage_{s}_s" for s in STAGES)
#: Stage name -> its wall time in seconds (None: unknown, e.g. a run copied by ``--from-runs``).
StageTimes = dict[str, float | None]

_COLLECT, _ISOLATE, _TRACK, _SEGMENT, _RETRIEVE, _SCORE = (stage_spec(s) for s in STAGES)


def run_collect(paths: JobPaths, cfg: EvalConfig) -> float | None:
    """Collect the scripted run (or copy the stored one of ``cfg.source``, with its policy's side files) into the
    job's run file; returns the wall time (s), None for a copied run (it was not produced here)."""
    dest = paths.outputs(_COLLECT)["runs"]
    scene, seed = paths.scene, paths.seed
    t0 = time.perf_counter()
    if cfg.source is not None:
        src = output_path(cfg.source, scene, seed)
        if optional_file(src, "the stored run") is None:
            raise FileNotFoundError(f"{src}: no stored run for {scene} seed {seed}")
        sides = [(side, registry.side_path(dest, suffix)) for suffix in registry.side_suffixes()
                 if optional_file(side := registry.side_path(src, suffix), "the run's side file") is not None]
        # the run and its side files appear together (a side file of an older copy never outlives its run)
        registry.remove_side_files(dest)
        with all_or_none([dest, *(d for _, d in sides)]) as tmps:
            for (from_, _), tmp in zip([(src, dest), *sides], tmps):
                shutil.copyfile(regular_file(from_, "the stored run"), tmp)
        return None
    collect_file(cfg.scene(scene), seed, dest, root_seed=cfg.root_seed, policy=cfg.collect_policy,
                 max_actions=cfg.max_actions, keep_discarded=True, policy_params=dict(cfg.policy_params) or None)
    return time.perf_counter() - t0


def run_isolate(paths: JobPaths, cfg: EvalConfig) -> float:
    """Isolate the contacts of the job's run file (the detector it was collected with, default isolation); returns
    the wall time (s)."""
    t0 = time.perf_counter()
    isolate_file(list(paths.inputs(_ISOLATE).values()), paths.outputs(_ISOLATE)["contacts"], seed=cfg.root_seed)
    return time.perf_counter() - t0


def run_track(paths: JobPaths, method: str, cfg: EvalConfig) -> float:
    """Track the contacts with ``method`` (its defaults, or the scene's ``[methods.<method>]``) into the tracks and
    diagnostics partitions; the
    estimate after every step too when one of ``cfg.estimators`` needs it (the final estimate is the same).
    Returns the wall time (s)."""
    # Imported here: the trackers load numba's kernels (about a quarter of a second), which only the processes
    # that track need.
    from pipeline.track.stage import TrackConfig, track_file

    t0 = time.perf_counter()
    # An estimator that runs at every in-contact step (the paper's, online) reads the estimate after every step.
    # the parameters the scene's robot was tuned with (its [methods.<method>], e.g. Table I's real column)
    config = TrackConfig(method=method, robot=cfg.robot, params=cfg.scene(paths.scene).hardware.method_params(method),
                         every_step=needs_every_step(cfg.estimators))
    out = paths.outputs(_TRACK)
    track_file(paths.inputs(_TRACK)["contacts"], out["tracks"], config, seed=cfg.root_seed, jobs=1,
               diagnostics_path=out["diagnostics"])
    return time.perf_counter() - t0


def run_segment(paths: JobPaths, cfg: EvalConfig) -> float:
    """Segment the tracks (``by="auto"``: Alg. 3's components for STUCCO, the tracker's own labels otherwise);
    returns the wall time (s)."""
    t0 = time.perf_counter()
    segment_file(paths.inputs(_SEGMENT)["tracks"], paths.outputs(_SEGMENT)["segments"], seed=cfg.root_seed,
                 by="auto")
    return time.perf_counter() - t0


def run_retrieve(paths: JobPaths, method: str, cfg: EvalConfig, estimator: str) -> float:
    """Estimate the target's pose with ``estimator`` (and simulate the grasp if ``cfg.grasp``) into the
    retrieval and candidates partitions of that estimator; returns the wall time (s)."""
    t0 = time.perf_counter()
    config = RetrieveConfig(method=method, estimator=estimator,
                            params=RetrievalParams(n_restarts=cfg.restarts, robot=cfg.robot), grasp=cfg.grasp,
                            grasp_params=GraspParams(), stream=cfg.estimator_stream)
    out = paths.outputs(_RETRIEVE, estimator)
    retrieve_file(paths.inputs(_RETRIEVE, estimator)["segments"], paths.reads(_RETRIEVE, estimator)["runs"],
                  out["retrieval"], out["candidates"], config, seed=cfg.root_seed, jobs=1)
    return time.perf_counter() - t0


def run_score(paths: JobPaths, cfg: EvalConfig, estimator: str, walls: StageTimes) -> float:
    """Score one estimator's retrieval into its scores partition, with the wall time of every stage
    (:func:`with_stage_times`): those of ``walls`` (stage -> s, the earlier stages) and the score's own, which is
    also returned (s) and set in ``walls``."""
    t0 = time.perf_counter()
    inputs = paths.inputs(_SCORE, estimator)

    def timed(table: pa.Table) -> pa.Table:
        walls["score"] = time.perf_counter() - t0
        return with_stage_times(table, walls)

    score_file(inputs["retrieval"], inputs["segments"], paths.reads(_SCORE, estimator)["runs"],
               paths.outputs(_SCORE, estimator)["scores"], seed=cfg.root_seed,
               diagnostics_path=inputs["diagnostics"], amend=timed)
    return walls["score"]


def with_stage_times(table: pa.Table, walls: Mapping[str, float | None]) -> pa.Table:
    """Scores + one ``stage_<name>_s`` column per stage (seconds, null if unknown); ``wall_s`` = the sum of the
    known ones."""
    n = table.num_rows
    for s in STAGES:
        v = walls.get(s)
        table = table.append_column(f"stage_{s}_s", pa.array([v] * n, pa.float64()))
    total = float(sum(v for s, v in walls.items() if s in STAGES and v is not None))
    i = table.column_names.index("wall_s")
    return table.set_column(i, "wall_s", pa.array([total] * n, pa.float64()))


def stored_stage_s(scores_files: Iterable[Path]) -> StageTimes:
    """Stage -> wall time (s) recorded in the first existing, readable file of ``scores_files`` (its
    ``stage_<name>_s`` columns, first row); the stages it has no finite value for are left out; {} when none is
    there. A file that is not Parquet (a damaged output the resume rebuilds anyway) lends no time."""
    for path in scores_files:
        if optional_file(path, "the scores file") is None:
            continue
        try:
            names = set(pq.read_schema(path).names)
            cols = [c for c in STAGE_COLUMNS if c in names]
            row = pq.read_table(path, columns=cols).slice(0, 1).to_pylist()
        except (pa.ArrowInvalid, OSError):
            continue
        if not row:
            continue
        return {s: float(v) for s, c in zip(STAGES, STAGE_COLUMNS)
                if (v := row[0].get(c)) is not None and math.isfinite(v)}
    return {}
