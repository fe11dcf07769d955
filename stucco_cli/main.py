"""`stucco` entry point: the click group, its shared options, and the registration of every command.

Commands live in sibling modules (one per stage family) and only parse options, call :mod:`pipeline`, and report;
what they share is in :mod:`stucco_cli.common`. Command modules import their stage lazily, inside the command, so
that `stucco --help` stays fast; they do not import this module, so the CLI has no import cycle.

The global options (``--seed``, ``-j``, ``-v``, ``-q``) may also follow the command name, with the same meaning
(:func:`stucco_cli.common.global_options`; docs/cli.md).
"""
from __future__ import annotations

import click

from pipeline import __version__
from stucco_cli import bench, bench_runs, bench_scale, evaluate, plot, retrieve, score, sim, study, track
from stucco_cli.common import JOBS, SEED, Settings, configure_logging

_ANYWHERE = " May also follow the command name."


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--seed", type=SEED, default=0, show_default=True,
              help="Root seed; every random draw of every stage derives from it." + _ANYWHERE)
@click.option("--jobs", "-j", type=JOBS, default=1, show_default=True,
              help="Parallel worker processes for stages that process independent runs." + _ANYWHERE)
@click.option("-v", "--verbose", count=True, help="More log output (repeatable)." + _ANYWHERE)
@click.option("-q", "--quiet", is_flag=True, help="Only errors; no progress bars, no summary lines." + _ANYWHERE)
@click.version_option(__version__, prog_name="stucco")
@click.pass_context
def cli(ctx: click.Context, seed: int, jobs: int, verbose: int, quiet: bool) -> None:
    """STUCCO: track contact points in clutter, segment them into objects, retrieve a target blind.

    Shell completion: eval "$(_STUCCO_COMPLETE=bash_source stucco)" (docs/cli.md).
    """
    verbosity = -1 if quiet else verbose
    ctx.obj = Settings(seed=seed, jobs=jobs, verbosity=verbosity)
    configure_logging(verbosity)


for _command in (sim.scenes, sim.collect, sim.isolate, track.track, track.segment, retrieve.retrieve, score.score,
                 plot.plot, evaluate.evaluate, study.study, bench.bench):
    cli.add_command(_command)
for _command in (bench_runs.bench_retrieval, bench_runs.bench_pushes, bench_runs.bench_grasp_sensitivity,
                 bench_runs.bench_probe, bench_runs.bench_explore, bench_scale.bench_scale, sim.sim_bench):
    bench.bench.add_command(_command)
