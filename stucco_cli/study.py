"""`stucco study ...`: the training-set study (paper Fig. 5) and tuning on it."""
from __future__ import annotations

import json
from pathlib import Path

import click

from stucco_cli.common import JOBS, Settings, global_options, parsed, pass_settings, say, user_errors, writable_dir
from stucco_cli.progress import bars_off


@click.group()
@global_options()
def study() -> None:
    """Studies on the training set (SELECT1-4, greedy random walk)."""


def _grid(scenes: str, seeds: str):
    from pipeline.collect import parse_seeds
    from pipeline.scenes import SceneError, load_scene

    names = tuple(s.strip() for s in scenes.split(",") if s.strip())
    for n in names:
        try:
            sc = load_scene(n)
        except SceneError as e:
            raise click.BadParameter(str(e), param_hint="--scenes") from None
        if sc.walk is None:
            raise click.BadParameter(f"scene {n!r} has no [walk] table (not a training scene)",
                                     param_hint="--scenes")
    return names, parsed("--seeds", parse_seeds, seeds)


_common = [
    click.option("--scenes", default="SELECT1,SELECT2,SELECT3,SELECT4", show_default=True),
    click.option("--seeds", default="7-46", show_default=True),
    click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=Path("out/training"),
                 show_default=True, help="Runs, contacts.parquet and the study's outputs."),
    click.option("--jobs", "-j", type=JOBS, default=None, help="Processes [the group's -j]."),
    click.option("--max-actions", type=click.IntRange(min=1), default=None, help="Cut runs (test grids)."),
]


def _options(f):
    for o in reversed(_common):
        f = o(f)
    return f


@study.command("training")
@_options
@click.option("--methods", default="all", show_default=True)
@global_options(own_jobs=True)
@pass_settings
def training(settings: Settings, scenes, seeds, out_dir, jobs, max_actions, methods) -> None:
    """Fig. 5: collect (greedy walk, discard rule), track with every method, median FMI against median CE with
    20th-80th percentile bars, for all runs and runs with ambiguity >= 0.3."""
    writable_dir("--out", out_dir)
    from pipeline.evaluate import parse_methods
    from pipeline.studies.training_figure import training_study

    names, seed_list = _grid(scenes, seeds)
    method_list = parsed("--methods", parse_methods, methods)
    with user_errors("study training"):
        res = training_study(out_dir, names, seed_list, method_list, root_seed=settings.seed,
                             jobs=jobs or settings.jobs, progress=bars_off(settings), max_actions=max_actions)
    click.echo(f"{res['kept']} of {res['collected']} trajectories kept by the discard rule "
               f"({json.dumps(res['per_scene_kept'])}; discarded: {json.dumps(res['discarded_by_reason'])}); "
               f"{res['ambiguous']} with ambiguity >= 0.3")
    for key in ("all", "ambiguous"):
        click.echo(f"\n{key} runs: | method | runs | FMI median [20-80%] | CE cm median [20-80%] |")
        for m, s in res["summary"][key].items():
            click.echo(f"| {m} | {s['runs']} | {s['fmi']:.3f} [{s['fmi_lo']:.3f}-{s['fmi_hi']:.3f}] | "
                       f"{s['ce_cm']:.2f} [{s['ce_lo']:.2f}-{s['ce_hi']:.2f}] |")
    say(settings, f"{res['wall_s']:.1f} s -> {out_dir / 'training.csv'}, {out_dir / 'fig5.png'}")


@study.command("tune")
@_options
@click.option("--methods", default="all", show_default=True)
@click.option("--values", "values_json", default=None,
              help='JSON {"method": ["param", [v, ...]]} replacing the default grid of those methods.')
@global_options(own_jobs=True)
@pass_settings
def tune_cmd(settings: Settings, scenes, seeds, out_dir, jobs, max_actions, methods, values_json) -> None:
    """Sweep STUCCO's characteristic length and each baseline's main parameter on the training set; report the
    chosen values (highest median FMI; within 0.01 of it, lowest median CE). Defaults are not changed."""
    writable_dir("--out", out_dir)
    from pipeline.evaluate import parse_methods
    from pipeline.registry import tune_grid
    from pipeline.studies.tuning import tune

    names, seed_list = _grid(scenes, seeds)
    method_list = parsed("--methods", parse_methods, methods)
    known = tune_grid()
    grid = {m: known[m] for m in method_list if m in known}
    if values_json:
        try:
            extra = {k: (v[0], tuple(float(x) for x in v[1])) for k, v in json.loads(values_json).items()}
        except (ValueError, TypeError, IndexError, AttributeError) as e:
            raise click.BadParameter(f"not a JSON object of method -> [param, [values]]: {e}",
                                     param_hint="--values") from None
        grid.update(extra)
    with user_errors("study tune"):
        res = tune(out_dir, grid, names, seed_list, root_seed=settings.seed, jobs=jobs or settings.jobs,
                   progress=bars_off(settings), max_actions=max_actions)
    click.echo("| method | parameter | value | runs | median FMI | median CE cm | |")
    for s in res["table"]:
        flag = ("chosen" if s["chosen"] else "") + (" default" if s["default"] else "")
        click.echo(f"| {s['method']} | {s['parameter']} | {s['value']:g} | {s['runs']} | {s['fmi']:.3f} | "
                   f"{s['ce_cm']:.2f} | {flag.strip()} |")
    for m, c in res["chosen"].items():
        click.echo(f"{m}: {c['parameter']} = {c['value']:g} (default {c['default']:g})")
    say(settings, f"{res['runs']} runs, {res['wall_s']:.1f} s -> {out_dir / 'tune.csv'}")
