"""`stucco bench retrieval`, `bench pushes`, `bench grasp-sensitivity`, `bench probe` and `bench explore`:
benchmarks over collected runs (an evaluation directory's, the active protocol's or the explore policy's)."""
from __future__ import annotations

from pathlib import Path

import click

from pipeline import registry
from stucco_cli.bench import parse_floats, parse_ints, parse_methods
from stucco_cli.common import global_options, parsed, pass_settings, say, unique, user_errors, writable_dir
from stucco_cli.progress import run_bar


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


def _out_option(name: str, files: str):
    """The ``--out`` option of a bench over collected runs: its folder (default out/bench/NAME) and the files it
    writes there."""
    return click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
                        default=Path(f"out/bench/{name}"), show_default=True, help=files)


@click.command("retrieval")
@click.option("--runs-from", "runs_from", required=True, type=click.Path(path_type=Path),
              help="Evaluation directory made by `stucco evaluate` (its runs and segments are used).")
@click.option("--scenes", default="FB,BC,IB,TC", show_default=True, help="Comma-separated retrieval tasks.")
@click.option("--seeds", default="0-19", show_default=True, help="Run seeds: N, N-M, or a comma-separated list.")
@click.option("--estimators", default="all", show_default=True,
              help="Pose estimators of the estimator rungs (comma-separated: "
                   + ", ".join(registry.estimator_names()) + "; or 'all').")
@click.option("--method", default=registry.tracker_names()[0], show_default=True,
              help="Tracking method of the tracker rung.")
@_out_option("retrieval", "ladder.csv, ladder_summary.csv, ladder.png.")
@global_options()
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
    parse_methods(method, "--method")
    pairs = _collected_pairs(runs_from, scene_list, seed_list)
    with user_errors("bench retrieval"):
        rows = ladder_rows(runs_from, pairs, est, method, settings.seed, jobs=settings.jobs,
                           progress=run_bar(settings, "ladder"))
        paths = write_outputs(rows, out_dir)
    summary = summarise(rows)
    click.echo(ladder_tables(summary))
    click.echo(summary_markdown(summary), nl=False)
    say(settings, f"-> {', '.join(str(p) for p in paths)}")


@click.command("pushes")
@click.option("--runs-from", "runs_from", required=True, type=click.Path(path_type=Path),
              help="Evaluation directory made by `stucco evaluate` (its runs are used).")
@click.option("--scenes", default="FB,BC,IB", show_default=True, help="Comma-separated retrieval tasks.")
@click.option("--seeds", default="100-109", show_default=True, help="Run seeds: N, N-M, or a comma-separated list.")
@click.option("--replay/--no-replay", default=True, show_default=True,
              help="Also replay each push in pybullet, the whole scene and the target alone.")
@_out_option("pushes", "pushes.csv, pushes_summary.csv, pushes.png.")
@global_options()
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
    say(settings, f"-> {', '.join(str(p) for p in paths)}")


@click.command("grasp-sensitivity")
@click.option("--runs-from", "runs_from", required=True, type=click.Path(path_type=Path),
              help="Evaluation directory made by `stucco evaluate` with the scripted policy (its runs and retrieval "
                   "tables are used).")
@click.option("--shifts-um", default="1,100", show_default=True,
              help="Shifts along x, micrometres (comma-separated, 0.001-10000): of the estimate and of the target.")
@_out_option("grasp-sensitivity", "sensitivity.csv, sensitivity_summary.md.")
@global_options()
@pass_settings
def bench_grasp_sensitivity(settings, runs_from, shifts_um, out_dir) -> None:
    """How reproducible a grasp's outcome is: every scripted grasp of an evaluation simulated again at its
    estimate, and with the estimate or the target moved by each shift; the outcomes that change
    (docs/experiments/grasp-simulation-speed.md)."""
    writable_dir("--out", out_dir)
    from pipeline.studies.grasp_sensitivity import sensitivity_rows, summarise, summary_markdown, write_outputs

    _evaluation_dir(runs_from)
    shifts = parse_floats("--shifts-um", shifts_um, lo=0.001, hi=10_000.0)
    if not shifts:
        raise click.BadParameter("expected at least one shift", param_hint="--shifts-um")
    with user_errors("bench grasp-sensitivity"):
        rows = sensitivity_rows(runs_from, [s * 1e-6 for s in shifts], jobs=settings.jobs,
                                progress=run_bar(settings, "grasps"))
        paths = write_outputs(rows, out_dir)
    click.echo(summary_markdown(summarise(rows)), nl=False)
    say(settings, f"-> {', '.join(str(p) for p in paths)}")


def _budget_outputs(name: str, runs_help: str):
    """The ``--runs``, ``--out`` and ``--png`` options of a budget bench (``probe``, ``explore``): its run files
    under out/bench/NAME/runs, its tables and figure NAME_budget.* under out/bench/NAME."""
    def wrap(f):
        f = click.option("--png", type=click.Path(dir_okay=False, path_type=Path), default=None,
                         help=f"Where the PNG goes instead (e.g. docs/img/{name}_budget.png).")(f)
        f = click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
                         default=Path(f"out/bench/{name}"), show_default=True,
                         help=f"{name}_budget.csv, {name}_budget_summary.csv, {name}_budget.png.")(f)
        return click.option("--runs", "runs_dir", type=click.Path(file_okay=False, path_type=Path),
                            default=Path(f"out/bench/{name}/runs"), show_default=True, help=runs_help)(f)
    return wrap


