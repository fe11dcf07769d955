"""`stucco bench ...`: benchmarks that print tables (speed is measured here, never in tests)."""
from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import click

from pipeline import registry
from stucco_cli.common import JOBS, check_paths, parsed, pass_settings, unique, user_errors, writable_dir
from stucco_cli.progress import run_bar


@click.group()
def bench() -> None:
    """Benchmarks: what accuracy costs in time."""


def _choices(name: str, text: str, allowed: Sequence[str], what: str = "value", allow_none: bool = True
             ) -> tuple[str, ...]:
    """Comma-separated words of ``allowed`` for option `name`; '' gives () where ``allow_none``."""
    out = tuple(t.strip() for t in text.split(",") if t.strip())
    bad = [t for t in out if t not in allowed]
    if bad or not (out or allow_none):
        raise click.BadParameter(f"unknown {what} {bad[0]!r}; expected some of {', '.join(allowed)}"
                                 if bad else f"expected at least one {what}", param_hint=name)
    return out


def _ints(name: str, text: str, lo: int = 1, hi: int = 100_000) -> tuple[int, ...]:
    """Comma-separated integers in [lo, hi] for option `name`; '' gives ()."""
    out = []
    for t in (t.strip() for t in text.split(",")):
        if not t and not text.strip():
            continue
        try:
            v = int(t)
        except ValueError:
            raise click.BadParameter(f"expected comma-separated integers, got {t!r}", param_hint=name) from None
        if not lo <= v <= hi:
            raise click.BadParameter(f"{v} is not in [{lo}, {hi}]", param_hint=name)
        out.append(v)
    return tuple(out)


@bench.command("track")
@click.option("--streams", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="Folder of stream_T*.npz files [data/anchors].")
@click.option("--T", "t_list", default="50,100,200,400", show_default=True, help="Contact counts.")
@click.option("--N", "n_list", default="100,500", show_default=True, help="Particle counts.")
@click.option("--repeats", type=click.IntRange(min=1), default=3, show_default=True)
@click.option("--accuracy-seeds", type=click.IntRange(min=0), default=5, show_default=True,
              help="Tracker seeds for the accuracy table (0 skips it).")
@click.option("--methods", default="stucco", show_default=True, help="Comma-separated methods for a per-method table.")
@click.option("--reference-python", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Python of a venv with the authors' stucco==1.2.1 (see ../shared/anchors/README.md) to rerun "
                   "the reference side by side instead of using its recorded figures.")
@click.option("--reference-budget", type=click.FloatRange(min=1.0), default=180.0, show_default=True,
              help="Seconds of replay after which the authors' harness stops a rerun (a cut rerun gives a lower "
                   "bound on the speed-up).")
@click.option("--json", "json_path", type=click.Path(path_type=Path), default=None, help="Also save every figure.")
def bench_track(streams, t_list, n_list, repeats, accuracy_seeds, methods, reference_python, reference_budget,
                json_path) -> None:
    """Replay the authors' anchor streams: time per update, memory, FMI and CE, against the reference."""
    # Everything cheap is checked before the measurements, which a late failure would lose.
    ts, ns, method_list = _ints("--T", t_list), _ints("--N", n_list), _methods(methods)
    for name, values in (("--T", ts), ("--N", ns)):
        if not values:
            raise click.BadParameter("expected at least one value", param_hint=name)
    from pipeline.studies.anchors import ANCHOR_DIR, check_streams

    check_paths({"--streams": streams or ANCHOR_DIR, "--reference-python": reference_python}, {"--json": json_path})
    from pipeline.atomic import write_text
    from pipeline.studies.trackers import check_reference, track_bench

    with user_errors("bench track"):
        check_streams(sorted({*ts, 50}), streams)  # T=50 also warms the kernels up
        if reference_python:
            check_reference(reference_python)
        res = track_bench(ts, ns, repeats=repeats, acc_seeds=accuracy_seeds, streams=streams,
                          reference_python=reference_python, reference_budget_s=reference_budget,
                          methods=method_list, echo=click.echo)
    if json_path:
        write_text(json_path, json.dumps(res, indent=1))  # atomically, like every other output


def _floats(name: str, text: str, lo: float = 0.1, hi: float = 100.0) -> tuple[float, ...]:
    """Comma-separated finite numbers in [lo, hi] for option `name`; '' gives ()."""
    out = []
    for t in (t.strip() for t in text.split(",") if t.strip()):
        try:
            v = float(t)
        except ValueError:
            raise click.BadParameter(f"expected comma-separated numbers, got {t!r}", param_hint=name) from None
        if not lo <= v <= hi:  # also refuses nan
            raise click.BadParameter(f"{t} is not in [{lo:g}, {hi:g}]", param_hint=name)
        out.append(v)
    return tuple(out)


