"""Drawing blocks shared by every figure of a run: the scene at its final poses, the gripper's trail (scripted
actions and the active protocol's probes told apart), contact points coloured by segment with the true objects
named, the estimated target and the grasp attempted at it, and titles wrapped to the figure's width.

Nothing here reads a file: :mod:`pipeline.figures` (the evaluation's figures) and :mod:`pipeline.figures.tables`
(``stucco plot``, ``stucco segment --plot``) gather what to draw.
"""
from __future__ import annotations

import textwrap
from collections.abc import Sequence

import numpy as np

from pipeline.geometry import rotate
from pipeline.retrieve import primitive_of

__all__ = ["pyplot", "outline", "scene_shapes", "window", "draw_scene", "draw_trail", "draw_points", "draw_estimate",
           "draw_grasp", "wrap", "legend_outside", "TRAIL", "PROBE", "ESTIMATE"]

#: Colours of the layers (segments use tab10, unassigned points grey).
#: The trail is dark grey and the probes amber so that neither is taken for a segment's tab10 colour.
TRAIL, PROBE, ESTIMATE, GRASP_OK, GRASP_FAIL = "0.3", "#ffb000", "tab:red", "tab:green", "tab:red"
UNASSIGNED = (0.55, 0.55, 0.55, 1.0)
#: Marker per true object (index into the scene's bodies, in order of appearance in a panel).
MARKERS = "osD^v<>phX*"


def pyplot():
    """matplotlib.pyplot on the Agg backend, imported when a figure is drawn: about a second of start-up (measured)
    that every process importing the evaluation (the CLI, the workers) would pay, most of which draw nothing."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


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
    return rotate(corners, yaw) + c


def scene_shapes(info) -> list[tuple[np.ndarray, bool, bool, str]]:
    """(outline, is target, is wall, name) of every body of a run (:class:`pipeline.retrieve.RunInfo`) at its pose
    after the last action; bodies not built or without a constant horizontal slice are left out."""
    sc = info.scene
    shapes = []
    for i, spec in enumerate(list(sc.objects) + list(sc.walls)):
        pose = info.final_poses[i]
        if not np.all(np.isfinite(pose)):
            continue
        try:
            shapes.append((outline(primitive_of(spec), pose), i == info.target_id, i >= len(sc.objects), spec.name))
        except ValueError:  # a lying object has no constant horizontal slice; not in the retrieval tasks
            continue
    return shapes


def window(shapes, *points: np.ndarray, margin: float = 0.06) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) corners around the objects (not the walls) and ``points`` (each (K, 2)), plus ``margin``."""
    near = [xy for xy, _, is_wall, _ in shapes if not is_wall] + [np.asarray(p).reshape(-1, 2) for p in points
                                                                 if np.asarray(p).size]
    if not near:
        return np.array([-0.3, -0.3]), np.array([0.3, 0.3])
    lo = np.min([a.min(axis=0) for a in near], axis=0) - margin
    hi = np.max([a.max(axis=0) for a in near], axis=0) + margin
    return lo, hi


def draw_scene(ax, shapes, names: bool = False) -> None:
    """Walls and objects outlined (the target thicker and shaded); with ``names``, each object's name at its centre."""
    for xy, is_target, is_wall, name in shapes:
        if is_target:
            ax.fill(xy[:, 0], xy[:, 1], color="0.88", zorder=0)
        ax.plot(xy[:, 0], xy[:, 1], color="k" if is_target else ("0.6" if is_wall else "0.35"),
                lw=1.6 if is_target else 0.8, zorder=1)
        if names and not is_wall:
            c = xy[:-1].mean(axis=0)
            ax.annotate(name + (" (target)" if is_target else ""), c, fontsize=6, ha="center", va="center",
                        color="0.25", zorder=1, annotation_clip=True)


def draw_trail(ax, ee: np.ndarray, probe: np.ndarray | None = None, label: bool = True) -> None:
    """The gripper's trail ``ee`` (K + 1, 2): scripted actions as a thin grey line, the probing policy's actions
    (``probe``, (K,) bool) as thick amber segments with their end points, the start as a dot."""
    ee = np.asarray(ee, dtype=np.float64)
    probe = np.zeros(len(ee) - 1, bool) if probe is None else np.asarray(probe, bool)
    scripted = np.where(np.r_[~probe, False] | np.r_[False, ~probe], ee.T, np.nan).T  # vertices of scripted moves
    ax.plot(scripted[:, 0], scripted[:, 1], "-", color=TRAIL, lw=0.8, alpha=0.7, zorder=2,
            label="gripper trail (scripted)" if label else None)
    if probe.any():
        for k in np.flatnonzero(probe):
            ax.plot(ee[k:k + 2, 0], ee[k:k + 2, 1], "-", color=PROBE, lw=2.0, alpha=0.9, zorder=2,
                    solid_capstyle="round")
        ends = ee[1:][probe]
        ax.plot(ends[:, 0], ends[:, 1], "o", color=PROBE, ms=2.5, zorder=2,
                label=f"probes ({int(probe.sum())} actions)" if label else None)
    ax.plot(ee[0, 0], ee[0, 1], "o", color=TRAIL, ms=4, zorder=2, label="start" if label else None)