@click.command("probe")
@click.option("--scenes", default="FB,BC,IB,TC", show_default=True, help="Comma-separated retrieval tasks.")
@click.option("--seeds", default="100-119", show_default=True, help="Run seeds: N, N-M, or a comma-separated list.")
@click.option("--budgets", default="0,1,2,4,8,12", show_default=True, help="Probe budgets.")
@_budget_outputs("probe", "Run files of `collect --policy scripted+probe` (made here when missing).")
@global_options()
@pass_settings
def bench_probe(settings, scenes, seeds, budgets, runs_dir, out_dir, png) -> None:
    """Active retrieval: grasp success against the probe budget per task, with probes used, time per probe
    decision and how far probing moved the target (docs/active.md)."""
    writable_dir("--out", out_dir)
    from pipeline.collect import parse_seeds
    from pipeline.evaluate import parse_scenes
    from pipeline.studies.probe_budget import budget_rows, summarise, write_outputs

    scene_list = parsed("--scenes", parse_scenes, scenes)
    seed_list = parsed("--seeds", parse_seeds, seeds)
    budget_list = tuple(sorted(set(parse_ints("--budgets", budgets, lo=0, hi=64))))
    if not budget_list:
        raise click.BadParameter("expected at least one budget", param_hint="--budgets")
    with user_errors("bench probe"):
        rows = budget_rows([(sc, s) for sc in scene_list for s in seed_list], runs_dir, budget_list, settings.seed,
                           jobs=settings.jobs, progress=run_bar(settings, "probe"))
        summary = summarise(rows)
        paths = write_outputs(rows, summary, out_dir, png)
    click.echo("| task | budget | runs | GS % first attempt | GS % within the attempts | probes | "
               "decision s (median / max) | target moved mm / rad | wide |")
    click.echo("|---|---|---|---|---|---|---|---|---|")
    for s in summary:
        click.echo(f"| {s['scene']} | {s['budget']} | {s['runs']} | {s['gs_pct']:.0f} | {s['gs_any_pct']:.0f} | "
                   f"{s['probes_mean']:.2f} | "
                   f"{s['decision_s_median']:.3f} / {s['decision_s_max']:.3f} | {s['moved_mm_median']:.1f} / "
                   f"{s['turned_rad_median']:.3f} | {s['wide']} |")
    say(settings, f"-> {', '.join(str(p) for p in paths)}")


@click.command("explore")
@click.option("--scenes", default="FB,BC,IB,TC", show_default=True,
              help="Comma-separated retrieval tasks, scene files or folders of scene files (each with a target "
                   "region).")
@click.option("--seeds", default="100-109", show_default=True, help="Run seeds: N, N-M, or a comma-separated list.")
@click.option("--budgets", default="100,200,400,2000", show_default=True, help="Action budgets (actions per run).")
@_budget_outputs("explore", "Run files of `collect --policy explore`, one folder per budget (made here when missing).")
@global_options()
@pass_settings
def bench_explore(settings, scenes, seeds, budgets, runs_dir, out_dir, png) -> None:
    """The explore policy: grasp success against its action budget and against its decision time, per task
    and per target shape of other scenes (docs/active.md)."""
    writable_dir("--out", out_dir)
    from pipeline.collect import parse_seeds
    from pipeline.evaluate.config import parse_scenes, scene_files
    from pipeline.studies.explore_budget import budget_rows, summarise, write_outputs

    names = parsed("--scenes", lambda t: parse_scenes(t, files=True), scenes)
    files = {name: path for name, path, _ in parsed("--scenes", scene_files, scenes)}
    seed_list = parsed("--seeds", parse_seeds, seeds)
    budget_list = tuple(sorted(set(parse_ints("--budgets", budgets, lo=1, hi=100_000))))
    if not budget_list:
        raise click.BadParameter("expected at least one budget", param_hint="--budgets")
    with user_errors("bench explore"):
        rows = budget_rows([(files.get(sc, sc), s) for sc in names for s in seed_list], runs_dir, budget_list,
                           settings.seed, jobs=settings.jobs, progress=run_bar(settings, "explore"))
        summary = summarise(rows)
        paths = write_outputs(rows, summary, out_dir, png)
    click.echo("| group | budget | runs | GS % first attempt | GS % within the attempts | actions (median / max) | "
               "probes | decision s (median / max) | budget spent |")
    click.echo("|---|---|---|---|---|---|---|---|---|")
    for s in summary:
        click.echo(f"| {s['group']} | {s['budget']} | {s['runs']} | {s['gs_pct']:.0f} | {s['gs_any_pct']:.0f} | "
                   f"{s['actions_median']:.0f} / {s['actions_max']} | {s['probes_mean']:.2f} | "
                   f"{s['decision_s_median']:.3f} / {s['decision_s_max']:.3f} | {s['budget_spent']} |")
    say(settings, f"-> {', '.join(str(p) for p in paths)}")
