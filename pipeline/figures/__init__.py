"""Figures of an evaluation: one Fig.-4-like picture per run and a summary of Table II.

* :func:`run_figure`: one panel per method for a (scene, seed) — walls and objects outlined at their poses after
  the last action (the target drawn thicker and shaded), the gripper's trail (the active protocol's probes in
  amber), the final tracked contact points coloured by segment (the segment chosen as the target ringed in
  black), the estimated target outline (dashed red) and the grasp attempted at it (an arrow, green if it held);
  the title gives grasp success, FMI, CE and the position error.
* :func:`summary_figure`: GS %, FMI and CE per scene and method as bars, the paper's Table II values as black
  markers.
* :func:`plot_table` (``stucco plot``) and :func:`segments_with_plot` (``stucco segment --plot``): one run of any
  stage's table over its scene (:mod:`pipeline.figures.tables`).

Drawing blocks are in :mod:`pipeline.figures.draw`. Files are written to a temporary name and renamed
(matplotlib's Agg backend, no display needed).
"""
from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pipeline import schema
from pipeline.atomic import save_figure
from pipeline.figures.draw import (
    draw_estimate,
    draw_grasp,
    draw_points,
    draw_scene,
    draw_trail,
    outline,
    pyplot,
    scene_shapes,
    window,
    wrap,
)
from pipeline.figures.tables import PLOTTABLE, plot_table, probe_actions, segments_with_plot
from pipeline.layout import partition
from pipeline.registry import method_title, tracker_names
from pipeline.retrieve import DEFAULT_ESTIMATOR, load_run, read_retrieval
from pipeline.score import read_scores
from pipeline.segment import final_estimates

__all__ = ["figure_path", "outline", "run_figure", "figure_methods", "drawn", "DRAWN_KEY", "summary_figure",
           "plot_table", "segments_with_plot", "PLOTTABLE"]


def figure_path(out: str | Path, scene: str, seed: int) -> Path:
    """``out/figures/<scene>-<seed:03d>.png``."""
    return Path(out) / "figures" / f"{scene}-{int(seed):03d}.png"


def _save(fig, path: Path, metadata: dict[str, str] | None = None) -> None:
    save_figure(fig, path, dpi=100, metadata=metadata)


#: The PNG text chunk in which a run figure records what it drew (:func:`drawn`).
DRAWN_KEY = "stucco.figure"


def figure_methods(out: str | Path, scene: str, seed: int, methods: Sequence[str], estimator: str) -> list[str]:
    """The methods :func:`run_figure` draws a panel for: those of ``methods`` with a scores file of ``estimator``
    (the first method when none has)."""
    return [m for m in methods if partition(out, "scores", scene, seed, m, estimator).is_file()] or list(methods)[:1]


def drawn(png: str | Path) -> dict | None:
    """What a run figure recorded it drew (``{"methods": [...], "estimator": ...}``, its PNG text chunk
    :data:`DRAWN_KEY`), or None (no such chunk, or not a PNG): the evaluation redraws a figure whose panels differ
    from those it would draw now."""
    try:
        data = Path(png).read_bytes()
    except OSError:
        return None
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        return None
    at = 8
    while at + 8 <= len(data):
        size, kind = int.from_bytes(data[at:at + 4], "big"), data[at + 4:at + 8]
        body = data[at + 8:at + 8 + size]
        if kind == b"tEXt" and body.startswith(DRAWN_KEY.encode() + b"\0"):
            try:
                return json.loads(body[len(DRAWN_KEY) + 1:].decode("latin-1"))
            except ValueError:
                return None
        if kind == b"IEND":
            break
        at += 12 + size
    return None


