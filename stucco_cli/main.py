"""`stucco` entry point: the click group, its shared options, and the registration of every command.

Commands live in sibling modules (one per stage family) and only parse options, call :mod:`pipeline`, and report;
what they share is in :mod:`stucco_cli.common`. Command modules import their stage lazily, inside the command, so
that `stucco --help` stays fast; they do not import this module, so the CLI has no import cycle.
"""
from __future__ import annotations

import logging

import click

from pipeline import __version__
from stucco_cli import bench, evaluate, retrieve, score, sim, study, track
from stucco_cli.common import JOBS, Settings


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Root seed; every random draw of every stage derives from it.")
@click.option("--jobs", "-j", type=JOBS, default=1, show_default=True,
              help="Parallel worker processes for stages that process independent runs.")
@click.option("-v", "--verbose", count=True, help="More log output (repeatable).")
@click.option("-q", "--quiet", is_flag=True, help="Only errors; no progress bars.")
@click.version_option(__version__, prog_name="stucco")
@click.pass_context
def cli(ctx: click.Context, seed: int, jobs: int, verbose: int, quiet: bool) -> None:
    """STUCCO: track contact points in clutter, segment them into objects, retrieve a target blind."""
    verbosity = -1 if quiet else verbose
    ctx.obj = Settings(seed=seed, jobs=jobs, verbosity=verbosity)
    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")


for _command in (sim.scenes, sim.collect, sim.isolate, track.track, track.segment, retrieve.retrieve, score.score,
                 evaluate.evaluate, study.study, bench.bench):
    cli.add_command(_command)
