"""`stucco retrieve`: pose estimation of the target and the simulated grasp, or the pose alone from a robot's
log."""
from __future__ import annotations

from pathlib import Path

import click

from pipeline import registry
from stucco_cli.common import (
    FORCE_OVERWRITE,
    Settings,
    check_paths,
    global_options,
    pass_settings,
    refuse_overwrite,
    say,
    user_errors,
)
from stucco_cli.progress import run_bar


def _side_path(out_path: Path, suffix: str) -> Path:
    return out_path.with_name(out_path.name.removesuffix(".parquet") + suffix)


@click.command()
@click.option("--segments", "segments_path", required=True, type=click.Path(path_type=Path),
              help="Segments table (Parquet) from `stucco segment`.")
@click.option("--runs", "run_dir", default=None, type=click.Path(path_type=Path),
              help="Directory of the collected run files (`stucco collect --out`), or one run file.")
@click.option("--contacts", "contacts_path", default=None, type=click.Path(path_type=Path),
              help="A robot's log instead of simulated runs: the contacts table (Parquet or CSV) the segments were "
                   "tracked from; needs --target. No grasp is simulated.")
@click.option("--target", default=None,
              help="The target of a log: box:WxL (short side W, long side L, m), cylinder:R (radius, m), "
                   "either with @MASS_KG, or SCENE:OBJECT.")
@click.option("--out", "out_path", required=True, type=click.Path(path_type=Path),
              help="Retrieval table to write (one row per run).")
@click.option("--candidates", "cand_path", type=click.Path(path_type=Path), default=None,
              help="Candidates table (one row per run, segment, restart) [default: OUT with suffix "
                   ".candidates.parquet].")
@click.option("--estimator", type=registry.choices("estimator"), default=registry.DEFAULT_ESTIMATOR,
              show_default=True, help="Pose estimator: " + "; ".join(f"{s.name}: {s.title}" for s in
                                                                     registry.estimators())
              + " (pipeline/registry.py, docs/retrieval.md).")
@click.option("--restarts", type=click.IntRange(2, 1000), default=None, help="ICP restarts per segment [30].")
@click.option("--robot", default=None,
              help="The gripper whose trail is free space: 'panda' or 'disc:RADIUS' (metres), as `stucco track` "
                   "[the one the segments were tracked with; panda when they record none].")
@click.option("--hypotheses", type=click.IntRange(1, 4096), default=None,
              help="Pose hypotheses of the plausible estimator [32].")
@click.option("--method", default=None, help="Tracking method to record [from the segments metadata].")
@click.option("--grasp/--no-grasp", default=None,
              help="Simulate the grasp at each estimate (pybullet) [--grasp with --runs; a log has nothing to grasp].")
@click.option("--stream", type=click.IntRange(min=0), default=0, show_default=True,
              help="The estimator's random stream: 0 the default; 1, 2, ... independent reruns of a stochastic "
                   "estimator on the same segments (recorded in the metadata).")