def _methods(text: str, param_hint: str = "--methods", allow_none: bool = False) -> tuple[str, ...]:
    return _choices(param_hint, text, registry.tracker_names(), "method", allow_none)


@bench.command("accuracy")
@click.option("--scenes", default="all", show_default=True, help="Comma-separated retrieval tasks, or 'all'.")
@click.option("--seeds", default="0-4", show_default=True, help="Run seeds: N, N-M, or a comma-separated list.")
@click.option("--N", "n_list", default="10,30,100,300,1000", show_default=True, help="STUCCO particle counts.")
@click.option("--restarts", "restart_list", default="5,10,30", show_default=True, help="ICP restarts (N = 100).")
@click.option("--sdf-mm", "sdf_list", default="1,2,4", show_default=True, help="Gripper SDF cell sizes, mm.")
@click.option("--hypotheses", "hyp_list", default="16,32,64,128", show_default=True,
              help="Pose hypotheses of the plausible estimator ('' for none).")
@click.option("--free-mm", "free_list", default="2.5,5,10", show_default=True,
              help="Free-space lattice spacings of the plausible estimator, mm ('' for none).")
@click.option("--paper-estimator/--no-paper-estimator", default=True, show_default=True,
              help="Also run the other registered pose estimators (the paper's) at the defaults.")
@click.option("--pushtrack-particles", "pt_particles", default="128,256,512,1024", show_default=True,
              help="Particles of the pushtrack estimator ('' for none).")
@click.option("--pushtrack-refine", "pt_refine", default="0,32,128", show_default=True,
              help="Particles the pushtrack estimator refines at the end ('' for none).")
@click.option("--pushtrack-substeps", "pt_substeps", default="1,4,8", show_default=True,
              help="Integration steps of one push in the pushtrack estimator ('' for none).")
@click.option("--pushtrack-starts", "pt_starts", default="1,6", show_default=True,
              help="Contacts of the segment the pushtrack estimator's filter may start from ('' for none).")
@click.option("--pushtrack-islands", "pt_islands", default="1,4", show_default=True,
              help="Independent filters the pushtrack estimator pools ('' for none).")
@click.option("--pushtrack-motion", "pt_motion", default="tip,push,sweep", show_default=True,
              help="Pushing models of the pushtrack estimator: tip (the gripper's slice, a box pushed on a long face "
                   "tipped onto its leading edge), push (a point pusher), sweep (the slice), translate, static ('' "
                   "for none).")
@click.option("--pushtrack-select", "pt_select", default="held_mean,grasp", show_default=True,
              help="How the pushtrack estimator chooses its estimate among the refined particles: cost, posterior, "
                   "grasp, mode, held_mean ('' for none).")
@click.option("--baselines", default=None,
              help="Comma-separated methods run at their defaults ('' for none) [every registered method but "
                   "the first: " + ",".join(registry.baseline_names()) + "].")
@click.option("--streams", "stream_list", default="0", show_default=True,
              help="The pose estimators' random streams, comma-separated: each setting's pose is estimated once per "
                   "stream on the same segments and its GS is their mean (0 1 2 to compare stochastic estimators "
                   "fairly; docs/evaluation.md, \"The estimator's own randomness\").")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=Path("out/accuracy"),
              show_default=True, help="Runs, contacts, accuracy.csv, summary.csv, pareto.png.")
