"""`stucco score`: the Table II metrics of a retrieval (grasp success, FMI, contact error, pose error, times)."""
from __future__ import annotations

from pathlib import Path

import click

from stucco_cli.common import (
    FORCE_OVERWRITE,
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
@click.option("--retrieval", "retrieval_path", required=True, type=click.Path(path_type=Path),
              help="Retrieval table from `stucco retrieve`.")
@click.option("--segments", "segments_path", required=True, type=click.Path(path_type=Path),
              help="The segments table the retrieval was made from.")
@click.option("--runs", "run_dir", required=True, type=click.Path(path_type=Path),
              help="Directory of the collected run files, or one run file.")
@click.option("--out", "out_path", required=True, type=click.Path(path_type=Path), help="Scores table to write.")
@click.option("--diagnostics", "diag_path", type=click.Path(path_type=Path), default=None,
              help="Track diagnostics table for tracking times [default: found next to the segments file].")
@click.option("--print", "print_table", is_flag=True, help="Print a summary per (scene, method) to stdout.")
@FORCE_OVERWRITE
@global_options(jobs=ONE_PROCESS)
@pass_settings
def score(settings: Settings, retrieval_path: Path, segments_path: Path, run_dir: Path, out_path: Path,
          diag_path: Path | None, print_table: bool, force_overwrite: bool) -> None:
    """Score runs: grasp success, FMI, contact error (cm), position error (cm), yaw error (rad) and stage timings."""
    from pipeline.score import diagnostics_beside, score_file, summary_lines

    inputs = {"--retrieval": retrieval_path, "--segments": segments_path, "--runs": run_dir}
    check_paths(dict(inputs, **{"--diagnostics": diag_path}), {"--out": out_path})
    diag_path = diag_path or diagnostics_beside(segments_path)
    check_paths(dict(inputs, **{"--diagnostics": diag_path}), {"--out": out_path})
    refuse_overwrite({"--out": out_path}, force_overwrite)
    with user_errors("score"):
        table = score_file(retrieval_path, segments_path, run_dir, out_path, seed=settings.seed,
                           diagnostics_path=diag_path)
    if print_table:
        for line in summary_lines(table):
            click.echo(line)
    say(settings, f"scored {table.num_rows} run(s) -> {out_path}")
