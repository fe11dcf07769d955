"""`stucco bench ...`: benchmarks that print tables (speed is measured here, never in tests)."""
from __future__ import annotations

import json
from pathlib import Path

import click

from stucco_cli.main import cli, pass_settings


@cli.group()
def bench() -> None:
    """Benchmarks: what accuracy costs in time."""


def _ints(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(t) for t in text.split(","))
    except ValueError:
        raise click.BadParameter(f"expected comma-separated integers, got {text!r}") from None


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
@click.option("--json", "json_path", type=click.Path(path_type=Path), default=None, help="Also save every figure.")
def bench_track(streams, t_list, n_list, repeats, accuracy_seeds, methods, reference_python, json_path) -> None:
    """Replay the authors' anchor streams: time per update, memory, FMI and CE, against the reference."""
    from pipeline.bench import track_bench

    res = track_bench(_ints(t_list), _ints(n_list), repeats=repeats, acc_seeds=accuracy_seeds, streams=streams,
                      reference_python=reference_python, methods=tuple(methods.split(",")), echo=click.echo)
    if json_path:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps(res, indent=1))


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(t) for t in text.split(",") if t.strip())
    except ValueError:
        raise click.BadParameter(f"expected comma-separated numbers, got {text!r}") from None


@bench.command("accuracy")
@click.option("--scenes", default="all", show_default=True, help="Comma-separated retrieval tasks, or 'all'.")
@click.option("--seeds", default="0-4", show_default=True, help="Run seeds: N, N-M, or a comma-separated list.")
@click.option("--N", "n_list", default="10,30,100,300,1000", show_default=True, help="STUCCO particle counts.")
@click.option("--restarts", "restart_list", default="5,10,30", show_default=True, help="ICP restarts (N = 100).")
@click.option("--sdf-mm", "sdf_list", default="1,2,4", show_default=True, help="Gripper SDF cell sizes, mm.")
@click.option("--baselines", default="birch,dbscan,kmeans,gmphd", show_default=True,
              help="Baselines at their defaults ('' for none).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=Path("out/accuracy"),
              show_default=True, help="Runs, contacts, accuracy.csv, summary.csv, pareto.png.")
@click.option("--jobs", "-j", type=click.IntRange(min=1), default=None, help="Processes over (scene, seed).")
@pass_settings
def bench_accuracy(settings, scenes, seeds, n_list, restart_list, sdf_list, baselines, out_dir, jobs) -> None:
    """What accuracy costs in time: every knob setting and baseline on a (scene, seed) grid; a table and a Pareto
    PNG of time per run against CE, FMI and grasp success."""
    import pyarrow as pa

    from pipeline.collect import parse_seeds
    from pipeline.evaluate import parse_scenes
    from pipeline.study import (_write_csv, accuracy_bench, accuracy_settings, pareto_figure, summarise_settings,
                                summary_markdown)
    from stucco_cli.main import user_errors

    try:
        scene_list = parse_scenes(scenes)
    except ValueError as e:
        raise click.BadParameter(str(e), param_hint="--scenes") from None
    try:
        seed_list = parse_seeds(seeds)
    except ValueError as e:
        raise click.BadParameter(str(e), param_hint="--seeds") from None
    sweep = accuracy_settings(_ints(n_list), _ints(restart_list), _floats(sdf_list),
                              tuple(b for b in baselines.split(",") if b.strip()))
    with user_errors("bench accuracy"):
        table = accuracy_bench(out_dir, scene_list, seed_list, sweep, root_seed=settings.seed,
                               jobs=jobs or settings.jobs, progress=settings.progress)
        rows = summarise_settings(table)
        _write_csv(pa.Table.from_pylist(rows), out_dir / "summary.csv")
        png = pareto_figure(rows, out_dir / "pareto.png")
    click.echo(summary_markdown(rows), nl=False)
    k = [r["setting"] for r in rows if r.get("knee")]
    if k:
        click.echo(f"knee (cheapest N within 10% of the best median CE of the N sweep): {k[0]}")
    click.echo(f"-> {out_dir / 'accuracy.csv'}, {out_dir / 'summary.csv'}, {png}", err=True)
