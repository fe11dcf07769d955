"""The ``evaluate`` stage: the (scene, seed, method) grid of the paper's Table II, end to end, resumable.

Every job runs collect -> isolate -> track -> segment -> retrieve -> score by calling the stage functions (the
same calls, parameters and metadata as the CLI), and keeps each stage's table in its own folder of the output
directory, one file per partition, so each folder opens as one table (:mod:`pipeline.layout`). One role per module
(docs/evaluation.md):

* :mod:`~pipeline.evaluate.config`: the grid's names, :class:`EvalConfig` (``DIR/evaluation.json``), :class:`Job`;
* :mod:`~pipeline.evaluate.freshness`: which stages of a job are out of date (``make`` on recorded digests, each
  file hashed once per call);
* :mod:`~pipeline.evaluate.stages`: each stage through its ``<stage>_file`` function, as the CLI runs it, on the
  files its :class:`~pipeline.layout.StageSpec` declares, returning its wall time;
* :mod:`~pipeline.evaluate.jobs`: a (scene, seed)'s run and a job brought up to date, with the stages' times;
* :mod:`~pipeline.evaluate.migrate`: a folder of the previous layout brought to this one;
* :mod:`~pipeline.evaluate.parallel`: joblib/loky or Dask across jobs, one thread per library inside one;
* :mod:`~pipeline.evaluate.run`: the driver, :func:`evaluate`;
* :mod:`~pipeline.evaluate.results`: reading a directory back, the scores of a grid, the report files;
* :mod:`~pipeline.evaluate.regression`: the regression snapshot.

Jobs are pure functions of (root seed, scene, seed, method, :class:`EvalConfig`): every random stream comes from
the stages' own ``SeedSequence`` derivations (collect: ``[root, scene_hash(scene), seed]``; track:
``[root, run_key(run)]``; retrieve: ``[root, run_key(run), sha256("retrieve")]``), so all methods of a seed see
the same collected run (actions, noise), results do not depend on ``jobs`` or on the order of jobs (up to the
last bits of Open3D's ICP, which vary from run to run anyway), and a stage rerun with ``stucco --seed ROOT
<stage>`` reproduces its file (byte for byte for isolate, track and segment). Outputs are written atomically
(:func:`pipeline.schema.write_table`).
"""
from pipeline.evaluate.config import (
    METHODS,
    QUICK_SCENES,
    QUICK_SEEDS,
    SCENES,
    EvalConfig,
    Job,
    config_lines,
    parse_methods,
    parse_scenes,
    scene_files,
)
from pipeline.evaluate.freshness import stale_stages
from pipeline.evaluate.jobs import JobResult, PreparedRun, prepare_run, run_job
from pipeline.evaluate.parallel import BACKENDS, parallel_backend, single_threaded
from pipeline.evaluate.regression import SNAPSHOT_SCORE_COLUMNS, snapshot, write_snapshot
from pipeline.evaluate.results import gather_scores, read_kind, write_report
from pipeline.evaluate.run import Evaluation, evaluate
from pipeline.evaluate.stages import STAGE_COLUMNS
from pipeline.layout import CONFIG, KINDS, PART, STAGE_SPECS, STAGES, JobPaths, StageSpec, job_paths, partition
from pipeline.parallel import map_jobs

__all__ = ["SCENES", "METHODS", "KINDS", "QUICK_SCENES", "QUICK_SEEDS", "STAGES", "STAGE_SPECS", "StageSpec",
           "STAGE_COLUMNS", "PART", "CONFIG", "EvalConfig", "Job", "JobPaths", "JobResult", "PreparedRun",
           "Evaluation", "parse_scenes", "scene_files", "parse_methods", "config_lines", "partition", "job_paths",
           "stale_stages", "prepare_run", "run_job", "evaluate", "read_kind",
           "gather_scores", "write_report", "snapshot", "write_snapshot", "SNAPSHOT_SCORE_COLUMNS", "single_threaded",
           "BACKENDS", "parallel_backend", "map_jobs"]
