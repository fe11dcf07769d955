"""Where an evaluation directory keeps its files, and what each stage of a job reads and writes.

::

    DIR/evaluation.json                                     what the directory was made with (root seed, ...)
    DIR/runs/FB-003.parquet                                 collect   (shared by every method of the seed)
    DIR/contacts/scene=FB/seed=3/part.parquet               isolate   (shared too)
    DIR/tracks/scene=FB/seed=3/method=stucco/part.parquet   track     (+ DIR/diagnostics/...)
    DIR/segments/scene=FB/seed=3/method=stucco/part.parquet segment
    DIR/retrieval/FB-003-stucco-plausible.parquet           retrieve (+ DIR/candidates/scene=.../estimator=...)
    DIR/scores/FB-003-stucco-plausible.parquet              score (a finished job)
    DIR/figures/FB-003.png, DIR/summary.png, DIR/report.md, DIR/report.csv

**One rule for every table**: a table's path names exactly the keys (scene, seed[, method[, estimator]]) that its
files do not hold as columns. The tables that hold all their keys (runs, retrieval, scores: :data:`FLAT`) are
files named by the keys directly under their folder; the others are hive-partitioned on them. So every table
folder opens the same way, its keys as columns::

    duckdb:   SELECT * FROM read_parquet('DIR/<table>/**/*.parquet', hive_partitioning=true)
    pyarrow:  pyarrow.dataset.dataset('DIR/<table>', partitioning='hive').to_table()

A hive level over a key the files also hold cannot open with pyarrow: the path's ``seed`` is inferred as int32,
the file's is int64, and pyarrow refuses to merge them. No file in a table folder is anything but a partition:
a side file (a policy's, :attr:`pipeline.registry.PolicySpec.side_files`) starts with ``_``, which pyarrow skips
and the ``*.parquet`` glob never matches. Any stage can be rerun alone with the normal CLI on a partition's files
(docs/evaluation.md, "The output directory"); ``DIR/runs`` is a directory of run files like ``stucco collect
--out`` writes.

This module only names paths: it imports no stage and not the evaluation driver (:mod:`pipeline.evaluate`), so
:mod:`pipeline.figures`, which the driver calls, can use it without an import cycle.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from pipeline.registry import DEFAULT_ESTIMATOR

__all__ = ["KINDS", "SHARED", "PER_ESTIMATOR", "FLAT", "LAYOUT_VERSION", "PART", "CONFIG", "LOCK", "RUN_STEM",
           "StageSpec", "STAGE_SPECS", "STAGES", "stage_spec", "partition", "JobPaths", "job_paths",
           "run_paths"]

#: Table kinds kept under DIR, in pipeline order; the first two are per (scene, seed), the rest per method too.
KINDS = ("runs", "contacts", "tracks", "diagnostics", "segments", "retrieval", "candidates", "scores")
#: Kinds kept per (scene, seed) only: every method of a seed reads the same collected run and contacts.
SHARED = ("runs", "contacts")
#: Kinds kept per pose estimator too (``estimator=`` partition level).
PER_ESTIMATOR = ("retrieval", "candidates", "scores")
#: Kinds whose tables hold their keys (scene, seed[, method, estimator]) as columns: flat files named by the keys.
FLAT = ("runs", "retrieval", "scores")
#: Version of this layout, kept in ``evaluation.json``. 3: no wall-time side files (the scores hold the stage
#: times) and side files named ``_*``; a folder of layout 2 (the same tables) is migrated in place
#: (:mod:`pipeline.evaluate.migrate`), an older one refused.
LAYOUT_VERSION = 3
#: File name of every hive partition.
PART = "part.parquet"
#: What the directory was made with (:class:`pipeline.evaluate.EvalConfig`), checked on resume.
CONFIG = "evaluation.json"
#: Lock file held by the one evaluation writing the directory (:func:`pipeline.atomic.exclusive`).
LOCK = ".evaluate.lock"
#: Role of an input recorded under its file's stem (``isolate`` names each run file's role so).
RUN_STEM = "<stem>"


@dataclass(frozen=True)
class StageSpec:
    """What one stage of a job reads and writes, by kind: the one declaration the stage runner
    (:mod:`pipeline.evaluate.stages`) and the freshness check (:mod:`pipeline.evaluate.freshness`) both read.

    Attributes
    ----------
    name : str
        The stage (``stucco <name>``).
    outputs : tuple of str
        Kinds the stage writes (one file each per job, or per job and estimator).
    inputs : tuple of (role, kind)
        Files the stage records in its outputs' metadata (``stucco.inputs``) under ``role`` (:data:`RUN_STEM`:
        the file's stem); an output is up to date when these digests match the current files.
    reads : tuple of str
        Kinds the stage also reads without recording a digest (the run file, for its scene and ground truth).
    per_estimator : bool
        Run once per pose estimator, into that estimator's partitions.
    """

    name: str
    outputs: tuple[str, ...]
    inputs: tuple[tuple[str, str], ...] = ()
    reads: tuple[str, ...] = ()
    per_estimator: bool = False

    @property
    def shared(self) -> bool:
        """The stage writes per (scene, seed), once for every method (collect, isolate)."""
        return all(k in SHARED for k in self.outputs)


#: The stages of a job, in the order they run.
STAGE_SPECS: tuple[StageSpec, ...] = (
    StageSpec("collect", outputs=("runs",)),
    StageSpec("isolate", outputs=("contacts",), inputs=((RUN_STEM, "runs"),)),
    StageSpec("track", outputs=("tracks", "diagnostics"), inputs=(("contacts", "contacts"),)),
    StageSpec("segment", outputs=("segments",), inputs=(("tracks", "tracks"),)),
    StageSpec("retrieve", outputs=("retrieval", "candidates"), inputs=(("segments", "segments"),), reads=("runs",),
              per_estimator=True),
    StageSpec("score", outputs=("scores",), inputs=(("retrieval", "retrieval"), ("segments", "segments"),
                                                    ("diagnostics", "diagnostics")), reads=("runs",),
              per_estimator=True),
)
#: Stage names, in the order they run.
STAGES = tuple(s.name for s in STAGE_SPECS)


def stage_spec(name: str) -> StageSpec:
    """The :class:`StageSpec` of stage ``name``; ValueError for another name."""
    for s in STAGE_SPECS:
        if s.name == name:
            return s
    raise ValueError(f"unknown stage {name!r}; expected one of {', '.join(STAGES)}")


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


@dataclass(frozen=True)
class JobPaths:
    """Every partition file of one job (scene, seed, method), for each of its pose estimators; made once per job
    (:func:`job_paths`) and handed to the freshness check and the stage runner.

    ``files[estimator][kind]`` is a path (not to be changed); the kinds not in :data:`PER_ESTIMATOR` are the same
    file for every estimator. ``method`` None: only the files of a (scene, seed) shared by its methods
    (:func:`run_paths`).
    """

    scene: str
    seed: int
    method: str | None
    estimators: tuple[str, ...]
    files: Mapping[str, Mapping[str, Path]]

    def of(self, kind: str, estimator: str | None = None) -> Path:
        """The file of ``kind`` (of ``estimator``, default the first, for a per-estimator kind)."""
        return self.files[estimator or self.estimators[0]][kind]

    def __getitem__(self, kind: str) -> Path:
        return self.of(kind)

    def inputs(self, stage: StageSpec, estimator: str | None = None) -> dict[str, Path]:
        """Role -> file of the inputs ``stage`` records (a :data:`RUN_STEM` role named by the file's stem)."""
        out = {}
        for role, kind in stage.inputs:
            path = self.of(kind, estimator)
            out[path.stem if role == RUN_STEM else role] = path
        return out

    def outputs(self, stage: StageSpec, estimator: str | None = None) -> dict[str, Path]:
        """Kind -> file ``stage`` writes (for ``estimator``)."""
        return {kind: self.of(kind, estimator) for kind in stage.outputs}

    def reads(self, stage: StageSpec, estimator: str | None = None) -> dict[str, Path]:
        """Kind -> file ``stage`` reads without recording it."""
        return {kind: self.of(kind, estimator) for kind in stage.reads}


def job_paths(out: str | Path, job, estimators: Sequence[str] | str = (DEFAULT_ESTIMATOR,)) -> JobPaths:
    """The :class:`JobPaths` of one job (anything with ``scene``, ``seed`` and ``method``, e.g. a
    :class:`pipeline.evaluate.Job`) for ``estimators`` (one name or several); with ``method`` None, only the
    files of the (scene, seed) shared by its methods (:data:`SHARED`)."""
    estimators = (estimators,) if isinstance(estimators, str) else tuple(estimators)
    if not estimators:
        raise ValueError("job_paths needs at least one estimator")
    out = Path(out)
    kinds = SHARED if job.method is None else KINDS
    # plain dicts: a JobPaths goes to worker processes (pickled), which a mappingproxy cannot
    files = {est: {k: partition(out, k, job.scene, job.seed, None if k in SHARED else job.method, est)
                   for k in kinds}
             for est in estimators}
    return JobPaths(job.scene, int(job.seed), job.method, estimators, files)


@dataclass(frozen=True)
class _Run:
    scene: str
    seed: int
    method: None = None


def run_paths(out: str | Path, scene: str, seed: int) -> JobPaths:
    """The files of one (scene, seed) shared by its methods: the run and its contacts (:data:`SHARED`)."""
    return job_paths(out, _Run(scene, int(seed)))