@click.option("--print", "print_table", is_flag=True, help="Print one line per run to stdout.")
@FORCE_OVERWRITE
@global_options()
@pass_settings
def retrieve(settings: Settings, segments_path: Path, run_dir: Path | None, contacts_path: Path | None,
             target: str | None, out_path: Path, cand_path: Path | None,
             estimator: str, restarts: int | None, robot: str, hypotheses: int | None, method: str | None,
             grasp: bool | None,
             stream: int, print_table: bool, force_overwrite: bool) -> None:
    """Estimate the target pose of every run from its segments and grasp it in simulation (--runs), or estimate
    it from a robot's log (--contacts with --target)."""
    if (run_dir is None) == (contacts_path is None):
        raise click.UsageError("give --runs (simulated runs) or --contacts with --target (a robot's log), not both")
    if contacts_path is not None and target is None:
        raise click.UsageError("--contacts (a robot's log) needs --target, the target's shape: e.g. "
                               "--target box:0.0616x0.1575 or --target cylinder:0.039")
    if run_dir is not None and target is not None:
        raise click.UsageError("--target is for a robot's log (--contacts); simulated runs carry their scene")
    if contacts_path is not None and grasp:
        raise click.UsageError("--grasp needs a simulated run (--runs): a robot's log has no scene to grasp in")
    grasp = grasp if grasp is not None else run_dir is not None
    from pipeline.grasp import GraspParams
    from pipeline.retrieve import RetrievalParams, RetrieveConfig, retrieve_file, tracking_robot

    def known(m: str) -> str:
        try:
            registry.tracker(m)
        except ValueError as e:
            raise click.BadParameter(str(e), param_hint="--method") from None
        return m

    if method is not None:
        known(method)
    cand_path = cand_path or _side_path(out_path, ".candidates.parquet")
    inputs = {"--segments": segments_path, **({"--runs": run_dir} if run_dir is not None else
                                              {"--contacts": contacts_path})}
    check_paths(inputs, {"--out": out_path, "--candidates": cand_path})
    refuse_overwrite({"--out": out_path, "--candidates": cand_path}, force_overwrite)
    with user_errors("retrieve"):  # without --method, the one the segments file records (retrieve_file)
        robot = robot or tracking_robot(segments_path) or "panda"
        params = RetrievalParams(robot=robot, **({} if restarts is None else {"n_restarts": restarts}))
        # --hypotheses sets the estimator's own n_hypotheses (the plausible one's); other estimators ignore it.
        fields = getattr(registry.resolve(registry.estimator(estimator).params), "__dataclass_fields__", {})
        own = {"n_hypotheses": hypotheses} if hypotheses is not None and "n_hypotheses" in fields else None
        config = RetrieveConfig(method=method, estimator=estimator, params=params, estimator_params=own,
                                grasp=grasp, grasp_params=GraspParams(), stream=stream)
        if contacts_path is not None:
            from pipeline.retrieve.log_route import retrieve_log_file

            table, _ = retrieve_log_file(segments_path, contacts_path, target, out_path, cand_path, config,
                                         seed=settings.seed, jobs=settings.jobs, progress=run_bar(settings, "retrieve"))
        else:
            table, _ = retrieve_file(segments_path, run_dir, out_path, cand_path, config, seed=settings.seed,
                                     jobs=settings.jobs, progress=run_bar(settings, "retrieve"))
    if print_table:
        click.echo(f"{'run':<10} {'x_m':>7} {'y_m':>7} {'yaw':>6} {'seg':>4} {'pts':>4} {'pos_err_cm':>10} "
                   f"{'yaw_err':>7} {'grasp':>6}  notes / outcome")
        for r in table.to_pylist():
            g = "-" if r["grasp_success"] is None else ("yes" if r["grasp_success"] else "no")
            pos = "-" if r["position_error_m"] is None else f"{r['position_error_m'] * 100:.2f}"
            yaw = "-" if r["yaw_error_rad"] is None else f"{r['yaw_error_rad']:.3f}"
            click.echo(f"{r['run']:<10} {r['x_m']:7.3f} {r['y_m']:7.3f} {r['yaw_rad']:6.2f} {r['segment']:>4} "
                       f"{r['n_points']:>4} {pos:>10} {yaw:>7} {g:>6}  "
                       f"{r['notes'] or '-'} / {r['grasp_outcome'] or '-'}")
    icp = sum(table.column("icp_s").to_pylist())
    gs = [v for v in table.column("grasp_s").to_pylist() if v is not None]
    ok = [v for v in table.column("grasp_success").to_pylist() if v is not None]
    say(settings, f"retrieved {table.num_rows} run(s) with the {estimator} estimator -> {out_path} "
                  f"(candidates -> {cand_path}); estimation {icp:.2f} s"
                  + (f", grasps {sum(ok)}/{len(ok)} in {sum(gs):.2f} s" if gs else ""))
