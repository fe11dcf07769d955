"""The evaluation driver: the (scene, seed, method) grid run or resumed, then the report and the figures.

Order: every stale (scene, seed) is collected and isolated once (shared by its methods), then every stale job runs
(:func:`pipeline.evaluate.run_job`), then the report and the figures are written; each of the three phases is
spread over the workers of :func:`pipeline.evaluate.parallel_backend` (docs/evaluation.md, "Parallelism").
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import pyarrow as pa
from tqdm import tqdm

from pipeline import registry, schema
from pipeline.atomic import exclusive
from pipeline.collect import output_path
from pipeline.evaluate.config import EvalConfig, Job, check_config, config_lines
from pipeline.evaluate.freshness import Digests, figure_stale, job_stale_stages, shared_stale_stages
from pipeline.evaluate.jobs import JobResult, PreparedRun, prepare_one, run_job
from pipeline.evaluate.parallel import parallel_backend
from pipeline.evaluate.results import gather_scores, write_report
from pipeline.evaluate.stages import StageTimes, stored_stage_s
from pipeline.figures import drawn, figure_methods, figure_path, run_figure, summary_figure
from pipeline.layout import LOCK, STAGE_SPECS, JobPaths, job_paths, run_paths
from pipeline.parallel import map_jobs
from pipeline.probe.report import read_times
from pipeline.report import table_ii
from pipeline.retrieve import load_run, run_files_by_name
from pipeline.seeds import check_root_seed

__all__ = ["Evaluation", "evaluate"]

#: The stages a (scene, seed) shares between its methods, prepared before the jobs.
SHARED_STAGES = tuple(s.name for s in STAGE_SPECS if s.shared)


@dataclass
class Evaluation:
    """The outcome of :func:`evaluate`: the jobs of the grid, what each did, the gathered scores, the (scene,
    seed) runs prepared (with the stages run) and the wall time in seconds."""

    out: Path
    jobs: list[Job]
    results: list[JobResult]
    scores: pa.Table
    prepared: list[tuple[str, int, tuple[str, ...]]] = field(default_factory=list)
    wall_s: float = 0.0

    @property
    def skipped(self) -> int:
        """Jobs that were already up to date."""
        return sum(1 for r in self.results if not r.ran)


def _runs_in(source: Path, root_seed: int) -> list[tuple[str, int]]:
    """(scene, seed) of every stored run file in ``source``; ValueError naming a run collected with another root
    seed (its later stages would be made with ``root_seed``, and retrieval refuses such a run), or a run file whose
    name is not its run's (each job copies the file named after its scene and seed)."""
    pairs = []
    for _, path in sorted(run_files_by_name(source).items()):
        info = load_run(path)
        read_times(path)  # a policy's side file beside it, checked now rather than in the report after every job
        check_root_seed(path, schema.read_metadata(path), root_seed, "; replay it with `stucco --seed {seed} evaluate`")
        named = output_path(source, info.scene.name, info.seed)
        if Path(path).name != named.name:  # each job copies its stored run by this name
            raise ValueError(f"{path}: holds run {info.run}, which evaluate reads from {named.name}; rename it")
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
        cluster; ``jobs`` is ignored): :func:`~pipeline.evaluate.parallel_backend`.

    Returns
    -------
    Evaluation
    """
    with parallel_backend(backend, scheduler) as cluster_jobs:
        return _evaluate(out, scenes, seeds, methods, cfg, jobs=jobs if cluster_jobs is None else cluster_jobs,
                         progress=progress, figures=figures)


def _evaluate(out, scenes, seeds, methods, cfg, *, jobs, progress, figures) -> Evaluation:
    t0 = time.perf_counter()
    out = Path(out)
    methods = tuple(methods)
    if cfg.source is not None:
        pairs = [(sc, s) for sc, s in _runs_in(Path(cfg.source), cfg.root_seed)
                 if (scenes is None or sc in scenes) and (seeds is None or s in seeds)]
        if not pairs:
            raise ValueError(f"{cfg.source}: no stored run matches the requested scenes and seeds")
    else:
        if scenes is None or seeds is None:
            raise ValueError("scenes and seeds are required unless runs are replayed from a directory")
        pairs = [(sc, int(s)) for sc in scenes for s in seeds]
        _check_policy_needs(cfg, scenes)
    # One evaluation at a time per folder: two with different settings would otherwise interleave their
    # partitions and evaluation.json could describe settings the stored files were not made with.
    with exclusive(out, LOCK):
        check_config(out, cfg)
        job_list = [Job(sc, s, m) for sc, s in pairs for m in methods]

        # One pass over the files: every digest taken once (the prepare phase writes only files not hashed
        # yet: a missing run, and contacts, which are checked as outputs here), the stale stages handed on.
        digest = Digests()
        shared_todo = {(sc, s): shared_stale_stages(out, sc, s, digest, cfg.source, cfg.root_seed, cfg)
                       for sc, s in pairs}
        need = [(out, sc, s, cfg, todo) for (sc, s), todo in shared_todo.items() if todo]
        with tqdm(total=len(need), desc="collect+isolate", unit="run", disable=progress or not need) as bar:
            prepared = {(p.scene, p.seed): p for p in map_jobs(prepare_one, need, jobs, bar)}
        for (sc, s), todo_shared in shared_todo.items():
            if "collect" in todo_shared:  # a stored run copied again (--from-runs) was hashed before its copy
                digest.forget(run_paths(out, sc, s)["runs"])
        paths = {j: job_paths(out, j, cfg.estimators) for j in job_list}
        stale = {j: job_stale_stages(paths[j], digest) for j in job_list}
        known = _shared_times(job_list, paths, stale, prepared)
        todo = [(out, j, cfg, stale[j], paths[j], known[(j.scene, j.seed)]) for j in job_list if stale[j]]
        done = [JobResult(j, (), 0.0) for j in job_list if not stale[j]]
        with tqdm(total=len(todo), desc="jobs", unit="job", disable=progress or not todo) as bar:
            results = done + map_jobs(run_job, todo, jobs, bar)
        results.sort(key=lambda r: r.job)
        scores = gather_scores(out, job_list, cfg.estimators)
        # Runs of the active protocol add its probes to the report (docs/active.md).
        from pipeline.probe.report import probe_lines  # imported here: it reads the run files only when writing
        from pipeline.probe.summary import active_markdown, active_rows

        write_report(out, scores, tuple(config_lines(cfg)) + tuple(probe_lines(out, job_list)),
                     estimator_stream=cfg.estimator_stream, tail=active_markdown(active_rows(out, scores)))
        if figures:
            # The figures show the first pose estimator's estimate (the report's first GS column).
            first = cfg.estimators[0]
            # stale: older than a scores file it shows, or showing other panels than it would now (methods dropped)
            stale_figs = [(out, sc, s, methods, first) for sc, s in pairs
                          if figure_stale(figure_path(out, sc, s),
                                          [paths[Job(sc, s, m)].of("scores", first) for m in methods])
                          or drawn(figure_path(out, sc, s)) != {"methods": figure_methods(out, sc, s, methods, first),
                                                                "estimator": first}]
            with tqdm(total=len(stale_figs), desc="figures", unit="fig", disable=progress or not stale_figs) as bar:
                map_jobs(run_figure, stale_figs, jobs, bar)
            summary_figure(table_ii(scores), out / "summary.png")
        return Evaluation(out=out, jobs=job_list, results=results, scores=scores,
                          prepared=[(p.scene, p.seed, p.ran) for p in prepared.values() if p.ran],
                          wall_s=time.perf_counter() - t0)


def _shared_times(job_list: Sequence[Job], paths: dict[Job, JobPaths], stale: dict[Job, tuple[str, ...]],
                  prepared: dict[tuple[str, int], PreparedRun]) -> dict[tuple[str, int], StageTimes]:
    """(scene, seed) -> wall times (s) of its shared stages (collect, isolate) for the stale jobs: those of this
    call's preparation, else those the stored scores of any job of the seed record (another method's, when a
    method is added to the grid)."""
    known: dict[tuple[str, int], StageTimes] = {}
    for j in job_list:
        key = (j.scene, j.seed)
        if not stale[j] or key in known:
            continue
        ran = prepared[key].stage_s if key in prepared else {}
        times: StageTimes = {}
        if len(ran) < len(SHARED_STAGES):
            siblings = (paths[k].of("scores", e) for k in job_list if (k.scene, k.seed) == key
                        for e in paths[k].estimators)
            times = {s: v for s, v in stored_stage_s(siblings).items() if s in SHARED_STAGES}
        known[key] = {**times, **ran}
    return known


def _check_policy_needs(cfg: EvalConfig, scenes: Sequence[str]) -> None:
    """ValueError (one line) naming the first scene without a key its collection policy reads (a scene without an
    action list under a scripted policy), before any job starts."""
    spec = registry.policy(cfg.collect_policy)
    for name in scenes:
        scene = cfg.scene(name)
        if (gap := spec.missing(scene)) is not None:
            raise ValueError(f"{scene.path}: key {gap[0]!r}: the {spec.name} policy needs the scene's {gap[1]} "
                             "(--policy explore needs none)")
