"""``stucco bench explore``: grasp success of the ``explore`` policy against its action budget, and against the
time its decisions take (docs/active.md, "Exploring without an action list").

A smaller action budget changes the run (the search is cut short and the probes start from there), so each
(scene, seed, budget) is its own run, collected into ``runs/b<budget>/`` when missing and read back otherwise; its
grasp is the active protocol's (:func:`pipeline.probe.retrieval.active_grasp`: the planned grasp, up to three
attempts, in the run's final state).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np

from pipeline import schema
from pipeline.atomic import save_figure, together, write_csv_rows
from pipeline.collect import collect_file, output_path
from pipeline.estimators.run_info import load_run
from pipeline.estimators.target_model import pose_error
from pipeline.evaluate.freshness import check_run_identity, check_run_settings
from pipeline.parallel import run_calls
from pipeline.probe.explore import ExploreParams
from pipeline.probe.report import run_stats
from pipeline.probe.retrieval import active_grasp
from pipeline.probe.summary import group_of
from pipeline.scenes import load_scene

__all__ = ["BUDGETS", "FIELDS", "budget_rows", "summarise", "write_outputs"]

#: Action budgets measured by default.
BUDGETS = (100, 200, 400, 2000)
FIELDS = ("scene", "group", "seed", "budget", "actions", "search_actions", "probes", "success", "success_any",
          "attempts", "position_error_m", "yaw_error_rad", "decision_s_median", "decision_s_max", "flagged")


def _one(scene_ref: str, seed: int, runs: Path, budget: int, root_seed: int, params: ExploreParams) -> dict:
    scene = load_scene(scene_ref)
    path = output_path(runs / f"b{budget}", scene.name, seed)
    params = dataclasses.replace(params, action_budget=budget)
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        collect_file(scene, seed, path, root_seed=root_seed, policy="explore", policy_params=params)
    # The run, its root seed, the scene, its effects and every parameter of the policy (the budget too).
    check_run_identity(path, scene.name, seed, root_seed, folder="--runs")
    check_run_settings(path, scene, "explore", None, params)
    info = load_run(path)
    r = active_grasp(info, root_seed)
    pe, ye = pose_error(info.target, r.pose, info.true_pose)
    probe = schema.probe_record(path)
    dec = np.asarray(run_stats(path)["decision_s"], dtype=np.float64)
    return dict(scene=scene.name, group=group_of(scene.name, scene.target.shape, scene.source), seed=seed,
                budget=budget, actions=len(info.steps),
                search_actions=int(probe["search"]["actions"]), probes=r.probes,
                success=bool(r.result.first_success), success_any=bool(r.result.success),
                attempts=len(r.result.attempts), position_error_m=pe, yaw_error_rad=ye,
                decision_s_median=float(np.median(dec)) if dec.size else None,
                decision_s_max=float(np.max(dec)) if dec.size else None, flagged=probe.get("flagged", ""))


def budget_rows(pairs: list[tuple[str, int]], runs: str | Path, budgets: tuple[int, ...] = BUDGETS,
                root_seed: int = 0, jobs: int = 1, progress: Callable | None = None,
                params: ExploreParams = ExploreParams()) -> list[dict]:
    """Rows (:data:`FIELDS`), one per (scene, seed) of ``pairs`` (a scene by name or file) and budget of
    ``budgets``, in that order; runs collected into ``runs`` when missing."""
    runs = Path(runs)
    runs.mkdir(parents=True, exist_ok=True)
    calls = [(sc, s, runs, b, root_seed, params) for sc, s in pairs for b in budgets]
    results = run_calls(_one, calls, jobs)
    if progress is not None:
        results = progress(results, total=len(calls))
    return list(results)


def summarise(rows: list[dict]) -> list[dict]:
    """Per group (paper task, or other scenes by target shape) and budget: runs, GS % at the first attempt and
    within the attempts, actions per run (median, largest), probes (mean), decision time (median of the runs'
    medians, largest), runs flagged ``budget_spent``."""
    out = []
    for g in dict.fromkeys(r["group"] for r in rows):
        for b in sorted({r["budget"] for r in rows if r["group"] == g}):
            sel = [r for r in rows if r["group"] == g and r["budget"] == b]
            med = [r["decision_s_median"] for r in sel if r["decision_s_median"] is not None]
            mx = [r["decision_s_max"] for r in sel if r["decision_s_max"] is not None]
            out.append(dict(group=g, budget=b, runs=len(sel),
                            gs_pct=100.0 * float(np.mean([r["success"] for r in sel])),
                            gs_any_pct=100.0 * float(np.mean([r["success_any"] for r in sel])),
                            actions_median=float(np.median([r["actions"] for r in sel])),
                            actions_max=int(max(r["actions"] for r in sel)),
                            probes_mean=float(np.mean([r["probes"] for r in sel])),
                            decision_s_median=float(np.median(med)) if med else float("nan"),
                            decision_s_max=float(np.max(mx)) if mx else float("nan"),
                            budget_spent=int(sum(r["flagged"] == "budget_spent" for r in sel))))
    return out


@together()  # its outputs appear all together or not at all
def write_outputs(rows: list[dict], summary: list[dict], out: str | Path, png: str | Path | None = None
                  ) -> list[Path]:
    """``explore_budget.csv`` (rows), ``explore_budget_summary.csv`` and the PNG (GS % against the median
    actions per run and against the median decision time, one line per group; ``png`` or
    ``out/explore_budget.png``), each written atomically."""
    import matplotlib  # imported here: only this output draws

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "explore_budget.csv", out / "explore_budget_summary.csv", Path(png or out / "explore_budget.png")]
    write_csv_rows(paths[0], rows, list(FIELDS))
    write_csv_rows(paths[1], summary, list(summary[0]) if summary else ["group", "budget"])
    fig, axes = plt.subplots(1, 2, figsize=(9.5, 3.6), sharey=True)
    for g in dict.fromkeys(s["group"] for s in summary):
        sel = [s for s in summary if s["group"] == g]
        axes[0].plot([s["actions_median"] for s in sel], [s["gs_pct"] for s in sel], marker="o", label=g)
        axes[1].plot([s["decision_s_median"] for s in sel], [s["gs_pct"] for s in sel], marker="o", label=g)
    axes[0].set_xlabel("actions per run (median), one point per action budget")
    axes[1].set_xlabel("decision time, s (median)")
    axes[0].set_ylabel("grasp success, first attempt (%)")
    for ax in axes:
        ax.set_ylim(0, 102)
        ax.axhline(95, color="grey", lw=0.8, ls="--")
    axes[1].legend(loc="upper left", fontsize=8)
    fig.suptitle("explore: grasp success against what it costs")
    fig.tight_layout()
    paths[2].parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, paths[2], dpi=120)
    return paths
