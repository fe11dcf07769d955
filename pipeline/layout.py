"""Where an evaluation directory keeps its files: one Parquet file per (scene, seed[, method[, estimator]]).

::

    DIR/evaluation.json                                     what the directory was made with (root seed, ...)
    DIR/runs/FB-003.parquet                                 collect   (shared by every method of the seed)
    DIR/contacts/scene=FB/seed=3/part.parquet               isolate   (shared too)
    DIR/tracks/scene=FB/seed=3/method=stucco/part.parquet   track     (+ DIR/diagnostics/...)
    DIR/segments/scene=FB/seed=3/method=stucco/part.parquet segment
    DIR/retrieval/FB-003-stucco-plausible.parquet           retrieve (+ DIR/candidates/scene=.../estimator=...)
    DIR/scores/FB-003-stucco-plausible.parquet              score (a finished job)
    DIR/figures/FB-003.png, DIR/summary.png, DIR/report.md, DIR/report.csv

Tables that carry their keys as columns (runs, retrieval, scores: :data:`FLAT`) are flat files named by their
keys; the others are hive-partitioned, so their keys come from the path. Either way every kind directory opens
with no extra arguments (``pyarrow.parquet.read_table(DIR/kind)``, ``pyarrow.dataset.dataset(DIR/kind,
partitioning="hive")``, pandas, DuckDB): a hive directory over a table that also holds the key would give that
column two clashing types (string vs dictionary, int64 vs int32). Any stage can be rerun alone with the normal
CLI on a partition's files (docs/evaluation.md, "The output directory"); ``DIR/runs`` is a directory of run files
like ``stucco collect --out`` writes.

This module only names paths: it imports no stage and not the evaluation driver (:mod:`pipeline.evaluate`), so
:mod:`pipeline.figures`, which the driver calls, can use it without an import cycle.
"""
from __future__ import annotations

from pathlib import Path

from pipeline.registry import DEFAULT_ESTIMATOR

__all__ = ["KINDS", "SHARED", "PER_ESTIMATOR", "FLAT", "LAYOUT_VERSION", "PART", "WALL", "CONFIG", "LOCK", "STAGE_KIND",
           "STAGES", "partition", "wall_path", "job_paths"]

#: Table kinds kept under DIR, in pipeline order; the first two are per (scene, seed), the rest per method too.
KINDS = ("runs", "contacts", "tracks", "diagnostics", "segments", "retrieval", "candidates", "scores")
#: Kinds kept per (scene, seed) only: every method of a seed reads the same collected run and contacts.
SHARED = ("runs", "contacts")
#: Kinds kept per pose estimator too (``estimator=`` partition level).
PER_ESTIMATOR = ("retrieval", "candidates", "scores")
#: Kinds whose tables hold their keys (scene, seed[, method, estimator]) as columns: flat files named by the keys.
FLAT = ("runs", "retrieval", "scores")
#: Version of this layout, kept in ``evaluation.json``: a directory made with another one is refused, not mixed.
LAYOUT_VERSION = 2
#: File name of every hive partition.
PART = "part.parquet"
#: Side file of a partition with its stage's wall time (beside a hive partition; under ``_wall_s/`` for a flat
#: file); readers skip names starting with ``_`` and only read ``*.parquet``.
WALL = "_wall_s.json"
#: What the directory was made with (:class:`pipeline.evaluate.EvalConfig`), checked on resume.
CONFIG = "evaluation.json"
#: Lock file held by the one evaluation writing the directory (:func:`pipeline.atomic.exclusive`).
LOCK = ".evaluate.lock"
#: Stage name -> the kind whose partition holds its wall time, in pipeline order.
STAGE_KIND = {"collect": "runs", "isolate": "contacts", "track": "tracks", "segment": "segments",
              "retrieve": "retrieval", "score": "scores"}
#: The stages of a job, in the order they run.
STAGES = tuple(STAGE_KIND)


def partition(out: str | Path, kind: str, scene: str, seed: int, method: str | None = None,
              estimator: str = DEFAULT_ESTIMATOR) -> Path:
    """The file of one partition: ``out/kind/S-NNN[-M[-E]].parquet`` for a :data:`FLAT` kind, else
    ``out/kind/scene=S/seed=N[/method=M[/estimator=E]]/part.parquet``."""
    if kind not in KINDS:
        raise ValueError(f"unknown kind {kind!r}; expected one of {', '.join(KINDS)}")
    if kind not in SHARED and method is None:
        raise ValueError(f"{kind} is per method; pass method=")
    keys = [f"scene={scene}", f"seed={int(seed)}"]
    if kind not in SHARED:
        keys.append(f"method={method}")
    if kind in PER_ESTIMATOR:
        keys.append(f"estimator={estimator}")
    if kind in FLAT:
        # the same name as `stucco collect` gives a run file, then the method and estimator
        return Path(out) / kind / ("-".join([scene, f"{int(seed):03d}", *(k.split("=", 1)[1] for k in keys[2:])])
                                   + ".parquet")
    return Path(out).joinpath(kind, *keys, PART)


def wall_path(path: Path) -> Path:
    """The side file holding the wall time of the stage that wrote partition file ``path``."""
    path = Path(path)
    return path.parent / WALL if path.name == PART else path.parent / "_wall_s" / f"{path.stem}.json"


def job_paths(out: Path, job, estimator: str = DEFAULT_ESTIMATOR) -> dict[str, Path]:
    """Kind -> partition file of one job (anything with ``scene``, ``seed`` and ``method``, e.g. a
    :class:`pipeline.evaluate.Job`); the per-estimator kinds are those of ``estimator``."""
    return {k: partition(out, k, job.scene, job.seed, None if k in SHARED else job.method, estimator)
            for k in KINDS}
