"""The ``evaluate`` stage: the (scene, seed, method) grid of the paper's Table II, end to end, resumable.

Every job runs collect -> isolate -> track -> segment -> retrieve -> score by calling the stage functions (the
same calls, parameters and metadata as the CLI), and keeps each stage's table under a hive-partitioned output
directory, one file per partition::

    DIR/evaluation.json                                     what the directory was made with (root seed, ...)
    DIR/runs/scene=FB/seed=3/part.parquet                   collect   (shared by every method of the seed)
    DIR/contacts/scene=FB/seed=3/part.parquet               isolate   (shared too)
    DIR/tracks/scene=FB/seed=3/method=stucco/part.parquet   track     (+ DIR/diagnostics/...)
    DIR/segments/scene=FB/seed=3/method=stucco/part.parquet segment
    DIR/retrieval/scene=FB/seed=3/method=stucco/estimator=plausible/part.parquet  retrieve (+ DIR/candidates/...)
    DIR/scores/scene=FB/seed=3/method=stucco/estimator=plausible/part.parquet     score (a finished job)
    DIR/figures/FB-003.png, DIR/summary.png, DIR/report.md, DIR/report.csv

Each kind directory is a Parquet dataset: :func:`read_kind` (``pyarrow.dataset`` with an explicit hive
partitioning schema, since ``seed`` would otherwise be inferred as int32 and clash with the files' int64).
Any stage can be rerun alone with the normal CLI on a partition's files, e.g. ``stucco --seed 0 segment --in
DIR/tracks/scene=FB/seed=3/method=stucco/part.parquet --out DIR/segments/.../part.parquet``.

Jobs are pure functions of (root seed, scene, seed, method, :class:`EvalConfig`): every random stream comes from
the stages' own ``SeedSequence`` derivations (collect: ``[root, scene_hash(scene), seed]``; track:
``[root, run_key(run)]``; retrieve: ``[root, run_key(run), sha256("retrieve")]``), so all methods of a seed see
the same collected run (actions, noise), results do not depend on ``jobs`` or on the order of jobs (up to the
last bits of Open3D's ICP, which vary from run to run anyway), and a stage rerun with ``stucco --seed ROOT
<stage>`` reproduces its file (byte for byte for isolate, track and segment). Outputs are written atomically
(:func:`pipeline.schema.write_table`).

**Resuming** works like ``make`` on recorded digests: an output is up to date when it exists and the SHA-256 of
every input recorded in its metadata (``stucco.inputs``) matches the current input file. A job runs its first
out-of-date stage and everything after it; a job whose scores are up to date is skipped. Deleting a file, or
rewriting it with other content, reruns its stage and every later one; a byte-identical rewrite (a CLI rerun of
a deterministic stage) reruns nothing.

**Wall times**: each stage's wall time goes to a ``_wall_s.json`` beside its file (ignored by pyarrow datasets
and by the stages, which only read ``*.parquet``), and the scores table gets ``stage_<name>_s`` columns and
``wall_s`` = their sum, the time to produce the run from nothing (collect and isolate, shared by the methods of a
seed, are counted in each).
"""
from __future__ import annotations

import json
import math
import os
import shutil
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import pyarrow as pa

from pipeline import schema
from pipeline.report import METHOD_ORDER
from pipeline.retrieve.estimators import DEFAULT_ESTIMATOR, ESTIMATORS

__all__ = ["SCENES", "METHODS", "KINDS", "QUICK_SCENES", "QUICK_SEEDS", "STAGE_COLUMNS", "EvalConfig", "Job",
           "JobResult", "Evaluation", "parse_scenes", "parse_methods", "partition", "stale_stages",
           "prepare_run", "run_job", "evaluate", "read_kind", "gather_scores", "write_report", "snapshot",
           "write_snapshot", "SNAPSHOT_SCORE_COLUMNS", "single_threaded", "BACKENDS", "parallel_backend"]

#: The paper's Table II tasks, in its order.
SCENES = ("FB", "BC", "IB", "TC")
#: STUCCO and the baselines, in the order of Table II.
METHODS = METHOD_ORDER
#: Table kinds kept under DIR, in pipeline order; the first two are per (scene, seed), the rest per method too.
KINDS = ("runs", "contacts", "tracks", "diagnostics", "segments", "retrieval", "candidates", "scores")
_SHARED = ("runs", "contacts")
#: Kinds kept per pose estimator too (``estimator=`` partition level).
_PER_ESTIMATOR = ("retrieval", "candidates", "scores")
PART = "part.parquet"
WALL = "_wall_s.json"
CONFIG = "evaluation.json"
#: `stucco evaluate --quick`: a couple of seeds of one scene.
QUICK_SCENES = ("FB",)
QUICK_SEEDS = (0, 1)
#: Stage name -> the kind whose partition holds its wall time.
_STAGE_KIND = {"collect": "runs", "isolate": "contacts", "track": "tracks", "segment": "segments",
               "retrieve": "retrieval", "score": "scores"}
