"""`stucco bench ...`: benchmarks that print tables (speed is measured here, never in tests)."""
from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import click

from pipeline import registry
from stucco_cli.common import (
    JOBS,
    ONE_PROCESS,
    check_paths,
    global_options,
    parsed,
    pass_settings,
    say,
    user_errors,
    writable_dir,
)
from stucco_cli.progress import bars_off


@click.group()
@global_options()
def bench() -> None:
    """Benchmarks: what accuracy costs in time.

    Commands: track, contacts, accuracy, sim (here and in stucco_cli/sim.py), retrieval, pushes,
    grasp-sensitivity, probe, explore (stucco_cli/bench_runs.py), scale (stucco_cli/bench_scale.py)."""


def parse_choices(name: str, text: str, allowed: Sequence[str], what: str = "value", allow_none: bool = True
             ) -> tuple[str, ...]:
    """Comma-separated words of ``allowed`` for option `name`; '' gives () where ``allow_none``."""
    out = tuple(t.strip() for t in text.split(",") if t.strip())
    bad = [t for t in out if t not in allowed]
    if bad or not (out or allow_none):
        raise click.BadParameter(f"unknown {what} {bad[0]!r}; expected some of {', '.join(allowed)}"
                                 if bad else f"expected at least one {what}", param_hint=name)
    return out


def parse_ints(name: str, text: str, lo: int = 1, hi: int = 100_000) -> tuple[int, ...]:
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
@global_options(jobs=ONE_PROCESS, seed="its tracker seeds are --accuracy-seeds")
@pass_settings
def bench_track(settings, streams, t_list, n_list, repeats, accuracy_seeds, methods, reference_python, reference_budget,
                json_path) -> None:
    """Replay the authors' anchor streams: time per update, memory, FMI and CE, against the reference."""
    # Everything cheap is checked before the measurements, which a late failure would lose.
    ts, ns, method_list = parse_ints("--T", t_list), parse_ints("--N", n_list), parse_methods(methods)
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
        say(settings, f"-> {json_path}")


@bench.command("contacts")
@click.option("--streams", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="Folder of stream_T*.npz files [data/anchors].")
@click.option("--T", "t_list", default="50,100,200", show_default=True, help="Contact steps of the streams.")
@click.option("--K", "k_list", default="1,2,3", show_default=True, help="Contacts per step.")
@click.option("--N", "n_particles", type=click.IntRange(1, 100_000), default=100, show_default=True,
              help="STUCCO's particles.")
@click.option("--methods", default="stucco", show_default=True, help="Comma-separated tracking methods.")
@click.option("--repeats", type=click.IntRange(min=1), default=3, show_default=True)
@click.option("--json", "json_path", type=click.Path(path_type=Path), default=None, help="Also save every figure.")
@global_options(jobs=ONE_PROCESS, seed="it replays fixed streams with tracker seed 0")
@pass_settings
def bench_contacts(settings, streams, t_list, k_list, n_particles, methods, repeats, json_path) -> None:
    """Several contacts per step: CPU time per contact point against one contact per step."""
    ts, ks, method_list = parse_ints("--T", t_list), parse_ints("--K", k_list, hi=16), parse_methods(methods)
    for name, values in (("--T", ts), ("--K", ks)):
        if not values:
            raise click.BadParameter("expected at least one value", param_hint=name)
    from pipeline.studies.anchors import ANCHOR_DIR, check_streams

    check_paths({"--streams": streams or ANCHOR_DIR}, {"--json": json_path})
    from pipeline.atomic import write_text
    from pipeline.studies.multi_contact import contacts_bench

    with user_errors("bench contacts"):
        check_streams(sorted({*ts, 50}), streams)
        rows = contacts_bench(ts, ks, n_particles=n_particles, methods=method_list, repeats=repeats,
                              streams=streams, echo=click.echo)
    if json_path:
        write_text(json_path, json.dumps(rows, indent=1))
        say(settings, f"-> {json_path}")


