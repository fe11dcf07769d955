"""Where an evaluation directory keeps its files: one Parquet file per hive partition of each table kind.

::

    DIR/evaluation.json                                     what the directory was made with (root seed, ...)
    DIR/runs/scene=FB/seed=3/part.parquet                   collect   (shared by every method of the seed)
    DIR/contacts/scene=FB/seed=3/part.parquet               isolate   (shared too)
    DIR/tracks/scene=FB/seed=3/method=stucco/part.parquet   track     (+ DIR/diagnostics/...)
    DIR/segments/scene=FB/seed=3/method=stucco/part.parquet segment
    DIR/retrieval/scene=FB/seed=3/method=stucco/estimator=plausible/part.parquet  retrieve (+ DIR/candidates/...)
    DIR/scores/scene=FB/seed=3/method=stucco/estimator=plausible/part.parquet     score (a finished job)
    DIR/figures/FB-003.png, DIR/summary.png, DIR/report.md, DIR/report.csv

Any stage can be rerun alone with the normal CLI on a partition's files, e.g. ``stucco --seed 0 segment --in
DIR/tracks/scene=FB/seed=3/method=stucco/part.parquet --out DIR/segments/.../part.parquet`` (docs/evaluation.md,
"The output directory").

This module only names paths: it imports no stage and not the evaluation driver (:mod:`pipeline.evaluate`), so
:mod:`pipeline.figures`, which the driver calls, can use it without an import cycle.
"""
from __future__ import annotations

from pathlib import Path

from pipeline.retrieve.estimators import DEFAULT_ESTIMATOR

__all__ = ["KINDS", "SHARED", "PER_ESTIMATOR", "PART", "WALL", "CONFIG", "STAGE_KIND", "STAGES", "partition",
           "job_paths"]

#: Table kinds kept under DIR, in pipeline order; the first two are per (scene, seed), the rest per method too.
KINDS = ("runs", "contacts", "tracks", "diagnostics", "segments", "retrieval", "candidates", "scores")
#: Kinds kept per (scene, seed) only: every method of a seed reads the same collected run and contacts.
SHARED = ("runs", "contacts")
#: Kinds kept per pose estimator too (``estimator=`` partition level).
PER_ESTIMATOR = ("retrieval", "candidates", "scores")
#: File name of every partition.
PART = "part.parquet"
#: Side file of a partition with its stage's wall time; pyarrow datasets and the stages only read ``*.parquet``.
WALL = "_wall_s.json"
#: What the directory was made with (:class:`pipeline.evaluate.EvalConfig`), checked on resume.
CONFIG = "evaluation.json"
#: Stage name -> the kind whose partition holds its wall time, in pipeline order.
STAGE_KIND = {"collect": "runs", "isolate": "contacts", "track": "tracks", "segment": "segments",
              "retrieve": "retrieval", "score": "scores"}
#: The stages of a job, in the order they run.
STAGES = tuple(STAGE_KIND)


def partition(out: str | Path, kind: str, scene: str, seed: int, method: str | None = None,
              estimator: str = DEFAULT_ESTIMATOR) -> Path:
    """The file of one partition: ``out/kind/scene=S/seed=N[/method=M[/estimator=E]]/part.parquet``."""
    if kind not in KINDS:
        raise ValueError(f"unknown kind {kind!r}; expected one of {', '.join(KINDS)}")
    p = Path(out) / kind / f"scene={scene}" / f"seed={int(seed)}"
    if kind not in SHARED:
        if method is None:
            raise ValueError(f"{kind} is per method; pass method=")
        p = p / f"method={method}"
    if kind in PER_ESTIMATOR:
        p = p / f"estimator={estimator}"
    return p / PART


def job_paths(out: Path, job, estimator: str = DEFAULT_ESTIMATOR) -> dict[str, Path]:
    """Kind -> partition file of one job (anything with ``scene``, ``seed`` and ``method``, e.g. a
    :class:`pipeline.evaluate.Job`); the per-estimator kinds are those of ``estimator``."""
    return {k: partition(out, k, job.scene, job.seed, None if k in SHARED else job.method, estimator)
            for k in KINDS}