STAGES = tuple(_STAGE_KIND)
#: Columns the evaluation adds to the scores table (seconds of wall time per stage; null if unknown).
STAGE_COLUMNS = tuple(f"stage_{s}_s" for s in STAGES)


@dataclass(frozen=True)
class EvalConfig:
    """What an evaluation directory is made with; stored in ``DIR/evaluation.json``, checked on resume.

    Attributes
    ----------
    root_seed : int
        Root of every job's SeedSequence (the CLI's ``--seed``).
    max_actions : int or None
        Cut every scripted run after this many actions (short test grids); None = the whole sequence.
    restarts : int
        ICP restarts per segment (30, the paper's).
    grasp : bool
        Simulate the grasp (grasp success is null without it).
    robot : str
        Gripper grid for tracking and retrieval.
    source : str or None
        Directory of stored run files replayed instead of simulating (``--from-runs``); None = simulate.
    estimators : tuple of str
        Pose estimators run on every job's segments (:data:`pipeline.retrieve.ESTIMATORS`), each into its own
        ``estimator=`` partition; the report shows them side by side.
    """

    root_seed: int = 0
    max_actions: int | None = None
    restarts: int = 30
    grasp: bool = True
    robot: str = "panda"
    source: str | None = None
    estimators: tuple[str, ...] = ESTIMATORS

    def __post_init__(self) -> None:
        object.__setattr__(self, "estimators", tuple(self.estimators))
        bad = [e for e in self.estimators if e not in ESTIMATORS]
        if not self.estimators or bad:
            raise ValueError(f"unknown estimator {bad[0] if bad else ''!r}; expected some of {', '.join(ESTIMATORS)}")
        if self.max_actions is not None and self.max_actions < 1:
            raise ValueError(f"max_actions must be a positive integer, got {self.max_actions!r}")
        if self.restarts < 2:
            raise ValueError(f"restarts must be at least 2, got {self.restarts!r}")

    def to_dict(self) -> dict[str, Any]:
        return dict(asdict(self), estimators=list(self.estimators))


@dataclass(frozen=True, order=True)
class Job:
    """One cell of the grid: a run of ``scene`` with ``seed``, tracked by ``method``."""

    scene: str
    seed: int
    method: str

    def __str__(self) -> str:
        return f"{self.scene}/{self.seed}/{self.method}"


@dataclass
class JobResult:
    """What a job did: the stages it (re)ran, in order (empty: skipped, already up to date)."""

    job: Job
    ran: tuple[str, ...]
    wall_s: float


@dataclass
class Evaluation:
    """The outcome of :func:`evaluate`."""

    out: Path
    jobs: list[Job]
    results: list[JobResult]
    scores: pa.Table
    prepared: list[tuple[str, int, tuple[str, ...]]] = field(default_factory=list)
    wall_s: float = 0.0

    @property
    def skipped(self) -> int:
        return sum(1 for r in self.results if not r.ran)


# ---------------------------------------------------------------------------------------------------------------
# Grid and paths
# ---------------------------------------------------------------------------------------------------------------


def _split(text: str) -> list[str]:
    return [p.strip() for p in str(text).split(",") if p.strip()]


def parse_scenes(text: str) -> tuple[str, ...]:
    """``"FB,BC"`` or ``"all"`` -> scene names; ValueError (one line) for a scene that cannot be evaluated.

    A scene can be evaluated when it has a scripted action sequence and a target (``kind = "retrieval"``).
    """
    from pipeline.scenes import SceneError, load_scene, scene_names

    names = _split(text)
    if not names:
        raise ValueError("no scene given; expected a comma-separated list such as FB,BC,IB,TC or 'all'")
    if names == ["all"]:
        return SCENES
    out: list[str] = []
    for n in names:
        try:
            sc = load_scene(n)
        except SceneError:
            raise ValueError(f"unknown scene {n!r}; expected some of {', '.join(scene_names())} "
                             f"(retrieval tasks: {', '.join(SCENES)})") from None
        if sc.actions is None or sc.target is None:
            raise ValueError(f"scene {n!r} is a training scene (no scripted actions or no target); "
                             f"evaluate retrieval tasks: {', '.join(SCENES)}")
        if sc.name not in out:
            out.append(sc.name)
    return tuple(out)


