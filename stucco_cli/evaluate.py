"""`stucco evaluate`: the whole (scene, seed, method) grid of Table II, resumable, with its report."""
from __future__ import annotations

from pathlib import Path

import click

from pipeline import registry
from stucco_cli.common import (
    JOBS,
    Settings,
    global_options,
    parsed,
    pass_settings,
    policy_params,
    unique,
    user_errors,
    writable_dir,
)
from stucco_cli.progress import bars_off


@click.command()
@click.option("--scenes", default=None, help="Comma-separated retrieval tasks, scene files or folders of scene "
              "files (`stucco scenes generate`), or 'all' [FB,BC,IB,TC].")
@click.option("--seeds", default=None, help="Run seeds: N, N-M, or a comma-separated list [0-19].")
@click.option("--methods", default="all", show_default=True,
              help=f"Comma-separated: {', '.join(registry.tracker_names())}; or 'all' (every registered method).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Evaluation directory (one folder per stage table, report, figures) [out/evaluate; "
                   "out/quick with --quick].")
@click.option("--jobs", "-j", type=JOBS, default=None,
              help="Worker processes over jobs [the group's -j].")
@click.option("--quick", is_flag=True, help="A couple of seeds of one scene (FB 0-1), all methods, into out/quick.")
@click.option("--from-runs", "from_runs", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Replay the stored run files of this directory instead of simulating (scenes and seeds "
                   "default to all found there).")
@click.option("--max-actions", type=click.IntRange(min=1), default=None,
              help="Cut every simulated run after N actions (small test grids).")
@click.option("--restarts", type=click.IntRange(2, 1000), default=30, show_default=True,
              help="ICP restarts per segment.")
@click.option("--estimators", default="all", show_default=True,
              help=f"Pose estimators to run on every job (comma-separated: {', '.join(registry.estimator_names())}; "
                   "or 'all'); the report shows their grasp success side by side, the first one's figures.")
@click.option("--figures/--no-figures", default=True, show_default=True,
              help="Draw a figure per run and the summary figure.")
@click.option("--snapshot", "snapshot_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Also write the regression snapshot (contacts, segments, scores) to this directory.")
@click.option("--suite", type=click.Choice(["bor", "training"]), default="bor", show_default=True,
              help="bor: the retrieval grid (Table II); training: the training-set study of Fig. 5 "
                   "(= `stucco study training`, SELECT1-4 seeds 7-46 by default, into out/training).")
@click.option("--backend", type=click.Choice(["loky", "dask"]), default="loky", show_default=True,
              help="loky: -j local processes; dask: joblib's Dask backend on --scheduler (pip install "
                   "'stucco[dask]'; workers must see --out at the same path).")
@click.option("--scheduler", default=None, help="Dask scheduler address for --backend dask (tcp://HOST:8786).")
@click.option("--policy", type=registry.choices("policy"), default=None,
              help="How the retrieval scenes are collected [the retrieval default, scripted: the paper's protocol]; "
                   "scripted+probe: the active protocol, probes until the target's pose is known, then a grasp for "
                   "the whole plausible set (docs/retrieval.md, \"Active retrieval\").")
@click.option("--policy-param", "policy_param", multiple=True, metavar="NAME=VALUE",
              help="A parameter of the collection policy, e.g. action_budget=400 for --policy explore (repeatable; "
                   "docs/active.md).")
@click.option("--estimator-stream", "estimator_stream", type=click.IntRange(min=0), default=0, show_default=True,
              help="The pose estimators' random stream: 0 the default; 1, 2, ... rerun every stochastic estimator "
                   "with independent draws on the same segments, to see how much of a grasp success is its luck "
                   "(docs/evaluation.md, \"The estimator's own randomness\"; use one --out per stream).")
@global_options(own_jobs=True)
@pass_settings
def evaluate(settings: Settings, scenes: str | None, seeds: str | None, methods: str, out_dir: Path | None,
             jobs: int | None, quick: bool, from_runs: Path | None, max_actions: int | None, restarts: int,
             estimators: str, figures: bool, snapshot_dir: Path | None, suite: str, backend: str,
             scheduler: str | None, policy: str | None, estimator_stream: int, policy_param: tuple[str, ...]) -> None:
    """Run collect -> isolate -> track -> segment -> retrieve -> score for every (scene, seed, method), resuming
    where a previous call stopped, and write Table II (report.md, report.csv) and figures into --out."""
    for opt, d in (("--out", out_dir), ("--snapshot", snapshot_dir)):
        if d is not None:
            writable_dir(opt, d)  # before the evaluation, whose results a failed snapshot would not reach
    from pipeline.collect import parse_seeds
    from pipeline.evaluate import QUICK_SCENES, QUICK_SEEDS, EvalConfig, parse_methods, parse_scenes, scene_files

    if suite == "training":
        ctx = click.get_current_context()
        given = [p.opts[-1] if p.name != "figures" else "--figures/--no-figures" for p in ctx.command.params
                 if p.name in _NOT_TRAINING and ctx.get_parameter_source(p.name) not in
                 (click.core.ParameterSource.DEFAULT, None)]
        if given or quick:  # an option the suite would drop silently
            raise click.UsageError(f"{(given or ['--quick'])[0]} does not apply to --suite training, which takes "
                                   "--scenes, --seeds, --methods, --out, -j, --max-actions")
        from stucco_cli.study import training

        ctx.invoke(training, scenes=scenes or "SELECT1,SELECT2,SELECT3,SELECT4", seeds=seeds or "7-46",
                   out_dir=out_dir or Path("out/training"), jobs=jobs, max_actions=max_actions, methods=methods)
        return
    try:
        if scenes is not None:
            scene_list = parse_scenes(scenes, files=True)  # a scene file is collected from that file
        elif from_runs is not None:
            scene_list = None
        else:
            scene_list = QUICK_SCENES if quick else parse_scenes("all")
    except ValueError as e:
        raise click.BadParameter(str(e), param_hint="--scenes") from None
    try:
        if seeds is not None:
            seed_list = parse_seeds(seeds)
        elif from_runs is not None:
            seed_list = None
        else:
            seed_list = list(QUICK_SEEDS) if quick else parse_seeds("0-19")
    except ValueError as e:
        raise click.BadParameter(str(e), param_hint="--seeds") from None
    method_list = parsed("--methods", parse_methods, methods)
    from pipeline.estimators.estimate import parse_estimators

    estimator_list = unique("--estimators", parsed("--estimators", parse_estimators, estimators))
    if from_runs is not None and scenes is not None and scene_files(scenes):
        raise click.UsageError("--scenes takes scene names with --from-runs (stored runs carry their scenes)")
    if from_runs is not None and policy is not None:
        raise click.UsageError("--policy applies to simulated runs, not to --from-runs (stored runs carry theirs)")
    if from_runs is not None and policy_param:
        raise click.UsageError("--policy-param applies to simulated runs, not to --from-runs")
    params = policy_params(policy_param, policy or registry.default_policy("retrieval"))
    if from_runs is not None and max_actions is not None:
        raise click.UsageError("--max-actions applies to simulated runs, not to --from-runs")
    out_dir = out_dir or Path("out/quick" if quick else "out/evaluate")
    jobs = jobs or settings.jobs
    with user_errors("evaluate"):
        cfg = EvalConfig(root_seed=settings.seed, max_actions=max_actions, restarts=restarts,
                         source=None if from_runs is None else str(from_runs),
                         estimators=estimator_list, scene_files=() if scenes is None else scene_files(scenes),
                         policy=policy, estimator_stream=estimator_stream, policy_params=params)
    _run(settings, out_dir, scene_list, seed_list, method_list, cfg, jobs, figures, snapshot_dir, backend, scheduler)


def _run(settings: Settings, out_dir: Path, scenes, seeds, methods, cfg, jobs: int, figures: bool,
         snapshot_dir: Path | None, backend: str = "loky", scheduler: str | None = None) -> None:
    from pipeline.evaluate import config_lines, write_snapshot
    from pipeline.evaluate import evaluate as run_evaluate
    from pipeline.report import claims, table_ii, to_markdown

    with user_errors("evaluate"):
        ev = run_evaluate(out_dir, scenes, seeds, methods, cfg, jobs=jobs, progress=bars_off(settings),
                          figures=figures, backend=backend, scheduler=scheduler)
        if snapshot_dir is not None:
            written = write_snapshot(out_dir, ev.jobs, snapshot_dir, cfg)
    rows = table_ii(ev.scores)
    if settings.verbosity >= 0:
        click.echo(to_markdown(rows), nl=False)
        for line in claims(rows) + config_lines(cfg):
            click.echo(line)
        from pipeline.probe.report import probe_lines  # runs of the active protocol: their probes
        from pipeline.probe.summary import active_markdown, active_rows

        for line in probe_lines(out_dir, ev.jobs):
            click.echo(line)
        click.echo(active_markdown(active_rows(out_dir, ev.scores)), nl=False)
        ran = len(ev.results) - ev.skipped
        click.echo(f"{len(ev.jobs)} job(s): {ran} run, {ev.skipped} already done; {ev.wall_s:.1f} s wall "
                   f"(-j {jobs}) -> {out_dir}/report.md, report.csv" + (", figures/, summary.png" if figures else ""),
                   err=True)
        if snapshot_dir is not None:
            click.echo(f"snapshot -> {', '.join(str(p) for p in written)}", err=True)


#: The options of ``evaluate`` that ``--suite training`` has no use for (refused when given).
_NOT_TRAINING = ("backend", "scheduler", "from_runs", "snapshot_dir", "estimator_stream", "policy", "estimators",
                 "restarts", "figures")
