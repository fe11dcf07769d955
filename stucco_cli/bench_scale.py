"""`stucco bench scale`: how evaluation wall time grows with the runs of a task, or each stage with the contacts of a
run."""
from __future__ import annotations

from pathlib import Path

import click

from pipeline import registry
from stucco_cli.bench import parse_ints, parse_methods
from stucco_cli.common import check_paths, global_options, parsed, pass_settings, say, unique, user_errors, writable_dir
from stucco_cli.progress import bars_off, progress_lines


@click.command("scale")
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
@global_options()
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
    method_list = parse_methods(methods)
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
                          progress=bars_off(settings))
        paths = write_outputs(rows, out_dir, png)
    click.echo("| task | runs | jobs | workers | backend | wall s | work s | wall per run s | efficiency | load |")
    click.echo("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        eff = "-" if r["efficiency"] is None else f"{r['efficiency']:.2f}"
        click.echo(f"| {r['scene']} | {r['runs']} | {r['jobs']} | {r['workers'] or '-'} | {r['backend']} | "
                   f"{r['wall_s']:.1f} | {r['work_s']:.1f} | {r['wall_per_run_s']:.2f} | {eff} | {r['load_avg']:.1f} |")
    say(settings, f"-> {', '.join(str(p) for p in paths)}")


def _one_task_and_sizes(scene: str, option: str, sizes: str, what: str) -> tuple[list, list[int]]:
    """`bench scale`'s one task (--scene) and its sizes (``option``: at least one positive integer)."""
    from pipeline.evaluate import parse_scenes  # imported here: start-up time

    scene_list = parsed("--scene", parse_scenes, scene)
    if len(scene_list) != 1:
        raise click.BadParameter("expected one task", param_hint="--scene")
    counts = parse_ints(option, sizes, 1, 100_000)
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
    method_list = parse_methods(methods)
    if len(method_list) != 1:
        raise click.BadParameter("expected one method with --contacts", param_hint="--methods")
    est = unique("--estimators", parsed("--estimators", parse_estimators, estimators))
    for tag in ["warmup"] + [f"c{n}" for n in counts]:
        if (out_dir / f"{scene_list[0]}-{tag}").exists():
            raise click.BadParameter(f"{out_dir / f'{scene_list[0]}-{tag}'} exists: a rerun stage is not a "
                                     "measurement; remove it or choose another --out", param_hint="--out")
    with user_errors("bench scale"):
        rows = contact_rows(out_dir, scene_list[0], sorted(set(counts)), method_list[0], est,
                            root_seed=settings.seed, seed=run_seed, progress=progress_lines(settings))
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
    say(settings, f"-> {', '.join(str(p) for p in paths)}")