@click.option("--jobs", "-j", type=JOBS, default=None, help="Processes over (scene, seed).")
@pass_settings
def bench_accuracy(settings, scenes, seeds, n_list, restart_list, sdf_list, hyp_list, free_list, paper_estimator,
                   pt_particles, pt_refine, pt_substeps, pt_starts, pt_islands, pt_motion, pt_select, stream_list,
                   baselines, out_dir, jobs) -> None:
    """What accuracy costs in time: every knob setting and baseline on a (scene, seed) grid; a table and a Pareto
    PNG of time per run against CE, FMI and grasp success."""
    writable_dir("--out", out_dir)
    import pyarrow as pa

    from pipeline.collect import parse_seeds
    from pipeline.estimators.pushtrack.filter import MOTIONS, SELECT_RULES
    from pipeline.evaluate import parse_scenes
    from pipeline.studies.accuracy import accuracy_bench
    from pipeline.studies.accuracy_settings import accuracy_settings
    from pipeline.studies.pareto import pareto_figure, summarise_settings, summary_markdown
    from pipeline.studies.tables import write_csv

    scene_list = parsed("--scenes", parse_scenes, scenes)
    seed_list = parsed("--seeds", parse_seeds, seeds)
    streams = _ints("--streams", stream_list, 0, 1_000_000)
    if not streams:
        raise click.BadParameter("at least one stream is needed", param_hint="--streams")
    sweep = accuracy_settings(_ints("--N", n_list), _ints("--restarts", restart_list, 1, 1000),
                              _floats("--sdf-mm", sdf_list, 0.25, 20.0),
                              hypotheses=_ints("--hypotheses", hyp_list, 1, 4096),
                              free_mm=_floats("--free-mm", free_list, 0.5, 100.0),
                              paper_estimator=paper_estimator,
                              pushtrack=(("n_particles", _ints("--pushtrack-particles", pt_particles, 8, 16384)),
                                         ("n_refine", _ints("--pushtrack-refine", pt_refine, 0, 256)),
                                         ("substeps", _ints("--pushtrack-substeps", pt_substeps, 1, 64)),
                                         ("starts", _ints("--pushtrack-starts", pt_starts, 1, 64)),
                                         ("islands", _ints("--pushtrack-islands", pt_islands, 1, 64)),
                                         ("motion", _choices("--pushtrack-motion", pt_motion, MOTIONS, "choice")),
                                         ("select", _choices("--pushtrack-select", pt_select, SELECT_RULES,
                                                             "choice"))),
                              baselines=None if baselines is None else _methods(baselines, "--baselines", True))
    with user_errors("bench accuracy"):
        table = accuracy_bench(out_dir, scene_list, seed_list, sweep, root_seed=settings.seed,
                               jobs=jobs or settings.jobs, progress=settings.progress, streams=streams)
        rows = summarise_settings(table)
        write_csv(pa.Table.from_pylist(rows), out_dir / "summary.csv")
        png = pareto_figure(rows, out_dir / "pareto.png")
    click.echo(summary_markdown(rows), nl=False)
    ran = list(dict.fromkeys(table.column("stream").to_pylist()))  # the streams as accuracy_bench ran them
    if ran != [0]:
        click.echo(f"GS: the mean over estimator streams {', '.join(map(str, ran))}")
    k = [r["setting"] for r in rows if r.get("knee")]
    if k:
        click.echo(f"knee (cheapest N within 10% of the best median CE of the N sweep): {k[0]}")
    click.echo(f"-> {out_dir / 'accuracy.csv'}, {out_dir / 'summary.csv'}, {png}", err=True)


def _evaluation_dir(runs_from: Path) -> None:
    """Usage error (``--runs-from``) unless ``runs_from`` is an evaluation directory (``stucco evaluate``'s)."""
    if not runs_from.is_dir() or not (runs_from / "runs").is_dir():
        raise click.BadParameter(f"{runs_from}: not an evaluation directory (no runs/ inside); make one with "
                                 f"`stucco evaluate --out {runs_from}`", param_hint="--runs-from")


def _collected_pairs(runs_from: Path, scene_list, seed_list) -> list[tuple[str, int]]:
    """Every (scene, seed) of the grid; a usage error (``--runs-from``) naming the first without a run file."""
    from pipeline.evaluate import partition

    pairs = [(sc, s) for sc in scene_list for s in seed_list]
    missing = [p for p in pairs if not partition(runs_from, "runs", *p).is_file()]
    if missing:
        raise click.BadParameter(f"{partition(runs_from, 'runs', *missing[0])}: no collected run for "
                                 f"{missing[0][0]} seed {missing[0][1]}", param_hint="--runs-from")
    return pairs


@bench.command("retrieval")
@click.option("--runs-from", "runs_from", required=True, type=click.Path(path_type=Path),
              help="Evaluation directory made by `stucco evaluate` (its runs and segments are used).")
@click.option("--scenes", default="FB,BC,IB,TC", show_default=True, help="Comma-separated retrieval tasks.")
@click.option("--seeds", default="0-19", show_default=True, help="Run seeds: N, N-M, or a comma-separated list.")
@click.option("--estimators", default="all", show_default=True,
              help="Pose estimators of the estimator rungs (comma-separated: "
                   + ", ".join(registry.estimator_names()) + "; or 'all').")
