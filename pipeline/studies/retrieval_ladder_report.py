"""The ladder's outputs: per-rung summary, the compact Markdown table, per-task text tables, CSV and PNG.

The rows come from :func:`pipeline.studies.retrieval_ladder.ladder_rows` (docs/retrieval.md, "Where grasps are lost").
"""
from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

import numpy as np

from pipeline.atomic import save_figure, together, write_text
from pipeline.studies.retrieval_ladder import PERTURBATIONS, RUNGS, LadderRow

__all__ = ["summarise", "summary_markdown", "ladder_tables", "write_outputs"]


def summarise(rows: Sequence[LadderRow]) -> list[dict]:
    """Per (scene, estimator, rung): runs, successes and the lost grasps by reason. The true-pose rungs, which no
    estimator touches, are listed under every estimator."""
    estimators = [e for e in dict.fromkeys(r.estimator for r in rows) if e] or [""]
    out = []
    for scene in dict.fromkeys(r.scene for r in rows):
        for est in estimators:
            for rung in RUNGS:
                sel = [r for r in rows if r.scene == scene and r.rung == rung and r.estimator in (est, "")]
                if not sel:
                    continue
                lost = {k: sum(r.reason == k for r in sel) for k in ("wrong_segment", "yaw", "position",
                                                                     "grasp_rule")}
                out.append(dict(scene=scene, estimator=est, rung=rung, runs=len(sel),
                                success=sum(r.success for r in sel), **{f"lost_{k}": v for k, v in lost.items()}))
    return out


#: Columns of the compact ladder table: (title, rungs pooled into it).
_COLUMNS = (("true pose", ("true_pose",)), ("yaw ±0.05", ("yaw+0.05", "yaw-0.05")),
            ("yaw ±0.10", ("yaw+0.10", "yaw-0.10")), ("yaw ±0.15", ("yaw+0.15", "yaw-0.15")),
            ("1 cm", tuple(p[0] for p in PERTURBATIONS if p[0].startswith(("pos+1", "pos-1")))),
            ("2 cm", tuple(p[0] for p in PERTURBATIONS if p[0].startswith(("pos+2", "pos-2")))),
            ("ideal, true segment", ("ideal_true_segment",)), ("ideal, our choice", ("ideal_our_choice",)),
            ("tracker, our choice", ("tracker_our_choice",)),
            ("ideal, true segment, held still", ("ideal_true_segment_static",)),
            ("ideal, true segment, translated", ("ideal_true_segment_translate",)),
            ("ideal, true segment, point pusher", ("ideal_true_segment_push",)),
            ("tracker, held still", ("tracker_our_choice_static",)),
            ("tracker, translated", ("tracker_our_choice_translate",)),
            ("tracker, point pusher", ("tracker_our_choice_push",)))


def summary_markdown(summary: Sequence[dict]) -> str:
    """One line per (task, estimator): grasps kept per rung (perturbations pooled over their directions: yaw ±, a
    shift's four directions) and why the tracker rung lost the others (wrong segment / yaw / position / rule)."""
    head = "| task | estimator | " + " | ".join(t for t, _ in _COLUMNS) + " | tracker lost: segment / yaw / " \
        "position / rule |\n|" + "---|" * (len(_COLUMNS) + 3) + "\n"
    body = ""
    for scene, est in dict.fromkeys((r["scene"], r["estimator"]) for r in summary):
        by = {r["rung"]: r for r in summary if (r["scene"], r["estimator"]) == (scene, est)}
        cells = []
        for _, rungs in _COLUMNS:
            got = [by[g] for g in rungs if g in by]
            cells.append(f"{sum(r['success'] for r in got)}/{sum(r['runs'] for r in got)}" if got else "-")
        t = by.get("tracker_our_choice")
        lost = "-" if t is None else " / ".join(str(t[f"lost_{k}"]) for k in ("wrong_segment", "yaw", "position",
                                                                             "grasp_rule"))
        body += f"| {scene} | {est} | " + " | ".join(cells) + f" | {lost} |\n"
    return head + body


def ladder_tables(summary: Sequence[dict]) -> str:
    """A table per (task, estimator) of :func:`summarise`'s rows: one line per rung, grasps kept / runs and the
    lost ones by reason."""
    reasons = ("wrong_segment", "yaw", "position", "grasp_rule")
    text = ""
    for scene, est in dict.fromkeys((r["scene"], r["estimator"]) for r in summary):
        text += f"\n{scene}, {est or 'no'} estimator\n{'rung':<20} {'GS':>7}   " + " ".join(
            f"{k:>13}" for k in reasons) + "\n"
        for r in summary:
            if (r["scene"], r["estimator"]) == (scene, est):
                text += f"{r['rung']:<20} {r['success']:>3}/{r['runs']:<3}   " + " ".join(
                    f"{r['lost_' + k]:>13}" for k in reasons) + "\n"
    return text


def _csv(rows: Sequence[dict]) -> str:
    buf = io.StringIO()
    if rows:
        w = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    return buf.getvalue()


@together()  # its outputs appear all together or not at all
def write_outputs(rows: Sequence[LadderRow], out: str | Path) -> tuple[Path, Path, Path]:
    """``ladder.csv`` (one row per grasp), ``ladder_summary.csv`` and ``ladder.png`` (per task, GS % per rung and
    estimator) into ``out``, each written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    summary = summarise(rows)
    paths = (out / "ladder.csv", out / "ladder_summary.csv", out / "ladder.png")
    write_text(paths[0], _csv([asdict(r) for r in rows]))
    write_text(paths[1], _csv(summary))
    scenes = list(dict.fromkeys(r["scene"] for r in summary))
    estimators = list(dict.fromkeys(r["estimator"] for r in summary))
    fig, axes = plt.subplots(len(scenes), 1, figsize=(12, 2.6 * len(scenes)), squeeze=False)
    width = 0.8 / max(1, len(estimators))
    for ax, scene in zip(axes[:, 0], scenes):
        for k, est in enumerate(estimators):
            sel = {r["rung"]: r for r in summary if r["scene"] == scene and r["estimator"] == est}
            x = np.arange(len(RUNGS)) + (k - (len(estimators) - 1) / 2) * width
            gs = [100.0 * sel[g]["success"] / sel[g]["runs"] if g in sel else np.nan for g in RUNGS]
            ax.bar(x, np.nan_to_num(gs), width, label=f"{est} estimator" if est else "true pose")
        ax.set_xticks(np.arange(len(RUNGS)), RUNGS, rotation=30, ha="right", fontsize=7)
        ax.set_ylim(0, 105)
        ax.set_ylabel(f"{scene}: GS %")
        ax.axhline(85, color="0.5", lw=0.6, ls="--")
    axes[0, 0].legend(fontsize=7, loc="lower left")
    axes[0, 0].set_title("Where grasps are lost: grasp success per rung (dashed: 85 %)", fontsize=9)
    fig.tight_layout()
    save_figure(fig, paths[2], dpi=90)
    return paths
