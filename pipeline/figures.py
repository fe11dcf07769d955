"""Figures of an evaluation: one Fig.-4-like picture per run and a summary of Table II.

* :func:`run_figure`: one panel per method for a (scene, seed) — walls and objects outlined at their poses after
  the last action (the target drawn thicker and shaded), the gripper's trail, the final tracked contact points
  coloured by segment (the segment chosen as the target ringed in black), and the estimated target outline
  (dashed red); the title gives grasp success, FMI, CE and the position error.
* :func:`summary_figure`: GS %, FMI and CE per scene and method as bars, the paper's Table II values as black
  markers.

Files are written to a temporary name and renamed (matplotlib's Agg backend, no display needed).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pipeline import schema
from pipeline.atomic import save_figure
from pipeline.layout import partition
from pipeline.registry import method_title, tracker_names
from pipeline.retrieve import DEFAULT_ESTIMATOR, load_run, primitive_of, read_retrieval
from pipeline.score import read_scores
from pipeline.segment import final_estimates

__all__ = ["figure_path", "outline", "run_figure", "summary_figure"]


def figure_path(out: str | Path, scene: str, seed: int) -> Path:
    """``out/figures/<scene>-<seed:03d>.png``."""
    return Path(out) / "figures" / f"{scene}-{int(seed):03d}.png"


def outline(prim, pose: np.ndarray, n: int = 64) -> np.ndarray:
    """Closed outline (K, 2), metres, of a :class:`pipeline.retrieve.Primitive` at a COM pose (x, y, yaw)."""
    pose = np.asarray(pose, dtype=np.float64)
    c = prim.centre_world(pose)
    if prim.kind == "cylinder":
        t = np.linspace(0.0, 2.0 * np.pi, n)
        return c + prim.half[0] * np.column_stack([np.cos(t), np.sin(t)])
    hx, hy = prim.half[:2]
    corners = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy], [hx, hy]])
    yaw = float(pose[2]) + prim.yaw
    rot = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
    return corners @ rot.T + c


def _save(fig, path: Path) -> None:
    save_figure(fig, path, dpi=100)


def _plt():
    # matplotlib is imported when a figure is drawn, not with this module: about a second of start-up (measured)
    # that every process importing the evaluation (the CLI, the workers) would pay, most of which draw nothing.
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def run_figure(out: str | Path, scene: str, seed: int, methods: Sequence[str], estimator: str | None = None,
               path: str | Path | None = None) -> Path:
    """Draw the run (scene, seed) of an evaluation directory, one panel per method with a scores file, with the
    estimate of ``estimator`` (default: :data:`pipeline.retrieve.DEFAULT_ESTIMATOR`).

    Returns the PNG path (:func:`figure_path` unless ``path`` is given).
    """
    estimator = estimator or DEFAULT_ESTIMATOR
    plt = _plt()
    out = Path(out)
    path = Path(path) if path is not None else figure_path(out, scene, seed)
    info = load_run(partition(out, "runs", scene, seed))
    sc = info.scene
    shapes = []
    for i, spec in enumerate(list(sc.objects) + list(sc.walls)):
        pose = info.final_poses[i]
        if not np.all(np.isfinite(pose)):
            continue
        try:
            shapes.append((outline(primitive_of(spec), pose), i == info.target_id, i >= len(sc.objects)))
        except ValueError:  # a lying object has no constant horizontal slice; not in the retrieval tasks
            continue
    # Zoom on the objects and the gripper's trail; walls are drawn where they enter that window.
    near = [xy for xy, _, is_wall in shapes if not is_wall] + [info.ee]
    lo = np.min([a.min(axis=0) for a in near], axis=0) - 0.06
    hi = np.max([a.max(axis=0) for a in near], axis=0) + 0.06
    methods = [m for m in methods if partition(out, "scores", scene, seed, m, estimator).is_file()] or list(methods)[:1]
    fig, axes = plt.subplots(1, len(methods), figsize=(3.6 * len(methods), 3.9), squeeze=False)
    cmap = plt.get_cmap("tab10")
    for ax, m in zip(axes[0], methods):
        for xy, is_target, is_wall in shapes:
            if is_target:
                ax.fill(xy[:, 0], xy[:, 1], color="0.85", zorder=0)
            ax.plot(xy[:, 0], xy[:, 1], color="k" if is_target else ("0.55" if is_wall else "0.35"),
                    lw=1.6 if is_target else 0.8, zorder=1)
        ax.plot(info.ee[:, 0], info.ee[:, 1], "-", color="tab:blue", lw=0.7, alpha=0.6, zorder=2)
        ax.plot(info.ee[0, 0], info.ee[0, 1], "o", color="tab:blue", ms=3, zorder=2)
        title = method_title(m)
        seg_path = partition(out, "segments", scene, seed, m)
        ret_path = partition(out, "retrieval", scene, seed, m, estimator)
        chosen = None
        if ret_path.is_file():
            r = read_retrieval(ret_path).to_pylist()[0]
            chosen = r["segment"]
            if r["segment"] >= 0:
                est = outline(info.target, np.array([r["x_m"], r["y_m"], r["yaw_rad"]]))
                ax.plot(est[:, 0], est[:, 1], "--", color="tab:red", lw=1.3, zorder=4)
        if seg_path.is_file():
            final = final_estimates(schema.read_segments(seg_path))
            if final.num_rows:
                x = final.column("x_m").to_numpy()
                y = final.column("y_m").to_numpy()
                seg = final.column("segment").to_numpy()
                ax.scatter(x, y, c=[cmap(s % 10) if s >= 0 else (0.5, 0.5, 0.5, 1.0) for s in seg], s=9,
                           linewidths=0.6, edgecolors=["k" if s == chosen else "none" for s in seg], zorder=3)
        sc_path = partition(out, "scores", scene, seed, m, estimator)
        if sc_path.is_file():
            s = read_scores(sc_path).to_pylist()[0]
            gs = {True: "GS yes", False: "GS no", None: "GS -"}[s["grasp_success"]]
            fmi = "-" if s["fmi"] is None else f"{s['fmi']:.2f}"
            ce = "-" if s["contact_error_cm"] is None else f"{s['contact_error_cm']:.2f}"
            title += f"\n{gs}, FMI {fmi}, CE {ce} cm, pos. err. {100 * s['position_error_m']:.1f} cm"
        ax.set_title(title, fontsize=8)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
        ax.tick_params(labelsize=6)
    fig.suptitle(f"{scene} seed {seed}: objects after the last action (target shaded), gripper trail (blue), "
                 f"tracked points by segment (chosen ringed), {estimator} estimate (red dashed)", fontsize=8)
    fig.tight_layout()
    _save(fig, path)
    return path


def summary_figure(rows, path: str | Path) -> Path:
    """GS %, FMI and CE cm per scene and method (bars, std as error bars) with the paper's values (black)."""
    plt = _plt()
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