def parse_methods(text: str) -> tuple[str, ...]:
    """``"stucco,kmeans"`` or ``"all"`` -> method names in Table II order; ValueError for an unknown one."""
    names = _split(text)
    if not names:
        raise ValueError(f"no method given; expected some of {', '.join(METHODS)} or 'all'")
    if names == ["all"]:
        return METHODS
    bad = [n for n in names if n not in METHODS]
    if bad:
        raise ValueError(f"unknown method {bad[0]!r}; expected some of {', '.join(METHODS)} or 'all'")
    return tuple(m for m in METHODS if m in names)


def partition(out: str | Path, kind: str, scene: str, seed: int, method: str | None = None,
              estimator: str = DEFAULT_ESTIMATOR) -> Path:
    """The file of one partition: ``out/kind/scene=S/seed=N[/method=M[/estimator=E]]/part.parquet``."""
    if kind not in KINDS:
        raise ValueError(f"unknown kind {kind!r}; expected one of {', '.join(KINDS)}")
    p = Path(out) / kind / f"scene={scene}" / f"seed={int(seed)}"
    if kind not in _SHARED:
        if method is None:
            raise ValueError(f"{kind} is per method; pass method=")
        p = p / f"method={method}"
    if kind in _PER_ESTIMATOR:
        p = p / f"estimator={estimator}"
    return p / PART


def _paths(out: Path, job: Job, estimator: str = DEFAULT_ESTIMATOR) -> dict[str, Path]:
    return {k: partition(out, k, job.scene, job.seed, None if k in _SHARED else job.method, estimator)
            for k in KINDS}


# ---------------------------------------------------------------------------------------------------------------
# Freshness (make on recorded digests)
# ---------------------------------------------------------------------------------------------------------------


class _Digests:
    """SHA-256 of files, each computed once per check."""

    def __init__(self) -> None:
        self._d: dict[Path, str] = {}

    def __call__(self, path: Path) -> str | None:
        if path not in self._d:
            if not path.is_file():
                return None
            self._d[path] = schema.file_digest(path)
        return self._d[path]


def _up_to_date(path: Path, inputs: dict[str, Path], digest: _Digests) -> bool:
    """``path`` exists and records exactly the current digest of each of ``inputs`` (role -> file)."""
    if not path.is_file():
        return False
    try:
        recorded = schema.read_metadata(path).get("inputs") or {}
    except schema.SchemaError:
        return False
    for role, src in inputs.items():
        d = digest(src)
        if d is None or (recorded.get(role) or {}).get("sha256") != d:
            return False
    return True


def _stage_inputs(p: dict[str, Path]) -> dict[str, tuple[tuple[str, dict[str, Path]], ...]]:
    """Stage -> ((output kind, {role: input file}), ...) as the stages record them."""
    return {
        "collect": (("runs", {}),),
        "isolate": (("contacts", {"part": p["runs"]}),),
        "track": (("diagnostics", {"contacts": p["contacts"]}), ("tracks", {"contacts": p["contacts"]})),
        "segment": (("segments", {"tracks": p["tracks"]}),),
        "retrieve": (("candidates", {"segments": p["segments"]}), ("retrieval", {"segments": p["segments"]})),
        "score": (("scores", {"retrieval": p["retrieval"], "segments": p["segments"],
                              "diagnostics": p["diagnostics"]}),),
    }


def stale_stages(out: str | Path, job: Job, estimators: Sequence[str] = (DEFAULT_ESTIMATOR,)) -> tuple[str, ...]:
    """The stages of ``job`` to (re)run: the first whose outputs (for any of ``estimators``) are missing or out
    of date, and all after it.

    Empty when the job is finished (its scores are up to date with the whole chain, for every estimator).
    """
    digest = _Digests()
    first = len(STAGES)
    for est in estimators:
        p = _paths(Path(out), job, est)
        for i, (stage, outputs) in enumerate(_stage_inputs(p).items()):
            if i >= first:
                break
            if not all(_up_to_date(p[kind], inputs, digest) for kind, inputs in outputs):
                first = i
                break
    return STAGES[first:]


# ---------------------------------------------------------------------------------------------------------------
# Stages (the CLI's calls and metadata)
# ---------------------------------------------------------------------------------------------------------------


