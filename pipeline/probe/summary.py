"""The active protocol's summary table for an evaluation: grasp success at the first attempt and within the
planned grasp's attempts, attempts, probes and actions per run, decision time and how far the target was pushed,
per paper task and, for other scenes (generated ones), per target shape (docs/active.md, "The planned grasp").

Ground truth (the recorded poses) is read for reporting only.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline import schema
from pipeline.estimators.run_info import load_run
from pipeline.layout import partition
from pipeline.probe.report import run_stats
from pipeline.report import PAPER_TABLE_II
from pipeline.scenes.files import scene_digest, shipped_digest

__all__ = ["active_rows", "active_markdown", "group_of"]

#: The paper's tasks (Table II's rows, the real row's stand-in included), reported one row each; every other scene is
#: grouped by its target's shape.
PAPER_TASKS = tuple(PAPER_TABLE_II)


def group_of(scene: str, shape: str, source: str | None = None) -> str:
    """The row a run of ``scene`` is reported in: a paper task by name, when its scene file's text ``source`` is the
    shipped one (or is not known), any other scene (an edited copy under a task's name too) by its target's
    ``shape`` ("box" or "cylinder", reported as a box or a can target)."""
    shipped = source is None or scene_digest(source) == shipped_digest(scene)
    return scene if scene in PAPER_TASKS and shipped else \
        f"other scenes, {'can' if shape == 'cylinder' else 'box'} target"


def _run_facts(run_path: Path) -> tuple[str, int, float, str]:
    """(the target's shape, "box" or "cylinder"; the run's actions; how far the target's centre moved from after the
    first action to the end of the run, m; the text of the scene file it was collected from) of a run file."""
    info = load_run(run_path)  # the scene recorded in the run file, its target, the final poses
    first = np.asarray(schema.read_run(run_path).column("obj_pose")[0].as_py(), dtype=np.float64).reshape(-1, 3)
    moved = math.hypot(*(info.true_pose[:2] - first[info.target_id, :2]))
    return info.target.kind, len(info.steps), moved, info.scene.source


def active_rows(out: str | Path, scores: pa.Table, method: str | None = None) -> list[dict]:
    """One dict per group (paper task, or other scenes by target shape) of an evaluation made with ``--policy
    scripted+probe``: ``group``, ``runs``, ``gs_first_pct``, ``gs_any_pct``, ``attempts``, ``probes``,
    ``actions`` (median), ``decision_s`` (median), ``decision_max_s``, ``pushed_cm`` (median).
    ``scores`` is the evaluation's scores table; the first estimator of each run is read (the active protocol's
    grasp is the same for every estimator). ``method`` None: the first method of the scores. Empty when no run of
    ``method`` was probed."""
    every = scores.to_pylist()
    method = method if method is not None else next(iter(r["method"] for r in every), None)  # the first method's
    rows = [r for r in every if r["method"] == method]
    first: dict[tuple[str, int], dict] = {}
    for r in rows:
        first.setdefault((r["scene"], r["seed"]), r)
    groups: dict[str, list[tuple[dict, dict, int, float]]] = {}
    for (scene, seed), r in first.items():
        path = partition(out, "runs", scene, seed)
        if r.get("grasp_attempts") is None or not path.is_file():
            continue
        shape, actions, pushed, source = _run_facts(path)
        groups.setdefault(group_of(scene, shape, source), []).append((r, run_stats(path), actions, pushed))
    out_rows = []
    order = {name: i for i, name in enumerate(PAPER_TASKS)}
    for name in sorted(groups, key=lambda g: (order.get(g, len(order)), g)):
        items = groups[name]
        dec = np.concatenate([np.asarray(s["decision_s"], dtype=np.float64) for _, s, _, _ in items])
        out_rows.append(dict(
            group=name, runs=len(items),
            gs_first_pct=100.0 * np.mean([bool(r["grasp_success"]) for r, _, _, _ in items]),
            gs_any_pct=100.0 * np.mean([bool(r["grasp_success_any"]) for r, _, _, _ in items]),
            attempts=float(np.mean([r["grasp_attempts"] for r, _, _, _ in items])),
            probes=float(np.mean([s["probes"] for _, s, _, _ in items])),
            actions=float(np.median([a for _, _, a, _ in items])),
            decision_s=float(np.median(dec)) if dec.size else math.nan,
            decision_max_s=float(np.max(dec)) if dec.size else math.nan,
            pushed_cm=100.0 * float(np.median([p for _, _, _, p in items]))))
    return out_rows


def active_markdown(rows: list[dict]) -> str:
    """The rows of :func:`active_rows` as a Markdown table ("" without rows)."""
    if not rows:
        return ""
    head = ("| active protocol | runs | GS % first attempt | GS % within the attempts | attempts per run | "
            "probes per run | actions per run (median) | decision s median (max) | target pushed cm (median) |\n"
            "|---|---|---|---|---|---|---|---|---|\n")
    return head + "".join(
        f"| {r['group']} | {r['runs']} | {r['gs_first_pct']:.0f} | {r['gs_any_pct']:.0f} | {r['attempts']:.2f} | "
        f"{r['probes']:.2f} | {r['actions']:.0f} | {r['decision_s']:.3f} ({r['decision_max_s']:.3f}) | "
        f"{r['pushed_cm']:.1f} |\n" for r in rows)