@click.option("--method", default=registry.tracker_names()[0], show_default=True,
              help="Tracking method of the tracker rung.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              default=Path("out/bench/retrieval"), show_default=True,
              help="ladder.csv, ladder_summary.csv, ladder.png.")
@pass_settings
def bench_retrieval(settings, runs_from, scenes, seeds, estimators, method, out_dir) -> None:
    """Where grasps are lost: grasp success at the true pose, the true pose perturbed, ideal contact points with
    the true segment and with our choice, and the tracker's points with our choice, per task and estimator."""
    writable_dir("--out", out_dir)
    from pipeline.collect import parse_seeds
    from pipeline.estimators.estimate import parse_estimators
    from pipeline.evaluate import parse_scenes
    from pipeline.studies.retrieval_ladder import ladder_rows
    from pipeline.studies.retrieval_ladder_report import ladder_tables, summarise, summary_markdown, write_outputs

    _evaluation_dir(runs_from)
    scene_list = parsed("--scenes", parse_scenes, scenes)
    seed_list = parsed("--seeds", parse_seeds, seeds)
    est = unique("--estimators", parsed("--estimators", parse_estimators, estimators))
    _methods(method, "--method")
    pairs = _collected_pairs(runs_from, scene_list, seed_list)
    with user_errors("bench retrieval"):
        rows = ladder_rows(runs_from, pairs, est, method, settings.seed, jobs=settings.jobs,
                           progress=run_bar(settings, "ladder"))
        paths = write_outputs(rows, out_dir)
    summary = summarise(rows)
    click.echo(ladder_tables(summary))
    click.echo(summary_markdown(summary), nl=False)
    click.echo(f"-> {', '.join(str(p) for p in paths)}", err=True)


@bench.command("pushes")
@click.option("--runs-from", "runs_from", required=True, type=click.Path(path_type=Path),
              help="Evaluation directory made by `stucco evaluate` (its runs are used).")
@click.option("--scenes", default="FB,BC,IB", show_default=True, help="Comma-separated retrieval tasks.")
@click.option("--seeds", default="100-109", show_default=True, help="Run seeds: N, N-M, or a comma-separated list.")
@click.option("--replay/--no-replay", default=True, show_default=True,
              help="Also replay each push in pybullet, the whole scene and the target alone.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              default=Path("out/bench/pushes"), show_default=True,
              help="pushes.csv, pushes_summary.csv, pushes.png.")
@pass_settings
def bench_pushes(settings, runs_from, scenes, seeds, replay, out_dir) -> None:
    """The pushing models against the simulator, push by push: each push of the target run by every pushtrack
    pushing model from its recorded pose before (and replayed in pybullet), against its recorded pose after."""
    writable_dir("--out", out_dir)
    from pipeline.collect import parse_seeds
    from pipeline.evaluate import parse_scenes
    from pipeline.studies.pushes import push_rows, summarise, summary_markdown, write_outputs

    _evaluation_dir(runs_from)
    pairs = _collected_pairs(runs_from, parsed("--scenes", parse_scenes, scenes), parsed("--seeds", parse_seeds, seeds))
    with user_errors("bench pushes"):
        rows = push_rows(runs_from, pairs, replay=replay, jobs=settings.jobs, progress=run_bar(settings, "pushes"))
        paths = write_outputs(rows, out_dir)
    click.echo(summary_markdown(summarise(rows)), nl=False)
    click.echo(f"-> {', '.join(str(p) for p in paths)}", err=True)


@bench.command("probe")
@click.option("--scenes", default="FB,BC,IB,TC", show_default=True, help="Comma-separated retrieval tasks.")
@click.option("--seeds", default="100-119", show_default=True, help="Run seeds: N, N-M, or a comma-separated list.")
@click.option("--budgets", default="0,1,2,4,8,12", show_default=True, help="Probe budgets.")
@click.option("--runs", "runs_dir", type=click.Path(file_okay=False, path_type=Path),
              default=Path("out/bench/probe/runs"), show_default=True,
              help="Run files of `collect --policy scripted+probe` (made here when missing).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              default=Path("out/bench/probe"), show_default=True,
              help="probe_budget.csv, probe_budget_summary.csv, probe_budget.png.")
