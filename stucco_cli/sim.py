"""`stucco scenes`, `stucco collect`, `stucco isolate` and `stucco bench sim`: the simulation stages."""
from __future__ import annotations

import json
import os
from pathlib import Path

import click

from pipeline import registry
from pipeline.safe_open import regular_file
from pipeline.scenes.parse import MAX_NOISE_MM  # one bound: the scene files' and the option's
from stucco_cli.common import (
    FORCE_OVERWRITE,
    NOT_RANDOM,
    ONE_PROCESS,
    FiniteFloat,
    Settings,
    check_paths,
    global_options,
    parsed,
    pass_settings,
    policy_params,
    refuse_overwrite,
    say,
    user_errors,
    writable_dir,
)
from stucco_cli.generate import generate_scenes_command
from stucco_cli.progress import bars_off


@click.group(invoke_without_command=True)
@global_options(jobs=ONE_PROCESS, seed=NOT_RANDOM)
@click.pass_context
def scenes(ctx: click.Context) -> None:
    """List the scenes (data/scenes/*.toml) with a one-line description each; `scenes generate` draws new ones."""
    if ctx.invoked_subcommand is not None:
        return
    from pipeline.scenes import SCENE_DIR, load_all

    with user_errors():
        for s in load_all(SCENE_DIR):
            click.echo(f"{s.name:<8} {s.kind:<9} {s.description}")


scenes.add_command(generate_scenes_command)


def _load(scene: str):
    from pipeline.scenes import load_scene

    with user_errors():
        return load_scene(scene)


def _not_shadowing(sc) -> None:
    """Refuse, in one line naming the file and its ``name`` field, a scene file that takes a shipped scene's name
    with other content: its runs would be filed, replayed and reported as that scene's."""
    from pipeline.scenes.files import shadows_shipped

    if shadows_shipped(sc):
        raise click.ClickException(
            f"{sc.path}: name = \"{sc.name}\" is the name of a shipped scene but the file differs from "
            f"data/scenes/{sc.name}.toml; rename it (e.g. name = \"my_{sc.name}\") so its runs are not taken "
            f"for {sc.name}'s")


@click.command()
@click.option("--scene", required=True, help="Scene name (see `stucco scenes`) or path to a scene .toml file.")
@click.option("--seeds", default="0", show_default=True, help="Run seeds: N, N-M, or a comma-separated list.")
@click.option("--policy", type=registry.choices("policy"), default=None,
              help="How the gripper moves: " + "; ".join(f"{s.name}: {s.title}" for s in registry.policies())
              + " [" + ", ".join(f"{s.name} for {' and '.join(s.default_for)} scenes" for s in registry.policies()
                                 if s.default_for) + "].")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Directory for one <scene>-<seed>.parquet per run.")
@click.option("--max-actions", type=click.IntRange(min=1), default=None, help="Stop each run after N actions.")
@click.option("--noise-mm", type=FiniteFloat(min=0.0, max=MAX_NOISE_MM), default=None,
              help="Override the scene's replay noise half-width (mm); 0.075 is the authors' code value.")
@click.option("--keep-discarded", is_flag=True, help="Also write greedy-walk runs that fail the discard rule.")
@click.option("--policy-param", "policy_param", multiple=True, metavar="NAME=VALUE",
              help="A parameter of the policy, e.g. action_budget=400 for --policy explore (repeatable).")
@FORCE_OVERWRITE
@global_options()
@pass_settings
def collect(settings: Settings, scene: str, seeds: str, policy: str | None, out_dir: Path, max_actions: int | None,
            noise_mm: float | None, keep_discarded: bool, policy_param: tuple[str, ...], force_overwrite: bool) -> None:
    """Simulate runs of a scene and record one Parquet file per seed (table `sim_run`, docs/simulation.md)."""
    writable_dir("--out", out_dir)
    from pipeline.collect import collect as run_collect
    from pipeline.collect import output_path, parse_seeds

    sc = _load(scene)
    _not_shadowing(sc)
    seed_list = parsed("--seeds", parse_seeds, seeds)
    policy = policy or registry.default_policy(sc.kind)
    if (gap := registry.policy(policy).missing(sc)) is not None:
        usable = [s.name for s in registry.policies() if s.missing(sc) is None]
        raise click.ClickException(f"{sc.path}: key '{gap[0]}': scene {sc.name} has no {gap[1]}"
                                   + (f"; use --policy {' or '.join(usable)}" if usable else ""))
    params = dict(policy_params(policy_param, policy)) or None
    if noise_mm is not None:
        sc = sc.with_effects(noise_mm=noise_mm)
    refuse_overwrite([("--out", output_path(out_dir, sc.name, s)) for s in seed_list], force_overwrite)
    with user_errors():
        results = run_collect(sc, seed_list, out_dir, policy=policy, root_seed=settings.seed, jobs=settings.jobs,
                              progress=bars_off(settings), max_actions=max_actions, keep_discarded=keep_discarded,
                              policy_params=params)
    for r in results:
        touched = ", ".join(f"{k} x{v}" for k, v in r.touched.items()) or "nothing"
        state = f"discarded ({r.discarded})" if r.discarded else ("written" if r.path else "not written")
        say(settings, f"{r.scene} seed {r.seed}: {r.n_actions} actions, {r.n_contact} in contact, touched "
                      f"{touched}; {state}; {r.wall_s:.2f} s")
    written = sum(1 for r in results if r.path)
    say(settings, f"wrote {written} run file(s) to {out_dir}"
                  + (f" ({len(results) - written} discarded)" if written < len(results) else ""))


