"""`stucco retrieve`: pose estimation of the target and the simulated grasp."""
from __future__ import annotations

from pathlib import Path

import click

from stucco_cli.common import Settings, check_paths, pass_settings, user_errors


def _progress(settings: Settings, desc: str):
    from tqdm import tqdm

    return lambda it, total: tqdm(it, total=total, desc=desc, unit="run", disable=settings.progress)


def _side_path(out_path: Path, suffix: str) -> Path:
    return out_path.with_name(out_path.name.removesuffix(".parquet") + suffix)


@click.command()
@click.option("--segments", "segments_path", required=True, type=click.Path(path_type=Path),
              help="Segments table (Parquet) from `stucco segment`.")
@click.option("--runs", "run_dir", required=True, type=click.Path(path_type=Path),
              help="Directory of the collected run files (`stucco collect --out`), or one run file.")
@click.option("--out", "out_path", required=True, type=click.Path(path_type=Path),
              help="Retrieval table to write (one row per run).")
@click.option("--candidates", "cand_path", type=click.Path(path_type=Path), default=None,
              help="Candidates table (one row per run, segment, restart) [default: OUT with suffix "
                   ".candidates.parquet].")
@click.option("--estimator", type=click.Choice(["plausible", "paper"]), default="plausible", show_default=True,
              help="plausible: the paper's segment choice, then the best pose of a plausible set fitted to the "
                   "target's shape, the contacts and the gripper's free space; paper: the paper's ICP procedure.")
@click.option("--restarts", type=click.IntRange(2, 1000), default=None, help="ICP restarts per segment [30].")
@click.option("--hypotheses", type=click.IntRange(1, 4096), default=None,
              help="Pose hypotheses of the plausible estimator [32].")
@click.option("--method", default=None, help="Tracking method to record [from the segments metadata].")
@click.option("--grasp/--no-grasp", default=True, show_default=True,
              help="Simulate the grasp at each estimate (pybullet).")
@click.option("--print", "print_table", is_flag=True, help="Print one line per run to stdout.")
@pass_settings
def retrieve(settings: Settings, segments_path: Path, run_dir: Path, out_path: Path, cand_path: Path | None,
             estimator: str, restarts: int | None, hypotheses: int | None, method: str | None, grasp: bool,
             print_table: bool) -> None:
    """Estimate the target pose of every run from its segments and grasp it in simulation."""
    from pipeline import schema
    from pipeline.grasp import GraspParams
    from pipeline.methods import METHOD_ORDER
    from pipeline.retrieve import PlausibleParams, RetrievalParams, retrieve_file

    def known(m: str) -> str:
        if m not in METHOD_ORDER:
            raise click.BadParameter(f"unknown method {m!r}; expected one of {', '.join(METHOD_ORDER)}",
                                     param_hint="--method")
        return m

    if method is not None:
        known(method)
    cand_path = cand_path or _side_path(out_path, ".candidates.parquet")
    check_paths({"--segments": segments_path, "--runs": run_dir}, {"--out": out_path, "--candidates": cand_path})
    with user_errors():  # a bad segments file is refused before --method is taken from its metadata
        schema.read_segments(segments_path)
        meta = schema.read_metadata(segments_path)
    method = known(method or str((meta.get("params") or {}).get("method", "stucco")))
    with user_errors("retrieve"):
        params = RetrievalParams(**({} if restarts is None else {"n_restarts": restarts}))
        plausible = PlausibleParams(**({} if hypotheses is None else {"n_hypotheses": hypotheses}))
        table, _ = retrieve_file(segments_path, run_dir, out_path, cand_path, seed=settings.seed, method=method,
                                 grasp_params=GraspParams(), estimator=estimator, params=params,
                                 plausible_params=plausible, grasp=grasp, jobs=settings.jobs,
                                 progress=_progress(settings, "retrieve"))
    if print_table:
        click.echo(f"{'run':<10} {'x_m':>7} {'y_m':>7} {'yaw':>6} {'seg':>4} {'pts':>4} {'pos_err_cm':>10} "
                   f"{'yaw_err':>7} {'grasp':>6}  notes / outcome")
        for r in table.to_pylist():
            g = "-" if r["grasp_success"] is None else ("yes" if r["grasp_success"] else "no")
            click.echo(f"{r['run']:<10} {r['x_m']:7.3f} {r['y_m']:7.3f} {r['yaw_rad']:6.2f} {r['segment']:>4} "
                       f"{r['n_points']:>4} {r['position_error_m'] * 100:10.2f} {r['yaw_error_rad']:7.3f} {g:>6}  "
                       f"{r['notes'] or '-'} / {r['grasp_outcome'] or '-'}")
    if settings.verbosity >= 0:
        icp = sum(table.column("icp_s").to_pylist())
        gs = [v for v in table.column("grasp_s").to_pylist() if v is not None]
        ok = [v for v in table.column("grasp_success").to_pylist() if v is not None]
        click.echo(f"retrieved {table.num_rows} run(s) with the {estimator} estimator -> {out_path} "
                   f"(candidates -> {cand_path}); estimation {icp:.2f} s"
                   + (f", grasps {sum(ok)}/{len(ok)} in {sum(gs):.2f} s" if gs else ""), err=True)