@click.option("--png", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Where the PNG goes instead (e.g. docs/img/probe_budget.png).")
@pass_settings
def bench_probe(settings, scenes, seeds, budgets, runs_dir, out_dir, png) -> None:
    """Active retrieval: grasp success against the probe budget per task, with probes used, time per probe
    decision and how far probing moved the target (docs/retrieval.md, "Active retrieval")."""
    writable_dir("--out", out_dir)
    from pipeline.collect import parse_seeds
    from pipeline.evaluate import parse_scenes
    from pipeline.studies.probe_budget import budget_rows, summarise, write_outputs

    scene_list = parsed("--scenes", parse_scenes, scenes)
    seed_list = parsed("--seeds", parse_seeds, seeds)
    budget_list = tuple(sorted(set(_ints("--budgets", budgets, lo=0, hi=64))))
    if not budget_list:
        raise click.BadParameter("expected at least one budget", param_hint="--budgets")
    with user_errors("bench probe"):
        rows = budget_rows([(sc, s) for sc in scene_list for s in seed_list], runs_dir, budget_list, settings.seed,
                           jobs=settings.jobs, progress=run_bar(settings, "probe"))
        summary = summarise(rows)
        paths = write_outputs(rows, summary, out_dir, png)
    click.echo("| task | budget | runs | GS % | probes | decision s (median / max) | target moved mm / rad | wide |")
    click.echo("|---|---|---|---|---|---|---|---|")
    for s in summary:
        click.echo(f"| {s['scene']} | {s['budget']} | {s['runs']} | {s['gs_pct']:.0f} | {s['probes_mean']:.2f} | "
                   f"{s['decision_s_median']:.3f} / {s['decision_s_max']:.3f} | {s['moved_mm_median']:.1f} / "
                   f"{s['turned_rad_median']:.3f} | {s['wide']} |")
    click.echo(f"-> {', '.join(str(p) for p in paths)}", err=True)


@bench.command("scale")
@click.option("--scene", default="TC", show_default=True, help="The retrieval task whose seeds make the grid.")
@click.option("--runs", "run_counts", default="20,100", show_default=True,
              help="Comma-separated grid sizes: the first N seeds, each evaluated from scratch.")
@click.option("--methods", default=registry.tracker_names()[0], show_default=True,
              help="Comma-separated tracking methods of every run.")
@click.option("--estimators", default="all", show_default=True,
              help="Pose estimators of every job (comma-separated: " + ", ".join(registry.estimator_names())
                   + "; or 'all').")
@click.option("--max-actions", type=click.IntRange(min=1), default=None,
              help="Cut every run after N actions (small grids for a try).")
@click.option("--backend", type=click.Choice(["loky", "dask"]), default="loky", show_default=True,
              help="loky: -j local processes; dask: joblib's Dask backend on --scheduler.")
@click.option("--scheduler", default=None, help="Dask scheduler address for --backend dask (tcp://HOST:8786).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              default=Path("out/bench/scale"), show_default=True,
              help="One evaluation folder per grid size, scale.csv and scale.png.")
@click.option("--png", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also draw the figure here (e.g. docs/img/scale.png).")
@click.option("--contacts", "contact_counts", default=None,
              help="Instead of the runs axis: comma-separated contacts per run (e.g. 50,200,500,2000); one run of "
                   "--scene per size, collected with the rummage policy, each stage timed (wall and CPU s) -> "
                   "scale_contacts.csv and scale_contacts.png.")
@click.option("--run-seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Run seed of the --contacts runs.")
@pass_settings
def bench_scale(settings, scene, run_counts, methods, estimators, max_actions, backend, scheduler, out_dir,
                png, contact_counts, run_seed) -> None:
    """How `stucco evaluate` wall time grows with the number of runs of one task (collection included), or with
    --contacts, how each stage's time grows with the contacts of one run."""
    writable_dir("--out", out_dir)
    check_paths({}, {"--png": png})
    if contact_counts is not None:
        _scale_contacts(settings, scene, contact_counts, methods, estimators, out_dir, png, run_seed)
        return
    from pipeline.estimators.estimate import parse_estimators
    from pipeline.studies.scale import scale_rows, write_outputs

    scene_list, counts = _one_task_and_sizes(scene, "--runs", run_counts, "grid size")
    method_list = _methods(methods)
    est = unique("--estimators", parsed("--estimators", parse_estimators, estimators))
    if backend == "dask" and not scheduler:
        raise click.BadParameter("--backend dask needs --scheduler ADDRESS", param_hint="--scheduler")
    taken = [n for n in counts if (out_dir / f"{scene_list[0]}-{n}").exists()]
    if taken:
        raise click.BadParameter(f"{out_dir / f'{scene_list[0]}-{taken[0]}'} exists: a resumed evaluation is not a "
                                 "measurement; remove it or choose another --out", param_hint="--out")
    with user_errors("bench scale"):
        rows = scale_rows(out_dir, scene_list[0], counts, method_list, est, jobs=settings.jobs,
                          root_seed=settings.seed, max_actions=max_actions, backend=backend, scheduler=scheduler,
                          progress=settings.progress)
        paths = write_outputs(rows, out_dir, png)
    click.echo("| task | runs | jobs | workers | backend | wall s | work s | wall per run s | efficiency | load |")
    click.echo("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        eff = "-" if r["efficiency"] is None else f"{r['efficiency']:.2f}"
        click.echo(f"| {r['scene']} | {r['runs']} | {r['jobs']} | {r['workers'] or '-'} | {r['backend']} | "
                   f"{r['wall_s']:.1f} | {r['work_s']:.1f} | {r['wall_per_run_s']:.2f} | {eff} | {r['load_avg']:.1f} |")
    click.echo(f"-> {', '.join(str(p) for p in paths)}", err=True)


def _one_task_and_sizes(scene: str, option: str, sizes: str, what: str) -> tuple[list, list[int]]:
    """`bench scale`'s one task (--scene) and its sizes (``option``: at least one positive integer)."""
    from pipeline.evaluate import parse_scenes  # imported here: start-up time

    scene_list = parsed("--scene", parse_scenes, scene)
    if len(scene_list) != 1:
        raise click.BadParameter("expected one task", param_hint="--scene")
    counts = _ints(option, sizes, 1, 100_000)
    if not counts:
        raise click.BadParameter(f"expected at least one {what}", param_hint=option)
    return scene_list, counts


def _scale_contacts(settings, scene, contact_counts, methods, estimators, out_dir, png, run_seed) -> None:
    """`bench scale --contacts`: every stage timed against the contacts of one run (docs/evaluation.md, "Scale")."""
    ctx = click.get_current_context()
    for name in ("run_counts", "max_actions", "backend", "scheduler"):
        if ctx.get_parameter_source(name) != click.core.ParameterSource.DEFAULT:
            opt = next(p.opts[0] for p in ctx.command.params if p.name == name)
            raise click.BadParameter(f"{opt} does not apply to the contacts axis (one axis per call)",
                                     param_hint="--contacts")
    from pipeline.estimators.estimate import parse_estimators
    from pipeline.studies.scale_contacts import WARMUP_CONTACTS, contact_rows, growth, write_contact_outputs

    scene_list, counts = _one_task_and_sizes(scene, "--contacts", contact_counts, "contact count")
    method_list = _methods(methods)
    if len(method_list) != 1:
        raise click.BadParameter("expected one method with --contacts", param_hint="--methods")
    est = unique("--estimators", parsed("--estimators", parse_estimators, estimators))
    for tag in ["warmup"] + [f"c{n}" for n in counts]:
        if (out_dir / f"{scene_list[0]}-{tag}").exists():
            raise click.BadParameter(f"{out_dir / f'{scene_list[0]}-{tag}'} exists: a rerun stage is not a "
                                     "measurement; remove it or choose another --out", param_hint="--out")
    say = None if settings.progress else (lambda text: click.echo(text, err=True))
    with user_errors("bench scale"):
        rows = contact_rows(out_dir, scene_list[0], sorted(set(counts)), method_list[0], est,
                            root_seed=settings.seed, seed=run_seed, progress=say)
        paths = write_contact_outputs(rows, out_dir, png)
    click.echo("| task | contacts (asked) | actions | stage | wall s | CPU s | load |")
    click.echo("|---|---|---|---|---|---|---|")
    for r in rows:
        stage = r["stage"] + (f" ({r['estimator']})" if r["estimator"] else "")
        asked = f"warm-up ({WARMUP_CONTACTS})" if r["warmup"] else str(r["requested"])
        click.echo(f"| {r['scene']} | {r['contacts']} ({asked}) | {r['actions']} | {stage} | {r['wall_s']:.2f} | "
                   f"{r['cpu_s']:.2f} | {r['load_avg']:.1f} |")
    slopes = growth(rows)
    click.echo("growth, CPU s ~ contacts^b: " + ", ".join(
        f"{k} b={'-' if v is None else f'{v:.2f}'}" for k, v in slopes.items()))
    click.echo(f"-> {', '.join(str(p) for p in paths)}", err=True)
