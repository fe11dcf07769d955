"""`stucco track` and `stucco segment`."""
from __future__ import annotations

from pathlib import Path

import click

from pipeline import registry
from stucco_cli.common import (
    ALPHA,
    FORCE_OVERWRITE,
    NON_NEGATIVE,
    ONE_PROCESS,
    POSITIVE,
    FiniteFloat,
    Settings,
    check_paths,
    global_options,
    pass_settings,
    refuse_overwrite,
    say,
    user_errors,
)
from stucco_cli.progress import run_bar

#: Particles beyond this are refused where they enter: the filter holds (particles, points, 2) float64 arrays, so
#: 1e5 particles over 1,000 tracked points is already 1.6 GB.
MAX_PARTICLES = 100_000



# tracker parameter -> its option name, where they differ
_STUCCO_OPTIONS = {"n_particles": "particles"}


def _parse_sets(values: tuple[str, ...]) -> dict:
    """--set KEY=VALUE pairs -> dict; values parsed as int, float, bool or string."""
    out = {}
    for item in values:
        if "=" not in item:
            raise click.BadParameter(f"expected KEY=VALUE, got {item!r}", param_hint="--set")
        key, raw = item.split("=", 1)
        val: object = raw
        for conv in (int, float):
            try:
                val = conv(raw)
                break
            except ValueError:
                pass
        if raw.lower() in ("true", "false"):
            val = raw.lower() == "true"
        out[key.strip().replace("-", "_")] = val
    return out


def _check_options(method: str, name: str) -> None:
    """A dedicated option (``--length``) is refused, naming the methods that take it, for a method without it."""
    from dataclasses import fields

    with user_errors("track"):
        spec = registry.tracker(method)
    takes = [s.name for s in registry.trackers() if name in {f.name for f in fields(registry.resolve(s.params))}]
    if name not in {f.name for f in fields(registry.resolve(spec.params))}:
        option = _STUCCO_OPTIONS.get(name, name.replace("_", "-"))
        raise click.UsageError(f"--{option} applies to --method {', '.join(takes)} only; "
                               "use --set KEY=VALUE for this method's parameters")


@click.command()
@click.option("--in", "in_path", required=True, type=click.Path(path_type=Path), help="Contacts table (Parquet).")
@click.option("--out", "out_path", required=True, type=click.Path(path_type=Path), help="Tracks table to write.")
@click.option("--diagnostics", "diag_path", type=click.Path(path_type=Path), default=None,
              help="Per-step diagnostics table [default: OUT with suffix .diagnostics.parquet].")
@click.option("--method", default=registry.tracker_names()[0], show_default=True,
              help=f"Tracking method: {', '.join(registry.tracker_names())} (pipeline/registry.py).")
@click.option("--robot", default="panda", show_default=True, help="'panda' or 'disc:RADIUS' (metres).")
@click.option("--particles", "n_particles", type=click.IntRange(1, MAX_PARTICLES), default=None,
              help="N particles [100].")
@click.option("--length", type=POSITIVE, default=None, help="Characteristic length l, m^2 [0.02].")
@click.option("--penetration-length", type=POSITIVE, default=None, help="Penetration length l_p, m^2 [0.002].")
@click.option("--alpha", type=ALPHA, default=None, help="Connection threshold of Alg. 3, in (0, 1) [0.4].")
@click.option("--tolerance", type=NON_NEGATIVE, default=None, help="Ignored penetration depth, m [0.002].")
@click.option("--weighting", type=click.Choice(["reference", "paper"]), default=None,
              help="Particle weighting rule [reference].")
@click.option("--replace", type=click.Choice(["after-resample", "every-step", "never"]), default=None,
              help="When ReplaceInconsistentPoints runs [after-resample].")
@click.option("--ess-threshold", type=FiniteFloat(0.0, 1.0), default=None,
              help="Resample when ESS/N is below this [0.8].")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Any other tracker parameter (e.g. baselines: --set eps=0.05).")
@click.option("--scene", "scene_name", default=None, metavar="NAME|FILE",
              help="Start from the parameters the scene's robot was tuned with (its [methods.<method>], e.g. "
                   "REAL's Table I real column), as `stucco evaluate` does; options and --set override them.")
@click.option("--every-step", is_flag=True, help="Also write the estimate after every step.")
@click.option("--threads", type=click.IntRange(min=1), default=None,
              help="Threads of STUCCO's particle loops [1, or $STUCCO_THREADS]; results do not depend on it. "
                   "More than one only pays on otherwise idle cores.")