@click.command()
@click.option("--in", "in_path", required=True, type=click.Path(path_type=Path),
              help="Directory of run files from `stucco collect` (or one run file).")
@click.option("--out", "out_path", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Contacts table to write (Parquet).")
@click.option("--report", is_flag=True, help="Print the isolation error (median, 90th percentile) to stdout.")
@FORCE_OVERWRITE
@global_options(jobs=ONE_PROCESS)
@pass_settings
def isolate(settings: Settings, in_path: Path, out_path: Path, report: bool, force_overwrite: bool) -> None:
    """Detect contacts from the wrench residual and isolate them on the gripper surface -> contacts table."""
    check_paths({"--in": in_path}, {"--out": out_path})
    from pipeline.isolate import isolate_file, run_files

    if in_path.is_dir():
        files = run_files(in_path)
        if not files:
            raise click.ClickException(f"{in_path}: no *.parquet run files (write them with `stucco collect`)")
    elif in_path.is_file():
        files = [in_path]
    elif not os.path.lexists(in_path):
        raise click.ClickException(f"{in_path}: does not exist")
    else:  # a FIFO, device or dangling link: named for what it is, never opened
        with user_errors():
            regular_file(in_path, "the run file")
    refuse_overwrite({"--out": out_path}, force_overwrite)
    with user_errors():
        res = isolate_file(files, out_path, seed=settings.seed)
    summary = res.error_summary()
    if report:
        if summary["n"]:
            click.echo(f"isolation error over {summary['n']} contacts: median {summary['median_m'] * 1000:.2f} mm, "
                       f"p90 {summary['p90_m'] * 1000:.2f} mm, mean {summary['mean_m'] * 1000:.2f} mm "
                       f"({res.n_runs} runs, {res.n_actions} actions, {res.n_contact} in contact, "
                       f"{res.n_unisolated} not isolated)")
        else:
            click.echo(f"isolation error: no contacts with a known true point ({res.n_runs} runs, "
                       f"{res.n_actions} actions)")
    say(settings, f"isolated {res.n_contact - res.n_unisolated} contact(s) of {res.n_contact} in contact over "
                  f"{res.n_actions} actions of {res.n_runs} run(s) -> {out_path}")


@click.command("sim")
@click.option("--scene", default="FB", show_default=True, help="Scene name or .toml path.")
@click.option("--actions", "n_actions", type=click.IntRange(min=1), default=None,
              help="Actions per measurement [the whole scripted sequence].")
@click.option("--repeat", type=click.IntRange(min=1), default=3, show_default=True,
              help="Measurements per variant (the minimum is reported).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table.")
@global_options(jobs=ONE_PROCESS, seed="it times one run with the scene's fixed draws")
def sim_bench(scene: str, n_actions: int | None, repeat: int, as_json: bool) -> None:
    """Time one scripted run of a scene with every effect on, then with each effect switched off."""
    from pipeline.studies.sim_effects import effect_costs

    sc = _load(scene)
    with user_errors():
        rows = effect_costs(sc, n_actions=n_actions, repeat=repeat)
    if as_json:
        click.echo(json.dumps(rows, indent=1))
        return
    click.echo(f"{'variant':<22} {'build s':>8} {'settle s':>9} {'actions s':>10} {'total s':>8} {'delta s':>8}")
    for r in rows:
        click.echo(f"{r['variant']:<22} {r['build_s']:>8.3f} {r['settle_s']:>9.3f} {r['actions_s']:>10.3f} "
                   f"{r['total_s']:>8.3f} {r['delta_s']:>+8.3f}")
