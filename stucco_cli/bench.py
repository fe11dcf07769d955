"""`stucco bench ...`: benchmarks that print tables (speed is measured here, never in tests)."""
from __future__ import annotations

import json
from pathlib import Path

import click

from stucco_cli.main import cli


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
