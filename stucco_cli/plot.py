"""`stucco plot`: one run of any stage's table (run, contacts, tracks, segments, retrieval) drawn over its scene."""
from __future__ import annotations

from pathlib import Path

import click

from stucco_cli.common import (
    FORCE_OVERWRITE,
    NOT_RANDOM,
    ONE_PROCESS,
    Settings,
    check_paths,
    global_options,
    pass_settings,
    refuse_overwrite,
    say,
    user_errors,
)


@click.command()
@click.option("--in", "in_path", required=True, type=click.Path(path_type=Path),
              help="A table of any stage: a run file (collect), contacts, tracks, segments or retrieval.")
@click.option("--out", "out_path", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Figure to write (PNG; another matplotlib format by its suffix, e.g. .svg, .pdf).")
@click.option("--run", default=None, help="Run to draw, e.g. FB/0 [the table's first].")
@click.option("--runs", "run_dir", type=click.Path(path_type=Path), default=None,
              help="Folder of the run files (or one run file) the table was made from [found beside the table: its "
                   "folder, or a runs/ folder there or above].")
@FORCE_OVERWRITE
@global_options(jobs=ONE_PROCESS, seed=NOT_RANDOM)
@pass_settings
def plot(settings: Settings, in_path: Path, out_path: Path, run: str | None, run_dir: Path | None,
         force_overwrite: bool) -> None:
    """Draw one run of a table over its scene: objects at their final poses (target shaded, named), the gripper's
    trail (the probing policy's actions in amber), and the table's own layer: true contact points (run),
    isolated contacts (contacts), tracked points by label (tracks), points by segment with the true object as
    marker (segments), or the estimate and the grasp attempted at it (retrieval). The scene is the one the run
    file carries (checked against the table's recorded run digests)."""
    check_paths({"--in": in_path, "--runs": run_dir}, {"--out": out_path})
    if not in_path.is_file():
        raise click.ClickException(f"{in_path}: no such file (--in takes a table, e.g. a run file or segments.parquet)")
    refuse_overwrite({"--out": out_path}, force_overwrite)
    from pipeline.figures import plot_table

    with user_errors("plot"):
        path, drawn, kind = plot_table(in_path, out_path, run=run, runs=run_dir)
    say(settings, f"drew run {drawn} of the {kind} table {in_path} -> {path}")