def _write_wall(path: Path, seconds: float) -> None:
    side = path.parent / WALL
    tmp = side.with_name(f".{WALL}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps({"wall_s": round(float(seconds), 6)}))
    os.replace(tmp, side)


def _read_wall(path: Path) -> float | None:
    try:
        v = json.loads((path.parent / WALL).read_text())["wall_s"]
        return float(v) if math.isfinite(float(v)) else None
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _collect(scene_name: str, seed: int, cfg: EvalConfig, dest: Path) -> None:
    from pipeline.collect import RUN_KIND, collect_run, output_path
    from pipeline.scenes import load_scene

    t0 = time.perf_counter()
    if cfg.source is not None:
        src = output_path(cfg.source, scene_name, seed)
        if not src.is_file():
            raise FileNotFoundError(f"{src}: no stored run for {scene_name} seed {seed}")
        dest.parent.mkdir(parents=True, exist_ok=True)
        tmp = dest.with_name(f".{dest.name}.{os.getpid()}.tmp")
        shutil.copyfile(src, tmp)
        os.replace(tmp, dest)
        wall = None
    else:
        table, params, _ = collect_run(load_scene(scene_name), seed, root_seed=cfg.root_seed, policy="scripted",
                                       max_actions=cfg.max_actions)
        schema.write_table(table, dest, stage="collect", params=params, seed=cfg.root_seed, kind=RUN_KIND)
        wall = time.perf_counter() - t0
    if wall is None:
        (dest.parent / WALL).unlink(missing_ok=True)
    else:
        _write_wall(dest, wall)


def _isolate(runs: Path, dest: Path, cfg: EvalConfig) -> None:
    from pipeline.isolate import DetectionParams, IsolationParams, isolate_runs, params_dict

    t0 = time.perf_counter()
    det, iso = DetectionParams(), IsolationParams()
    res = isolate_runs([runs], det, iso)
    params = params_dict(det, iso)
    params["isolation_error"] = res.error_summary()
    params["counts"] = {"runs": res.n_runs, "actions": res.n_actions, "in_contact": res.n_contact,
                        "unisolated": res.n_unisolated}
    schema.write_table(res.table, dest, stage="isolate", params=params, seed=cfg.root_seed,
                       inputs={runs.stem: runs}, kind="contacts")
    _write_wall(dest, time.perf_counter() - t0)


def _track(p: dict[str, Path], method: str, cfg: EvalConfig) -> None:
    from pipeline.track.stage import TrackConfig, track_file

    t0 = time.perf_counter()
    config = TrackConfig(method=method, robot=cfg.robot, params={}, every_step=False)
    track_file(p["contacts"], p["tracks"], config, seed=cfg.root_seed, jobs=1, diagnostics_path=p["diagnostics"])
    _write_wall(p["tracks"], time.perf_counter() - t0)


def _segment(p: dict[str, Path], cfg: EvalConfig) -> None:
    from pipeline.segment import segment_file

    t0 = time.perf_counter()
    segment_file(p["tracks"], p["segments"], seed=cfg.root_seed, by="auto")
    _write_wall(p["segments"], time.perf_counter() - t0)


def _retrieve(p: dict[str, Path], method: str, cfg: EvalConfig, estimator: str) -> None:
    from pipeline.grasp import GraspParams
    from pipeline.retrieve import PlausibleParams, RetrievalParams, retrieval_metadata, retrieve

    t0 = time.perf_counter()
    segments = schema.read_segments(p["segments"])
    params = RetrievalParams(n_restarts=cfg.restarts, robot=cfg.robot)
    plausible = PlausibleParams()
    gparams = GraspParams()
    table, candidates = retrieve(segments, p["runs"].parent, method=method, root_seed=cfg.root_seed, params=params,
                                 grasp=cfg.grasp, grasp_params=gparams, jobs=1, segments_path=str(p["segments"]),
                                 estimator=estimator, plausible_params=plausible)
    meta = retrieval_metadata(estimator, params, plausible, method=method, grasp=cfg.grasp, grasp_params=gparams)
    inputs = {"segments": p["segments"]}
    schema.write_table(candidates, p["candidates"], stage="retrieve", params=meta, seed=cfg.root_seed,
                       inputs=inputs, kind="candidates")
    schema.write_table(table, p["retrieval"], stage="retrieve", params=meta, seed=cfg.root_seed, inputs=inputs,
                       kind="retrieval")
    _write_wall(p["retrieval"], time.perf_counter() - t0)


def _score(p: dict[str, Path], cfg: EvalConfig) -> None:
    from pipeline.retrieve import read_retrieval
    from pipeline.score import score

    t0 = time.perf_counter()
    retrieval = read_retrieval(p["retrieval"])
    segments = schema.read_segments(p["segments"])
    diagnostics = schema.read_diagnostics(p["diagnostics"])
    table = score(segments, retrieval, p["runs"].parent, diagnostics=diagnostics,
                  segments_path=str(p["segments"]), retrieval_path=str(p["retrieval"]))
    walls = {s: _read_wall(p[k]) for s, k in _STAGE_KIND.items() if s != "score"}
    walls["score"] = time.perf_counter() - t0
    table = _with_stage_times(table, walls)
    inputs = {"retrieval": p["retrieval"], "segments": p["segments"], "diagnostics": p["diagnostics"]}
    schema.write_table(table, p["scores"], stage="score", params={"runs": str(p["runs"].parent)},
                       seed=cfg.root_seed, inputs=inputs, kind="scores")


def _with_stage_times(table: pa.Table, walls: dict[str, float | None]) -> pa.Table:
    """Scores + one ``stage_<name>_s`` column per stage; ``wall_s`` = the sum of the known ones."""
    n = table.num_rows
    for s in STAGES:
        v = walls.get(s)
        table = table.append_column(f"stage_{s}_s", pa.array([v] * n, pa.float64()))
    total = float(sum(v for v in walls.values() if v is not None))
    i = table.column_names.index("wall_s")
    return table.set_column(i, "wall_s", pa.array([total] * n, pa.float64()))


# ---------------------------------------------------------------------------------------------------------------
# Jobs
# ---------------------------------------------------------------------------------------------------------------


@contextmanager
def single_threaded():
    """Run the job's numeric libraries on one thread each (numba, OpenMP, BLAS), restoring them afterwards.

    Parallelism is over jobs. The tracker's numba kernels and scikit-learn's k-means parallelise problems of a
    few hundred points, where OpenMP threads only spin: measured on the 2-core machine beside one busy process,
    one FB run of k-means tracking took 5-13 s with 2 OpenMP threads and 0.2 s with one (STUCCO 1.9 s and
    0.03 s). ``threadpool_limits`` only reaches libraries already loaded, hence the imports first. Open3D's
    ICP (which ships its own TBB, beyond these limits) still gives poses that vary in the last bits from one run
    to the next, whatever ``jobs`` is (measured; tests/test_regression.py states the tolerance).
    """
    import numba

    # numba's threading layer first: started after Open3D has loaded its older TBB, numba warns that it cannot
    # use TBB (and falls back to OpenMP anyway).
    prev = numba.get_num_threads()
    import open3d  # noqa: F401  (any OpenMP runtime it brings)
    import sklearn.cluster  # noqa: F401  (scikit-learn's OpenMP runtime)
    from threadpoolctl import threadpool_limits

    numba.set_num_threads(1)
    try:
        with threadpool_limits(1):
            yield
    finally:
        numba.set_num_threads(prev)


def prepare_run(out: str | Path, scene: str, seed: int, cfg: EvalConfig) -> tuple[str, ...]:
    """Collect and isolate one (scene, seed) unless up to date; returns the stages run."""
    out = Path(out)
    runs = partition(out, "runs", scene, seed)
    contacts = partition(out, "contacts", scene, seed)
    ran: list[str] = []
    if not runs.is_file():
        _collect(scene, seed, cfg, runs)
        ran.append("collect")
    if ran or not _up_to_date(contacts, {"part": runs}, _Digests()):
        with single_threaded():
            _isolate(runs, contacts, cfg)
        ran.append("isolate")
    return tuple(ran)


def run_job(out: str | Path, job: Job, cfg: EvalConfig) -> JobResult:
    """Bring one job up to date: run its stale stages in order (:func:`stale_stages`)."""
    out = Path(out)
    t0 = time.perf_counter()
    todo = stale_stages(out, job, cfg.estimators)
    if not todo:
        return JobResult(job, (), 0.0)
    p = _paths(out, job)
    try:
        with single_threaded():
            for stage in todo:
                if stage == "collect":
                    if not p["runs"].is_file():
                        _collect(job.scene, job.seed, cfg, p["runs"])
                elif stage == "isolate":
                    _isolate(p["runs"], p["contacts"], cfg)
                elif stage == "track":
                    _track(p, job.method, cfg)
                elif stage == "segment":
                    _segment(p, cfg)
                elif stage == "retrieve":
                    for est in cfg.estimators:
                        _retrieve(_paths(out, job, est), job.method, cfg, est)
                else:
                    for est in cfg.estimators:
                        _score(_paths(out, job, est), cfg)
    except Exception as e:
        e.add_note(f"in evaluation job {job} ({out})")
        raise
    return JobResult(job, tuple(todo), time.perf_counter() - t0)


def _check_config(out: Path, cfg: EvalConfig) -> None:
    path = out / CONFIG
    want = cfg.to_dict()
    if path.is_file():
        try:
            have = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise ValueError(f"{path}: unreadable ({e}); remove it or use another --out") from None
        diff = sorted(k for k in set(want) | set(have) if have.get(k) != want.get(k))
        if diff:
            k = diff[0]
            raise ValueError(f"{out}: was made with {k}={have.get(k)!r}, this evaluation asks for "
                             f"{k}={want.get(k)!r}; use another --out (or delete {out})")
        return
    out.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{CONFIG}.tmp")
    tmp.write_text(json.dumps(want, indent=1, sort_keys=True) + "\n")
    os.replace(tmp, path)


BACKENDS = ("loky", "dask")


@contextmanager
def parallel_backend(backend: str = "loky", scheduler: str | None = None):
    """Where :func:`_map` runs jobs: ``"loky"`` (local processes) or ``"dask"`` (joblib's Dask backend on the
    ``distributed`` scheduler at ``scheduler``, e.g. ``tcp://10.0.0.5:8786``; the optional extra
    ``stucco[dask]``). Job functions write their own files under the evaluation directory, so Dask workers
    must see the same filesystem path. Yields the ``jobs`` value to pass to :func:`_map` for Dask (-1: every
    worker of the cluster), or None for loky."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; expected one of {', '.join(BACKENDS)}")
    if backend == "loky":
        if scheduler is not None:
            raise ValueError("--scheduler applies to --backend dask only")
        yield None
        return
    if not scheduler:
        raise ValueError("--backend dask needs --scheduler ADDRESS (e.g. tcp://127.0.0.1:8786)")
    try:
        from distributed import Client
    except ImportError:
        raise ValueError("--backend dask needs the optional extra: pip install 'stucco[dask]'") from None
    from joblib import parallel_config

    with Client(scheduler) as client, parallel_config(backend="dask", wait_for_workers_timeout=60):
        client.wait_for_workers(1, timeout=60)
        yield -1


def _map(fn: Callable, args: list[tuple], jobs: int, bar) -> list:
    """fn(*a) for every a, in ``jobs`` processes (joblib/loky) or in this one; results in completion order.

    ``jobs == -1``: the active joblib backend decides (the Dask cluster's workers, :func:`parallel_backend`).
    """
    out = []
    if (jobs > 1 or jobs == -1) and len(args) > 1:
        from joblib import Parallel, delayed

        par = Parallel(n_jobs=-1 if jobs == -1 else min(jobs, len(args)), return_as="generator_unordered")
        for r in par(delayed(fn)(*a) for a in args):
            out.append(r)
            bar.update()
    else:
        for a in args:
            out.append(fn(*a))
            bar.update()
    return out


def _runs_in(source: Path) -> list[tuple[str, int]]:
    """(scene, seed) of every stored run file in ``source``."""
    from pipeline.retrieve import load_run, run_files_by_name

    pairs = []
    for _, path in sorted(run_files_by_name(source).items()):
        info = load_run(path)
        pairs.append((info.scene.name, info.seed))
    if not pairs:
        raise ValueError(f"{source}: no collected run files (*.parquet written by `stucco collect`)")
    return sorted(pairs)


def evaluate(out: str | Path, scenes: Sequence[str] | None, seeds: Sequence[int] | None, methods: Sequence[str],
             cfg: EvalConfig = EvalConfig(), *, jobs: int = 1, progress: bool | None = None,
             figures: bool = True, backend: str = "loky", scheduler: str | None = None) -> Evaluation:
    """Run (or resume) the grid and write the report.

    Parameters
    ----------
    out : path
        Evaluation directory (created; an existing one must have been made with the same ``cfg``).
    scenes, seeds : sequence
        The grid; with ``cfg.source`` (stored runs) None takes every (scene, seed) found there, and given values
        filter them.
    methods : sequence of str
    cfg : EvalConfig
    jobs : int
        Worker processes (joblib/loky) over (scene, seed) preparations, then over jobs, then figures.
    progress : bool or None
        tqdm's ``disable`` (True: no bars; None: bars on a TTY).
    figures : bool
        Draw a figure per (scene, seed) and the summary figure.
    backend, scheduler : str
        ``"loky"`` (``jobs`` local processes) or ``"dask"`` with the scheduler's address (every worker of the
        cluster; ``jobs`` is ignored): :func:`parallel_backend`.

    Returns
    -------
    Evaluation
    """
    with parallel_backend(backend, scheduler) as cluster_jobs:
        return _evaluate(out, scenes, seeds, methods, cfg, jobs=jobs if cluster_jobs is None else cluster_jobs,
                         progress=progress, figures=figures)


def _evaluate(out, scenes, seeds, methods, cfg, *, jobs, progress, figures) -> Evaluation:
    from tqdm import tqdm

    t0 = time.perf_counter()
    out = Path(out)
    methods = tuple(methods)
    if cfg.source is not None:
        pairs = [(sc, s) for sc, s in _runs_in(Path(cfg.source))
                 if (scenes is None or sc in scenes) and (seeds is None or s in seeds)]
        if not pairs:
            raise ValueError(f"{cfg.source}: no stored run matches the requested scenes and seeds")
    else:
        if scenes is None or seeds is None:
            raise ValueError("scenes and seeds are required unless runs are replayed from a directory")
        pairs = [(sc, int(s)) for sc in scenes for s in seeds]
    _check_config(out, cfg)
    job_list = [Job(sc, s, m) for sc, s in pairs for m in methods]

    need = [(out, sc, s, cfg) for sc, s in pairs if _run_stale(out, sc, s)]
    with tqdm(total=len(need), desc="collect+isolate", unit="run", disable=progress or not need) as bar:
        prepared = _map(_prepare_one, need, jobs, bar)
    todo = [(out, j, cfg) for j in job_list if stale_stages(out, j, cfg.estimators)]
    pending = {t[1] for t in todo}
    done = [JobResult(j, (), 0.0) for j in job_list if j not in pending]
    with tqdm(total=len(todo), desc="jobs", unit="job", disable=progress or not todo) as bar:
        results = done + _map(run_job, todo, jobs, bar)
    results.sort(key=lambda r: r.job)
    scores = gather_scores(out, job_list, cfg.estimators)
    write_report(out, scores)
    if figures:
        from pipeline.figures import figure_path, run_figure, summary_figure

        stale_figs = [(out, sc, s, methods, cfg.estimators[0]) for sc, s in pairs
                      if _figure_stale(figure_path(out, sc, s),
                                       [partition(out, "scores", sc, s, m, cfg.estimators[0]) for m in methods])]
        with tqdm(total=len(stale_figs), desc="figures", unit="fig", disable=progress or not stale_figs) as bar:
            _map(run_figure, stale_figs, jobs, bar)
        from pipeline.report import table_ii

        summary_figure(table_ii(scores), out / "summary.png")
    return Evaluation(out=out, jobs=job_list, results=results, scores=scores,
                      prepared=[p for p in prepared if p[2]], wall_s=time.perf_counter() - t0)


def _run_stale(out: Path, scene: str, seed: int) -> bool:
    runs = partition(out, "runs", scene, seed)
    return not runs.is_file() or not _up_to_date(partition(out, "contacts", scene, seed), {"part": runs}, _Digests())


def _prepare_one(out: Path, scene: str, seed: int, cfg: EvalConfig) -> tuple[str, int, tuple[str, ...]]:
    try:
        return scene, seed, prepare_run(out, scene, seed, cfg)
    except Exception as e:
        e.add_note(f"in evaluation run {scene}/{seed} ({out})")
        raise


def _figure_stale(png: Path, inputs: Iterable[Path]) -> bool:
    if not png.is_file():
        return True
    t = png.stat().st_mtime_ns
    return any(p.is_file() and p.stat().st_mtime_ns > t for p in inputs)


# ---------------------------------------------------------------------------------------------------------------
# Reading results
# ---------------------------------------------------------------------------------------------------------------


def _partitioning(kind: str):
    import pyarrow.dataset as ds

    fields = [("scene", pa.string()), ("seed", pa.int64())]
    if kind not in _SHARED:
        fields.append(("method", pa.string()))
    if kind in _PER_ESTIMATOR:
        fields.append(("estimator", pa.string()))
    return ds.partitioning(pa.schema(fields), flavor="hive")


def read_kind(out: str | Path, kind: str, filter=None) -> pa.Table:
    """Every partition of one kind under an evaluation directory as one table (``pyarrow.dataset``).

    Partition keys (scene, seed[, method[, estimator]]) are columns of the result (they already are of runs,
    retrieval and scores).
    ``filter`` is a ``pyarrow.dataset`` expression, e.g. ``ds.field("method") == "stucco"``.
    """
    import pyarrow.dataset as ds

    root = Path(out) / kind
    if kind not in KINDS:
        raise ValueError(f"unknown kind {kind!r}; expected one of {', '.join(KINDS)}")
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such directory; has the evaluation run?")
    return ds.dataset(root, format="parquet", partitioning=_partitioning(kind)).to_table(filter=filter)


def gather_scores(out: str | Path, job_list: Sequence[Job], estimators: Sequence[str] = (DEFAULT_ESTIMATOR,)
                  ) -> pa.Table:
    """The scores of the given jobs (those finished), one row per job and estimator, in grid order."""
    from pipeline.score import read_scores

    tables = []
    for j in sorted(job_list):
        for est in estimators:
            path = partition(out, "scores", j.scene, j.seed, j.method, est)
            if path.is_file():
                tables.append(read_scores(path))
    if not tables:
        from pipeline.score import SCORES_COLUMNS

        cols = [pa.field(c.name, c.type) for c in SCORES_COLUMNS] + [pa.field(c, pa.float64()) for c in STAGE_COLUMNS]
        return pa.schema(cols).empty_table()
    return pa.concat_tables(tables, promote_options="permissive")


def write_report(out: str | Path, scores: pa.Table) -> tuple[Path, Path]:
    """``out/report.md`` and ``out/report.csv`` (atomically) from a scores table."""
    from pipeline.report import claims, table_ii, to_csv, to_markdown

    rows = table_ii(scores)
    md = to_markdown(rows)
    notes = claims(rows)
    if notes:
        md += "\n" + "\n".join(f"- {n}" for n in notes) + "\n"
    paths = (Path(out) / "report.md", Path(out) / "report.csv")
    for path, text in zip(paths, (md, to_csv(rows))):
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_text(text)
        os.replace(tmp, path)
    return paths


# ---------------------------------------------------------------------------------------------------------------
# Regression snapshot
# ---------------------------------------------------------------------------------------------------------------

#: Score columns compared by the regression test (the others are wall times).
SNAPSHOT_SCORE_COLUMNS = ("scene", "seed", "method", "estimator", "run", "grasp_success", "fmi", "contact_error_cm",
                          "position_error_m", "yaw_error_rad", "low_confidence", "n_points", "n_segments")


def snapshot(out: str | Path, job_list: Sequence[Job], estimators: Sequence[str] = ESTIMATORS
             ) -> dict[str, pa.Table]:
    """What the regression test compares, as one table per kind, rows in grid order.

    ``contacts``: the isolate output of every (scene, seed); ``segments``: the track + segment output of every
    job, with a leading ``method`` column; ``scores``: :data:`SNAPSHOT_SCORE_COLUMNS` (no wall times).
    """
    out = Path(out)
    jobs_ = sorted(job_list)
    pairs = list(dict.fromkeys((j.scene, j.seed) for j in jobs_))
    contacts = pa.concat_tables([schema.read_contacts(partition(out, "contacts", sc, s)) for sc, s in pairs])
    segs = []
    for j in jobs_:
        t = schema.read_segments(partition(out, "segments", j.scene, j.seed, j.method))
        segs.append(t.add_column(0, "method", pa.array([j.method] * t.num_rows, pa.string())))
    segments = pa.concat_tables(segs)
    scores = gather_scores(out, jobs_, estimators).select(list(SNAPSHOT_SCORE_COLUMNS))
    return {"contacts": contacts, "segments": segments, "scores": scores}


def write_snapshot(out: str | Path, job_list: Sequence[Job], dest: str | Path, cfg: EvalConfig) -> list[Path]:
    """Write :func:`snapshot` to ``dest/<kind>.parquet`` (the expected results of ``data/regression``)."""
    dest = Path(dest)
    written = []
    for kind, table in snapshot(out, job_list, cfg.estimators).items():
        path = dest / f"{kind}.parquet"
        schema.write_table(table, path, stage="evaluate", params=dict(cfg.to_dict(), snapshot=kind),
                           seed=cfg.root_seed, kind=f"regression-{kind}")
        written.append(path)
    return written
