"""``stucco study training``: the paper's Fig. 5, median FMI against median contact error on the training set.

docs/studies.md, ``stucco study training (Fig. 5)``.
"""
from __future__ import annotations

import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa

from pipeline.atomic import save_figure
from pipeline.registry import tracker_names
from pipeline.studies.tables import percentile_of, write_csv
from pipeline.studies.training import TRAINING_SCENES, TRAINING_SEEDS, load_training, score_methods

__all__ = ["training_study", "fig5"]


def training_study(out: str | Path, scenes: Sequence[str] = TRAINING_SCENES, seeds: Sequence[int] = TRAINING_SEEDS,
                   methods: Sequence[str] | None = None, *,
                   root_seed: int = 0, jobs: int = 1, progress: bool | None = None,
                   max_actions: int | None = None, min_ambiguity: float = 0.3) -> dict[str, Any]:
    """Collect (greedy walk, discard rule), isolate, track with every method at its defaults, score.

    Writes ``out/training.csv`` (one row per (run, method)) and ``out/fig5.png``; returns counts, the per-method
    summary (all runs and runs with ambiguity >= ``min_ambiguity``) and the wall time.
    """
    t0 = time.perf_counter()
    out = Path(out)
    methods = tuple(methods) if methods is not None else tracker_names()
    info, contacts, truths = load_training(out, scenes, seeds, root_seed, jobs, progress, max_actions)
    rows = score_methods(contacts, truths, [(m, {}) for m in methods], root_seed, jobs, progress)
    table = pa.Table.from_pylist(rows)
    write_csv(table, out / "training.csv")
    summ = {"all": _fig5_stats(rows, methods, 0.0), "ambiguous": _fig5_stats(rows, methods, min_ambiguity)}
    fig5(summ, out / "fig5.png", min_ambiguity)
    discarded = [r for r in info if r["discarded"] is not None]
    n_amb = sum(1 for t in truths.values() if t["ambiguity"] >= min_ambiguity)
    return dict(collected=len(info), kept=len(info) - len(discarded), ambiguous=n_amb,
                discarded_by_reason={k: sum(1 for r in discarded if r["discarded"] == k)
                                     for k in sorted({r["discarded"] for r in discarded})},
                per_scene_kept={sc: sum(1 for r in info if r["scene"] == sc and r["discarded"] is None)
                                for sc in dict.fromkeys(r["scene"] for r in info)},
                summary=summ, wall_s=time.perf_counter() - t0)


def _fig5_stats(rows: list[dict], methods: Sequence[str], min_ambiguity: float) -> dict[str, dict]:
    """Per method, over runs with ambiguity >= ``min_ambiguity``: runs, and the 50th (20th, 80th) percentiles
    of FMI and CE (cm)."""
    out = {}
    for m in methods:
        sub = [r for r in rows if r["method"] == m and r["ambiguity"] >= min_ambiguity]
        f = [r["fmi"] for r in sub]
        c = [r["contact_error_cm"] for r in sub]
        out[m] = dict(runs=len(sub), fmi=percentile_of(f, 50), fmi_lo=percentile_of(f, 20),
                      fmi_hi=percentile_of(f, 80), ce_cm=percentile_of(c, 50), ce_lo=percentile_of(c, 20),
                      ce_hi=percentile_of(c, 80))
    return out


def fig5(summary: dict[str, dict[str, dict]], path: str | Path, min_ambiguity: float = 0.3) -> Path:
    """The paper's Fig. 5: median FMI against median CE, 20th-80th percentile bars; top all runs, bottom runs
    with ambiguity >= ``min_ambiguity``."""
    # matplotlib (about a second) is imported when the figure is drawn, not with the study.
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(6, 8))
    panels = (("all", "all runs"), ("ambiguous", f"runs with ambiguity >= {min_ambiguity:g}"))
    for ax, (key, title) in zip(axes, panels):
        for i, (m, s) in enumerate(summary[key].items()):
            if not s["runs"] or not math.isfinite(s["ce_cm"]):
                continue
            ax.errorbar(s["ce_cm"], s["fmi"], xerr=[[s["ce_cm"] - s["ce_lo"]], [s["ce_hi"] - s["ce_cm"]]],
                        yerr=[[s["fmi"] - s["fmi_lo"]], [s["fmi_hi"] - s["fmi"]]], fmt="o", capsize=3,
                        color=f"C{i}", label=f"{m} ({s['runs']} runs)")
        ax.set_xlabel("contact error (cm)")
        ax.set_ylabel("FMI")
        ax.set_title(f"training set, {title}")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)
