"""What accuracy costs in time, summarised: Pareto fronts of time against each metric, the knee, table and figure.

Input is the per-run table of :func:`pipeline.studies.accuracy_bench`; docs/studies.md, ``stucco bench accuracy``.
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from pipeline.atomic import save_figure
from pipeline.studies.tables import mean_of, median_of

__all__ = ["pareto_front", "knee", "summarise_settings", "summary_markdown", "pareto_figure"]


def pareto_front(points: np.ndarray, minimize: Sequence[bool] | None = None) -> np.ndarray:
    """Non-dominated rows of ``points``.

    Parameters
    ----------
    points : ndarray, shape (n, k)
        One row per candidate; NaN rows are never on the front.
    minimize : sequence of bool, length k
        Per column, True to minimise (default), False to maximise.

    Returns
    -------
    ndarray of bool, shape (n,)
        True for rows that no other row dominates (at least as good in every column, better in one).
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2:
        raise ValueError(f"points must be (n, k), got shape {p.shape}")
    sign = np.array([1.0 if m else -1.0 for m in (minimize or [True] * p.shape[1])])
    q = p * sign
    ok = np.all(np.isfinite(q), axis=1)
    front = ok.copy()
    for i in np.flatnonzero(ok):
        others = q[ok]
        dominated = np.any(np.all(others <= q[i], axis=1) & np.any(others < q[i], axis=1))
        front[i] = not dominated
    return front


def knee(cost: Sequence[float], error: Sequence[float], tolerance: float = 0.1) -> int:
    """Index of the knee: the cheapest candidate whose error is within ``tolerance`` (relative) of the best.

    Beyond the knee, spending more time buys less than ``tolerance`` of the best error. NaN errors never qualify.
    """
    c = np.asarray(cost, dtype=np.float64)
    e = np.asarray(error, dtype=np.float64)
    ok = np.isfinite(e) & np.isfinite(c)
    if not ok.any():
        raise ValueError("no candidate with a finite cost and error")
    best = np.min(e[ok])
    good = ok & (e <= best + tolerance * abs(best) + 1e-12)
    idx = np.flatnonzero(good)
    return int(idx[np.argmin(c[idx])])


def summarise_settings(table: pa.Table) -> list[dict[str, Any]]:
    """Per setting: runs (distinct scene and seed), median time per run, median CE and FMI, grasp success rate
    (the mean over every row: over the estimator streams too, when there are several); plus Pareto flags (time
    against CE, against FMI, against GS) and the knee of the particle sweep (:func:`knee` on time vs CE)."""
    rows: list[dict[str, Any]] = []
    data = table.to_pylist()
    for name in dict.fromkeys(r["setting"] for r in data):
        sub = [r for r in data if r["setting"] == name]
        rows.append(dict(setting=name, method=sub[0]["method"], runs=len({(r["scene"], r["seed"]) for r in sub}),
                         compute_s=median_of([r["compute_s"] for r in sub]),
                         track_s=median_of([r["track_s"] for r in sub]), icp_s=median_of([r["icp_s"] for r in sub]),
                         ce_cm=median_of([r["contact_error_cm"] for r in sub]),
                         fmi=median_of([r["fmi"] for r in sub]),
                         gs=mean_of([None if r["grasp_success"] is None else float(r["grasp_success"])
                                     for r in sub])))
    t = np.array([r["compute_s"] for r in rows])
    for key, metric, minimize in (("front_ce", "ce_cm", True), ("front_fmi", "fmi", False),
                                  ("front_gs", "gs", False)):
        mask = pareto_front(np.column_stack([t, [r[metric] for r in rows]]), [True, minimize])
        for r, m in zip(rows, mask):
            r[key] = bool(m)
    # The knee is taken along the particle sweep: N is the knob that trades tracking time for tracking accuracy
    # (restarts and SDF resolution leave the tracked points of N = 100 unchanged or nearly so).
    knob = {r["setting"]: r["knob"] for r in data}
    st = [i for i, r in enumerate(rows) if knob[r["setting"]] == "n_particles"] or \
        [i for i, r in enumerate(rows) if r["method"] == "stucco"]
    if st:
        k = st[knee([rows[i]["compute_s"] for i in st], [rows[i]["ce_cm"] for i in st])]
        for i, r in enumerate(rows):
            r["knee"] = i == k
    return rows


def summary_markdown(rows: list[dict[str, Any]]) -> str:
    """:func:`summarise_settings` as a Markdown table (times in s, CE in cm; front flags CE/FMI/GS, x = on it)."""
    head = "| setting | runs | time/run s | track s | pose s | CE cm | FMI | GS | front (CE/FMI/GS) |\n"
    head += "|---|---|---|---|---|---|---|---|---|\n"
    body = ""
    for r in rows:
        flags = "/".join("x" if r[k] else "-" for k in ("front_ce", "front_fmi", "front_gs"))
        body += (f"| {r['setting']}{' (knee)' if r.get('knee') else ''} | {r['runs']} | {r['compute_s']:.3f} | "
                 f"{r['track_s']:.3f} | {r['icp_s']:.3f} | {r['ce_cm']:.2f} | {r['fmi']:.3f} | {r['gs']:.2f} | "
                 f"{flags} |\n")
    return head + body


def pareto_figure(rows: list[dict[str, Any]], path: str | Path) -> Path:
    """Three panels (CE, FMI, GS against median time per run), Pareto fronts drawn, the knee ringed."""
    # matplotlib (about a second) is imported when the figure is drawn, not with the study.
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    t = np.array([r["compute_s"] for r in rows])
    for ax, (metric, label, front) in zip(axes, (("ce_cm", "median contact error (cm)", "front_ce"),
                                                 ("fmi", "median FMI", "front_fmi"),
                                                 ("gs", "grasp success rate", "front_gs"))):
        y = np.array([r[metric] for r in rows], dtype=float)
        m = np.array([r[front] for r in rows])
        labels: dict[tuple[float, float], list[str]] = {}
        for r, xi, yi, on_front in zip(rows, t, y, m):
            c = "C0" if r["method"] == "stucco" else "C1"
            ax.scatter(xi, yi, color=c, s=30, zorder=3)
            if r.get("knee"):
                ax.scatter(xi, yi, s=160, facecolors="none", edgecolors="red", zorder=4)
            # Only the front, the knee and the baselines are named (the rest are in the table); points that
            # coincide on the plot share one label instead of printing over each other.
            if on_front or r.get("knee") or r["method"] != "stucco":
                key = (round(float(np.log10(max(xi, 1e-9))), 2), round(float(yi), 3))
                labels.setdefault(key, []).append(r["setting"].replace("stucco ", ""))
        for (lx, ly), names in labels.items():
            ax.annotate(", ".join(names), (10 ** lx, ly), fontsize=7, xytext=(4, 4), textcoords="offset points")
        o = np.argsort(t[m])
        ax.step(t[m][o], y[m][o], where="post", color="grey", lw=1, zorder=2)
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel("median time per run (s): track + segment + pose estimation")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    fig.suptitle("blue: STUCCO settings (named on the front), orange: baselines; grey: Pareto front; red ring: knee",
                 fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)