def parse_floats(name: str, text: str, lo: float = 0.1, hi: float = 100.0) -> tuple[float, ...]:
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


def parse_methods(text: str, param_hint: str = "--methods", allow_none: bool = False) -> tuple[str, ...]:
    return parse_choices(param_hint, text, registry.tracker_names(), "method", allow_none)


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
@click.option("--pushtrack-sweep-substeps", "pt_sweep_substeps", default="", show_default=True,
              help="Steps of the gripper's sweep over one push in the pushtrack estimator ('' for none).")
@click.option("--pushtrack-free-stretches", "pt_free_stretches", default="", show_default=True,
              help="on: the free space of the actions between two touches counted once per cell; off: once per "
                   "action ('' for none).")
@click.option("--baselines", default=None,
              help="Comma-separated methods run at their defaults ('' for none) [every registered method but "
                   "the first: " + ",".join(registry.baseline_names()) + "].")
@click.option("--streams", "stream_list", default="0", show_default=True,
              help="The pose estimators' random streams, comma-separated: each setting's pose is estimated once per "
                   "stream on the same segments and its GS is their mean (0 1 2 to compare stochastic estimators "
                   "fairly; docs/evaluation.md, \"The estimator's own randomness\").")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=Path("out/accuracy"),
              show_default=True, help="Runs, contacts, accuracy.csv, summary.csv, pareto.png.")
@click.option("--jobs", "-j", type=JOBS, default=None, help="Processes over (scene, seed) [the group's -j].")
@global_options(own_jobs=True)
@pass_settings
def bench_accuracy(settings, scenes, seeds, n_list, restart_list, sdf_list, hyp_list, free_list, paper_estimator,
                   pt_particles, pt_refine, pt_substeps, pt_starts, pt_islands, pt_motion, pt_select,
                   pt_sweep_substeps, pt_free_stretches, stream_list, baselines, out_dir, jobs) -> None:
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
    streams = parse_ints("--streams", stream_list, 0, 1_000_000)
    if not streams:
        raise click.BadParameter("at least one stream is needed", param_hint="--streams")
    sweep = accuracy_settings(parse_ints("--N", n_list), parse_ints("--restarts", restart_list, 1, 1000),
                              parse_floats("--sdf-mm", sdf_list, 0.25, 20.0),
                              hypotheses=parse_ints("--hypotheses", hyp_list, 1, 4096),
                              free_mm=parse_floats("--free-mm", free_list, 0.5, 100.0),
                              paper_estimator=paper_estimator,
                              pushtrack=(("n_particles", parse_ints("--pushtrack-particles", pt_particles, 8, 16384)),
                                         ("n_refine", parse_ints("--pushtrack-refine", pt_refine, 0, 256)),
                                         ("substeps", parse_ints("--pushtrack-substeps", pt_substeps, 1, 64)),
                                         ("starts", parse_ints("--pushtrack-starts", pt_starts, 1, 64)),
                                         ("islands", parse_ints("--pushtrack-islands", pt_islands, 1, 64)),
                                         ("motion", parse_choices("--pushtrack-motion", pt_motion, MOTIONS, "choice")),
                                         ("select", parse_choices("--pushtrack-select", pt_select, SELECT_RULES,
                                                             "choice")),
                                         ("sweep_substeps", parse_ints("--pushtrack-sweep-substeps",
                                                                       pt_sweep_substeps, 1, 256)),
                                         ("free_stretches", tuple(v == "on" for v in parse_choices(
                                             "--pushtrack-free-stretches", pt_free_stretches, ("on", "off"))))),
                              baselines=None if baselines is None else parse_methods(baselines, "--baselines", True))
    with user_errors("bench accuracy"):
        table = accuracy_bench(out_dir, scene_list, seed_list, sweep, root_seed=settings.seed,
                               jobs=jobs or settings.jobs, progress=bars_off(settings), streams=streams)
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
    say(settings, f"-> {out_dir / 'accuracy.csv'}, {out_dir / 'summary.csv'}, {png}")
