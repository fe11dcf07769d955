"""``stucco bench probe``: grasp success of the active protocol against the probe budget (docs/active.md).

Each (scene, seed) is collected once with the policy's largest budget (or read from ``--runs``). The policy's
decisions do not depend on its budget until the budget stops it, so the run with budget b is the first b probes
of that run: its set is recomputed from the decision the policy would have stopped at (:func:`stop_decision`)
and the grasp is simulated in the state after those probes, the gripper back at the end of the scripted part
(where the policy returns it through visited space; the return itself is not simulated for a cut run).
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
from pipeline.evaluate.freshness import check_run_settings
from pipeline.parallel import run_calls
from pipeline.probe.grasp_attempts import attempt_grasps
from pipeline.probe.policy import ProbeParams, required_contacts
from pipeline.probe.report import run_stats
from pipeline.probe.retrieval import active_state
from pipeline.scenes import load_scene
from pipeline.seeds import check_root_seed

__all__ = ["BUDGETS", "stop_decision", "decision_at", "budget_rows", "summarise", "write_outputs"]

BUDGETS = (0, 1, 2, 4, 8, 12)
FIELDS = ("scene", "seed", "budget", "probes", "success", "success_any", "attempts", "outcome", "position_error_m",
          "yaw_error_rad",
          "decision_s_median", "decision_s_max", "prior_s", "moved_m", "turned_rad", "wide")


def stop_decision(history: list[dict], budget: int, need: int, agree: float) -> int:
    """The decision (= probes made) at which the policy with ``budget`` stops: the first the policy marked
    ``stop`` (its set agrees, or one grasp holds it, on enough target contacts that span the box), else the
    budget (capped at the decisions recorded). Run files written before ``stop`` was recorded: the first decision
    whose set agrees (``share`` >= ``agree``) with at least min(``need``, budget) target contacts."""
    for k, h in enumerate(history[:budget + 1]):
        if h["stop"] if "stop" in h else h["share"] >= agree and len(h["target_steps"]) >= min(need, budget):
            return k
    return min(budget, len(history) - 1)


def decision_at(history: list[dict], budget: int, collected: int, need: int, agree: float) -> int:
    """The decision whose set a policy with ``budget`` grasps, in a run collected with budget ``collected``: the
    run's last one for its own budget or more (the probes of a segment taken at its end included), else
    :func:`stop_decision`."""
    return len(history) - 1 if budget >= collected else stop_decision(history, budget, need, agree)


def _at_decision(info, path: Path, scene, history: list[dict], k: int, last: bool, rows: int | None,
                 root_seed: int, params: ProbeParams, budget_end: bool) -> tuple:
    """(the planned grasp's attempts, position error, yaw error) of the set the policy holds at decision ``k``
    (with ``budget_end``, the set a policy whose budget ends there grasps), attempted as the active protocol ends
    its runs (:func:`pipeline.probe.grasp_attempts.attempt_grasps`), in the state after those probes."""
    belief, _, around, next_set = active_state(info, root_seed, params.method, None if last else k,
                                               params if budget_end else None)
    t = schema.read_run(path)
    poses = info.final_poses if last else np.asarray(t.column("obj_pose")[rows - 1].as_py()).reshape(-1, 3)
    n0 = int(history[0]["rows"])
    ee = info.final_ee if last else info.ee[n0]
    # a cut run's gripper stands back at the end of the scripted part (the return is simulated for the uncut run)
    res = attempt_grasps(scene, poses, ee, info.target, belief.poses, belief.weights, belief.best,
                         around if last else around.moved(ee), next_set=next_set,
                         tilted=info.final_tilted if last else None)
    pose = info.target.canonical(belief.poses[belief.best])
    pe, ye = pose_error(info.target, pose, poses[info.target_id])
    return res, pe, ye


def _one(scene_name: str, seed: int, runs: Path, budgets: tuple[int, ...], root_seed: int,
         params: ProbeParams) -> list[dict]:
    scene = load_scene(scene_name)
    path = output_path(runs, scene.name, seed)
    if not path.is_file():
        collect_file(scene, seed, path, root_seed=root_seed, policy="scripted+probe", policy_params=params)
    info = load_run(path)
    meta = schema.probe_record(path)  # checked against the run's rows: a history of one entry per decision
    if not meta:
        policy = (schema.read_metadata(path).get("params") or {}).get("policy")
        raise ValueError(f"{path}: a run of policy {policy!r}, not of scripted+probe; bench probe reads the "
                         "probing policy's runs (another --runs directory)")
    check_root_seed(path, schema.read_metadata(path), root_seed,
                    "; run `stucco --seed {seed} bench probe` or use another --runs directory")
    # the scene, its effects, the whole run and the policy's parameters this bench would collect it with (the
    # budget aside: a run stands for the smaller budgets, checked below)
    check_run_settings(path, scene, "scripted+probe", None, params, ignore=("budget",))
    collected = int(meta["params"].get("budget", params.budget))
    history = meta["history"]
    need = required_contacts(info.target, params)
    if max(budgets) > collected and meta.get("flagged") == "budget_spent":
        # the run stands for a larger budget only where its policy stopped by itself before its own budget
        raise ValueError(f"{path}: collected with a probe budget of {collected}, spent before the policy stopped; "
                         f"a budget of {max(budgets)} needs runs collected with it (another --runs directory)")
    out = []
    stopped: dict[tuple, tuple] = {}  # (decision, budget end) -> grasp outcome and errors, shared by budgets
    for b in budgets:
        k = decision_at(history, b, collected, need, params.plan.agree_share)
        last = k == len(history) - 1
        rows = None if last else int(history[k]["rows"])
        # A policy still going at its budget's end may give the segment up there (the run's last decision
        # already records it).
        end = k == b and not last
        if (k, end) not in stopped:
            stopped[(k, end)] = _at_decision(info, path, scene, history, k, last, rows, root_seed, params, end)
        res, pe, ye = stopped[(k, end)]
        st = run_stats(path, rows)
        dec = np.asarray(st["decision_s"][:k + 1])
        out.append(dict(scene=scene.name, seed=seed, budget=b, probes=k, success=res.first_success,
                        success_any=res.success, attempts=len(res.attempts),
                        outcome=res.outcome, position_error_m=pe, yaw_error_rad=ye,
                        decision_s_median=float(np.median(dec)) if dec.size else None,
                        decision_s_max=float(np.max(dec)) if dec.size else None, prior_s=st["prior_s"],
                        moved_m=st["moved_m"],
                        turned_rad=st["turned_rad"],
                        wide=max(history[k]["share"], history[k].get("held", 0.0)) < params.plan.agree_share))
    return out


def budget_rows(pairs: list[tuple[str, int]], runs: str | Path, budgets: tuple[int, ...] = BUDGETS,
                root_seed: int = 0, jobs: int = 1, progress: Callable | None = None,
                params: ProbeParams = ProbeParams()) -> list[dict]:
    """Rows (one per scene, seed, budget; :data:`FIELDS`) for (scene, seed) pairs; runs collected into ``runs``
    with the largest budget when missing (the policy's ``params`` otherwise)."""
    runs = Path(runs)
    runs.mkdir(parents=True, exist_ok=True)
    params = dataclasses.replace(params, budget=max(budgets))
    results = run_calls(_one, [(sc, s, runs, tuple(budgets), root_seed, params) for sc, s in pairs], jobs)
    if progress is not None:
        results = progress(results, total=len(pairs))
    return [r for rows in results for r in rows]


def summarise(rows: list[dict]) -> list[dict]:
    """Per scene and budget: runs, GS %, mean probes, decision time (median of the runs' medians, largest), the
    pushes' prior's time per run (median), median
    displacement of the target by the probes (mm, rad), runs whose set was still wide."""
    out = []
    for sc in dict.fromkeys(r["scene"] for r in rows):
        for b in sorted({r["budget"] for r in rows if r["scene"] == sc}):
            sel = [r for r in rows if r["scene"] == sc and r["budget"] == b]
            med = [r["decision_s_median"] for r in sel if r["decision_s_median"] is not None]
            mx = [r["decision_s_max"] for r in sel if r["decision_s_max"] is not None]
            prior = [r["prior_s"] for r in sel if r.get("prior_s")]
            out.append(dict(scene=sc, budget=b, runs=len(sel), gs_pct=100.0 * np.mean([r["success"] for r in sel]),
                            gs_any_pct=100.0 * np.mean([r["success_any"] for r in sel]),
                            probes_mean=float(np.mean([r["probes"] for r in sel])),
                            decision_s_median=float(np.median(med)) if med else float("nan"),
                            decision_s_max=float(np.max(mx)) if mx else float("nan"),
                            prior_s_median=float(np.median(prior)) if prior else float("nan"),
                            moved_mm_median=1000.0 * float(np.median([r["moved_m"] for r in sel])),
                            turned_rad_median=float(np.median([r["turned_rad"] for r in sel])),
                            wide=int(sum(r["wide"] for r in sel))))
    return out


@together()  # its outputs appear all together or not at all
def write_outputs(rows: list[dict], summary: list[dict], out: str | Path, png: str | Path | None = None
                  ) -> list[Path]:
    """``probe_budget.csv`` (rows), ``probe_budget_summary.csv`` and the PNG (GS % against the budget per task,
    ``png`` or ``out/probe_budget.png``), each written atomically."""
    import matplotlib  # imported here: only this output draws

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "probe_budget.csv", out / "probe_budget_summary.csv", Path(png or out / "probe_budget.png")]
    for path, data in ((paths[0], rows), (paths[1], summary)):
        write_csv_rows(path, data, list(data[0]) if data else list(FIELDS))
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    for sc in dict.fromkeys(s["scene"] for s in summary):
        sel = [s for s in summary if s["scene"] == sc]
        ax.plot([s["budget"] for s in sel], [s["gs_pct"] for s in sel], marker="o", label=sc)
    ax.set_xlabel("probe budget")
    ax.set_ylabel("grasp success (%)")
    ax.set_ylim(0, 102)
    ax.axhline(95, color="grey", lw=0.8, ls="--")
    ax.legend(loc="lower right")
    ax.set_title("Active retrieval: grasp success against probe budget")
    fig.tight_layout()
    paths[2].parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, paths[2], dpi=120)
    return paths