def draw_points(ax, xy: np.ndarray, colour_key: np.ndarray, colour_label: str, truth: np.ndarray | None = None,
                body_names: Sequence[str] | None = None, ringed: int | None = None,
                colour_names: Sequence[str] | None = None) -> list:
    """Points (M, 2) coloured by ``colour_key`` (segment or tracker label; -1 grey, "unassigned"), their marker
    the true object (``truth``: index into ``body_names``, -1 unknown). Returns legend handles: one per colour
    (``colour_label`` k) and one per true object, named, so the legend shows every colour and every marker.
    ``ringed``: the colour key drawn with a black ring (the chosen segment). ``colour_names``: the colour key is
    an index into these names (the true object), used for the colours' legend entries."""
    from matplotlib.lines import Line2D

    cmap = pyplot().get_cmap("tab10")
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    key = np.asarray(colour_key, dtype=np.int64)
    colours = [cmap(int(k) % 10) if k >= 0 else UNASSIGNED for k in key]
    truth = np.full(len(xy), -2, np.int64) if truth is None else np.asarray(truth, np.int64)
    chosen = (key == ringed) if ringed is not None else np.zeros(len(key), bool)
    object_handles = []
    for j, obj in enumerate(dict.fromkeys(truth.tolist())):
        sel = np.flatnonzero(truth == obj)
        marker = MARKERS[j % len(MARKERS)] if obj != -2 else "o"
        ax.scatter(xy[sel, 0], xy[sel, 1], c=[colours[i] for i in sel], s=22, marker=marker, zorder=3,
                   edgecolors=["k" if chosen[i] else "0.2" for i in sel],
                   linewidths=[1.2 if chosen[i] else 0.3 for i in sel])
        if obj != -2:  # -2: no ground truth carried
            name = (body_names[obj] if body_names is not None and 0 <= obj < len(body_names)
                    else ("no object" if obj < 0 else f"object {obj}"))
            object_handles.append(Line2D([], [], ls="", marker=marker, mfc="white", mec="k", ms=6,
                                         label=f"true: {name}"))
    colour_handles = []
    for k in sorted(set(key.tolist())):
        if colour_names is not None:
            text = colour_names[k] if 0 <= k < len(colour_names) else ("no object" if k < 0 else f"object {k}")
        else:
            text = (f"{colour_label} {k}" if k >= 0 else "unassigned") + (" (chosen)" if k == ringed else "")
        colour_handles.append(Line2D([], [], ls="", marker="o", mfc=cmap(int(k) % 10) if k >= 0 else UNASSIGNED,
                                     mec="k" if k == ringed else "none", ms=6, label=text))
    return colour_handles + object_handles


def draw_estimate(ax, target, pose: np.ndarray, label: str = "estimate") -> None:
    """The estimated target outline (dashed red) at a COM pose (3,)."""
    est = outline(target, np.asarray(pose, dtype=np.float64))
    ax.plot(est[:, 0], est[:, 1], "--", color=ESTIMATE, lw=1.3, zorder=4, label=label)


def draw_grasp(ax, scene, target, pose: np.ndarray, success: bool | None) -> None:
    """The grasp attempted at an estimated pose (:func:`pipeline.grasp.pregrasp`): an arrow from the pre-grasp point
    along the approach to the estimated centre, green if it held, red if it failed (nothing if not simulated)."""
    if success is None:
        return
    from pipeline.grasp import plan_for, pregrasp

    try:
        _, pre, approach = pregrasp(plan_for(scene), target, np.asarray(pose, dtype=np.float64))
    except ValueError:  # a scene without a target: nothing was grasped
        return
    centre = np.asarray(target.centre_world(np.asarray(pose, dtype=np.float64)))
    start = centre - 0.6 * (centre - pre)  # the last stretch of the approach, so the arrow stays in the window
    colour = GRASP_OK if success else GRASP_FAIL
    ax.annotate("", centre, start, arrowprops=dict(arrowstyle="-|>", color=colour, lw=1.8), zorder=5)
    ax.plot([], [], color=colour, lw=1.8, marker=">", ms=5, label=f"grasp attempt ({'held' if success else 'failed'})")


def wrap(text: str, width_in: float, fontsize: float) -> str:
    """``text`` broken into lines that fit ``width_in`` inches at ``fontsize`` points (each line wrapped alone)."""
    chars = max(20, int(width_in * 72.0 / (0.55 * fontsize)))
    return "\n".join(textwrap.fill(line, chars) for line in text.split("\n"))


def legend_outside(ax, handles: list | None = None, fontsize: float = 7) -> None:
    """The panel's legend to the right of it, outside the data (nothing when there is nothing to list)."""
    h, labels = ax.get_legend_handles_labels()
    handles = list(h) + list(handles or [])
    if handles:
        ax.legend(handles=handles, fontsize=fontsize, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0,
                  frameon=False)