@FORCE_OVERWRITE
@global_options()
@pass_settings
def track(settings: Settings, in_path: Path, out_path: Path, diag_path: Path | None, method: str, robot: str,
          sets: tuple[str, ...], scene_name: str | None, every_step: bool, threads: int | None, force_overwrite: bool,
          **stucco_opts) -> None:
    """Track contact points of every run of a contacts table (STUCCO soft tracking or a baseline)."""
    from pipeline.track.stage import TrackConfig, default_diagnostics_path, track_file

    if threads is not None:
        from pipeline.track.kernels import set_threads

        set_threads(threads)
    params = {k: v for k, v in stucco_opts.items() if v is not None}
    if params:
        _check_options(method, next(iter(params)))
    if scene_name is not None:
        from pipeline.scenes import load_scene

        with user_errors("--scene"):
            params = {**load_scene(scene_name).hardware.method_params(method), **params}
    params.update(_parse_sets(sets))
    diag_path = diag_path or default_diagnostics_path(out_path)
    check_paths({"--in": in_path}, {"--out": out_path, "--diagnostics": diag_path})
    refuse_overwrite({"--out": out_path, "--diagnostics": diag_path}, force_overwrite)
    with user_errors("track"):
        config = TrackConfig(method=method, robot=robot, params=params, every_step=every_step)
    with user_errors("track"):
        tracks, diagnostics = track_file(in_path, out_path, config, seed=settings.seed, jobs=settings.jobs,
                                         diagnostics_path=diag_path, progress=run_bar(settings, "track"))
    n_runs = len(set(tracks.column("run").to_pylist()))
    ms = diagnostics.column("update_ms").to_numpy()
    say(settings, f"tracked {n_runs} run(s), {tracks.num_rows} point rows -> {out_path} "
                  f"({ms.sum() / 1e3:.2f} s in updates; diagnostics -> {diag_path})")


@click.command()
@click.option("--in", "in_path", required=True, type=click.Path(path_type=Path), help="Tracks table (Parquet).")
@click.option("--out", "out_path", required=True, type=click.Path(path_type=Path), help="Segments table to write.")
@click.option("--by", type=click.Choice(["auto", "components", "tracker"]), default="auto", show_default=True,
              help="Alg. 3 connected components, the tracker's own labels, or auto (components for stucco).")
@click.option("--length", type=POSITIVE, default=None, help="Characteristic length l, m^2 [from the tracks metadata].")
@click.option("--alpha", type=ALPHA, default=None, help="Connection threshold, in (0, 1) [from the tracks metadata].")
@click.option("--plot", "plot_path", type=click.Path(path_type=Path), default=None,
              help="Also draw the final segments of the first runs over their scenes to this PNG.")
@click.option("--runs", "run_dir", type=click.Path(path_type=Path), default=None,
              help="Run files (folder or file) for --plot's scenes [found beside the tracks, as `stucco plot` does].")
@click.option("--print", "print_table", is_flag=True, help="Print one line per segment to stdout.")
@FORCE_OVERWRITE
@global_options(jobs=ONE_PROCESS)
@pass_settings
def segment(settings: Settings, in_path: Path, out_path: Path, by: str, length: float | None, alpha: float | None,
            plot_path: Path | None, run_dir: Path | None, print_table: bool, force_overwrite: bool) -> None:
    """Group tracked contact points into objects (Alg. 3 on the MAP particle, or the baseline's clusters)."""
    from pipeline.segment import segment_file, summarise

    if run_dir is not None and plot_path is None:
        raise click.UsageError("--runs names the scenes of --plot; give --plot FILE.png too")
    check_paths({"--in": in_path, "--runs": run_dir}, {"--out": out_path, "--plot": plot_path})
    refuse_overwrite({"--out": out_path, "--plot": plot_path}, force_overwrite)
    notes: list[str] = []
    with user_errors("segment"):  # the table and its plot appear together or not at all
        if plot_path is None:
            segments = segment_file(in_path, out_path, seed=settings.seed, length=length, alpha=alpha, by=by)
        else:
            from pipeline.figures import segments_with_plot

            segments, notes = segments_with_plot(in_path, out_path, plot_path, seed=settings.seed, runs=run_dir,
                                                 length=length, alpha=alpha, by=by)
    if print_table:
        rows = summarise(segments)
        click.echo(f"{'run':<16} {'segment':>7} {'points':>6} {'centroid_x_m':>12} {'centroid_y_m':>12} {'run_FMI':>8}")
        for r in rows:
            fmi = "" if r["run_fmi"] is None else f"{r['run_fmi']:.3f}"
            click.echo(f"{r['run']:<16} {r['segment']:>7} {r['n_points']:>6} {r['centroid_x_m']:>12.4f} "
                       f"{r['centroid_y_m']:>12.4f} {fmi:>8}")
    for note in notes:
        say(settings, f"plot: {note}")
    n_runs = len(set(segments.column("run").to_pylist()))
    say(settings, f"segmented {n_runs} run(s), {segments.num_rows} rows -> {out_path}"
                  + (f" (plot: {plot_path})" if plot_path else ""))