def run_figure(out: str | Path, scene: str, seed: int, methods: Sequence[str], estimator: str | None = None,
               path: str | Path | None = None) -> Path:
    """Draw the run (scene, seed) of an evaluation directory, one panel per method with a scores file, with the
    estimate of ``estimator`` (default: :data:`pipeline.retrieve.DEFAULT_ESTIMATOR`) and the grasp made at it.

    Returns the PNG path (:func:`figure_path` unless ``path`` is given).
    """
    estimator = estimator or DEFAULT_ESTIMATOR
    plt = pyplot()
    out = Path(out)
    path = Path(path) if path is not None else figure_path(out, scene, seed)
    run_path = partition(out, "runs", scene, seed)
    info = load_run(run_path)
    probe = probe_actions(run_path, len(info.ee) - 1)
    shapes = scene_shapes(info)
    lo, hi = window(shapes, info.ee)  # zoom on the objects and the trail; walls drawn where they enter it
    methods = figure_methods(out, scene, seed, methods, estimator)
    width = max(3.6 * len(methods), 5.2)  # one panel: wide enough for its title and the figure's
    fig, axes = plt.subplots(1, len(methods), figsize=(width, 4.4), squeeze=False)
    for ax, m in zip(axes[0], methods):
        draw_scene(ax, shapes)
        draw_trail(ax, info.ee, probe, label=False)
        title = method_title(m)
        seg_path = partition(out, "segments", scene, seed, m)
        ret_path = partition(out, "retrieval", scene, seed, m, estimator)
        chosen = None
        if ret_path.is_file():
            r = read_retrieval(ret_path).to_pylist()[0]
            chosen = r["segment"]
            if r["segment"] >= 0:
                pose = np.array([r["x_m"], r["y_m"], r["yaw_rad"]])
                draw_estimate(ax, info.target, pose)
                draw_grasp(ax, info.scene, info.target, pose, r["grasp_success"])
        if seg_path.is_file():
            final = final_estimates(schema.read_segments(seg_path))
            if final.num_rows:
                xy = np.column_stack([final.column("x_m").to_numpy(), final.column("y_m").to_numpy()])
                draw_points(ax, xy, final.column("segment").to_numpy(), "segment", ringed=chosen)
        sc_path = partition(out, "scores", scene, seed, m, estimator)
        if sc_path.is_file():
            s = read_scores(sc_path).to_pylist()[0]
            gs = {True: "GS yes", False: "GS no", None: "GS -"}[s["grasp_success"]]
            fmi = "-" if s["fmi"] is None else f"{s['fmi']:.2f}"
            ce = "-" if s["contact_error_cm"] is None else f"{s['contact_error_cm']:.2f}"
            title += f"\n{gs}, FMI {fmi}, CE {ce} cm, pos. err. {s['position_error_cm']:.1f} cm"
        ax.set_title(wrap(title, width / len(methods), 8), fontsize=8)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
        ax.tick_params(labelsize=6)
    probes = " and probes (amber)" if probe.any() else ""
    head = (f"{scene} seed {seed}: objects after the last action (target shaded), gripper trail (grey){probes}, "
            f"tracked points by segment (chosen ringed), {estimator} estimate (red dashed), grasp at it (arrow: "
            f"green held, red failed)")
    fig.suptitle(wrap(head, width, 8), fontsize=8)
    fig.tight_layout()
    _save(fig, path, {DRAWN_KEY: json.dumps({"methods": methods, "estimator": estimator})})
    return path


def summary_figure(rows, path: str | Path) -> Path:
    """GS %, FMI and CE cm per scene and method (bars, std as error bars) with the paper's values (black)."""
    plt = pyplot()
    path = Path(path)
    scenes = list(dict.fromkeys(r.scene for r in rows))
    methods = [m for m in tracker_names() if any(r.method == m for r in rows)]
    methods += sorted({r.method for r in rows} - set(methods))
    by: dict = {}
    for r in rows:
        by.setdefault((r.scene, r.method), r)  # the first pose estimator's grasp success (report order)
    panels = (("grasp success %", "grasp_success_pct", None, "paper_gs_pct", None),
              ("FMI", "fmi_mean", "fmi_std", "paper_fmi_mean", "paper_fmi_std"),
              ("contact error cm", "ce_cm_mean", "ce_cm_std", "paper_ce_cm_mean", "paper_ce_cm_std"))
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    width = 0.8 / max(1, len(methods))
    cmap = plt.get_cmap("tab10")
    x0 = np.arange(len(scenes))
    for ax, (label, mean, std, pmean, pstd) in zip(axes, panels):
        for k, m in enumerate(methods):
            xs = x0 + (k - (len(methods) - 1) / 2) * width
            vals = [getattr(by[(s, m)], mean) if (s, m) in by else np.nan for s in scenes]
            err = None
            if std:
                err = np.nan_to_num([getattr(by[(s, m)], std) if (s, m) in by else 0.0 for s in scenes])
            ax.bar(xs, np.nan_to_num(vals), width, yerr=err, color=cmap(k % 10), label=method_title(m),
                   error_kw={"lw": 0.6, "ecolor": "0.3"}, capsize=1.5)
            pv = [getattr(by[(s, m)], pmean) if (s, m) in by else None for s in scenes]
            pv = np.array([np.nan if v is None else v for v in pv], dtype=float)
            ax.plot(xs, pv, "k_", ms=8, mew=2)
        ax.set_xticks(x0, scenes)
        ax.set_title(label + " (black: paper)", fontsize=9)
    axes[0].set_ylim(0, 100)
    axes[1].set_ylim(0, 1.05)
    axes[0].legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    _save(fig, path)
    return path
