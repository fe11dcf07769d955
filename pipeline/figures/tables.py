"""One run of any stage's table drawn over its scene: ``stucco plot`` (:func:`plot_table`) and ``stucco segment
--plot`` (:func:`segments_with_plot`).

The scene is the one the run was collected in: a run file carries it (``params.scene_toml``), and every later table
records the SHA-256 of the run files it derives from (``stucco.runs``), so the run file is looked up beside the table
(its folder, a ``runs/`` folder there or above it, as ``stucco collect --out runs`` and ``stucco evaluate`` leave
them) or where ``runs`` says, and accepted only if its bytes are the recorded ones.

What each table adds over the scene (objects at their final poses, the gripper's trail with the probing policy's
actions told apart): a run its true contact points, by object; contacts the isolated contact points, by true object;
tracks the final tracked points by the tracker's label; segments the final points by segment, their marker the true
object (named as in the scene); retrieval the estimated target and the grasp attempted at it.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from pipeline import schema
from pipeline.atomic import all_or_none, save_figure
from pipeline.figures.draw import (
    draw_estimate,
    draw_grasp,
    draw_points,
    draw_scene,
    draw_trail,
    legend_outside,
    outline,
    pyplot,
    scene_shapes,
    window,
    wrap,
)
from pipeline.retrieve import load_run, run_files_by_name
from pipeline.safe_open import regular_file
from pipeline.segment import final_estimates, segment_file

__all__ = ["PLOTTABLE", "probe_actions", "find_run_file", "plot_table", "segments_with_plot"]

#: Table kinds ``stucco plot`` draws (``stucco.schema`` metadata), with what it calls them.
PLOTTABLE = {"sim_run": "run", "contacts": "contacts", "tracks": "tracks", "segments": "segments",
             "retrieval": "retrieval"}
#: Folders above a table searched for a ``runs/`` folder (an evaluation's segments sit four levels below it).
_UP = 5


def probe_actions(run_path: str | Path, n: int) -> np.ndarray:
    """(n,) bool: which actions of a run file the probing policy made (its optional ``probe`` column; all False
    for a run without one)."""
    names = pq.read_schema(regular_file(run_path, "the run file")).names
    if "probe" not in names:
        return np.zeros(n, bool)
    col = pq.read_table(run_path, columns=["probe"]).column("probe").to_pylist()
    return np.array([bool(v) for v in col][:n] + [False] * max(0, n - len(col)), bool)


def _search_dirs(table_path: Path) -> list[Path]:
    here = table_path.parent
    dirs = [here, here / "runs"] + [p / "runs" for p in list(here.parents)[:_UP]]
    return list(dict.fromkeys(d for d in dirs if d.is_dir()))


def find_run_file(table_path: str | Path, run: str, runs: str | Path | None = None) -> Path:
    """The collected run file of ``run`` that the table at ``table_path`` derives from: in ``runs`` (a folder or a
    run file) when given, else beside the table (module docstring); its SHA-256 must be the one the table records.

    Raises ValueError (one line naming the table and the run) when there is none.
    """
    table_path = Path(table_path)
    recorded = (schema.read_metadata(table_path).get("runs") or {}).get(run)
    dirs = [Path(runs)] if runs is not None else _search_dirs(table_path)
    differs = None
    for d in dirs:
        try:
            files = run_files_by_name(d)
        except (ValueError, OSError, schema.SchemaError):
            if runs is not None:
                raise
            continue
        f = files.get(run)
        if f is None:
            continue
        if recorded and schema.file_digest(f) != recorded:
            differs = f
            continue
        return f
    if differs is not None:
        raise ValueError(f"{table_path}: {differs} is not the run file of {run} this table was made from (its "
                         f"SHA-256 differs from the recorded {recorded[:12]}…); pass --runs with the right one")
    where = str(runs) if runs is not None else ", ".join(str(d) for d in dirs) or f"{table_path.parent}"
    raise ValueError(f"{table_path}: no run file of {run} found (looked in {where}); pass --runs DIR, the folder "
                     f"`stucco collect --out` wrote")


def _layer(kind: str, t: pa.Table, run: str) -> dict:
    """What a table of ``kind`` draws for ``run`` (rows ``t`` of that run): points and how to colour them, or the
    estimate; and a line of counts for the title."""
    if kind == "sim_run":
        known = np.array([v is not None for v in t.column("true_contact_x_m").to_pylist()], bool)
        xy = np.column_stack([np.nan_to_num(np.asarray(t.column(c).to_pylist(), dtype=float))
                              for c in ("true_contact_x_m", "true_contact_y_m")])[known]
        obj = t.column("object_id").to_numpy()[known]
        n_contact = int(np.sum(t.column("in_contact").to_numpy(zero_copy_only=False)))
        return dict(xy=xy, key=obj, by_object=True,
                    line=f"{t.num_rows} actions, {n_contact} in contact; true contact points by object")
    if kind == "contacts":
        ok = np.asarray(t.column("in_contact").to_numpy(zero_copy_only=False), bool)
        ok &= np.array([v is not None for v in t.column("contact_x_m").to_pylist()], bool)
        xy = np.column_stack([np.asarray(t.column(c).to_pylist(), dtype=object)[ok].astype(float)
                              for c in ("contact_x_m", "contact_y_m")])
        obj = t.column("object_id").to_numpy()[ok] if "object_id" in t.column_names else np.full(len(xy), -1)
        return dict(xy=xy, key=obj, by_object=True,
                    line=f"{int(ok.sum())} isolated contact points of {t.num_rows} actions, by true object")
    if kind in ("tracks", "segments"):
        final = final_estimates(t)
        xy = np.column_stack([final.column("x_m").to_numpy(), final.column("y_m").to_numpy()]) if final.num_rows \
            else np.zeros((0, 2))
        col, label = ("segment", "segment") if kind == "segments" else ("tracker_label", "label")
        key = final.column(col).to_numpy() if final.num_rows else np.zeros(0, np.int64)
        truth = final.column("object_id").to_numpy() if "object_id" in final.column_names else None
        n = len(set(key.tolist()) - {-1})
        return dict(xy=xy, key=key, label=label, truth=truth,
                    line=f"{len(xy)} final tracked points, {n} {label}{'s' if n != 1 else ''}"
                         + ("; marker: true object" if truth is not None else ""))
    r = t.to_pylist()[0]  # retrieval: one row per run
    grasp = {True: "grasp held", False: f"grasp failed ({r['grasp_outcome']})", None: "grasp not simulated"}
    error = "no ground truth to score it" if r["position_error_m"] is None else \
        f"position error {100 * r['position_error_m']:.1f} cm, yaw error {r['yaw_error_rad']:.2f} rad"
    return dict(xy=np.zeros((0, 2)), key=np.zeros(0, np.int64), estimate=r,
                line=f"{r['estimator']} estimate ({r['x_m']:.3f}, {r['y_m']:.3f}) m, {r['yaw_rad']:.2f} rad: {error}; "
                     f"{grasp[r['grasp_success']]}" + (f"; notes {r['notes']}" if r["notes"] else ""))


def _recorded_input(retrieval_path: Path, meta: dict, kind: str) -> Path | None:
    """The input file of ``kind`` (``contacts``, ``segments``) a retrieval table's metadata ``meta`` records, when
    it lies beside the table byte for byte as recorded (its SHA-256); None otherwise."""
    rec = (meta.get("inputs") or {}).get(kind) or {}
    path = retrieval_path.parent / str(rec.get("file") or "")
    return path if rec.get("file") and path.is_file() and schema.file_digest(path) == rec.get("sha256") else None


def _log_of(retrieval_path: Path, run: str) -> dict | None:
    """For a retrieval made from a robot log (`stucco retrieve --target`, no run file): its target spec ``spec``,
    primitive ``target`` and the gripper's trail ``ee`` (K, 2) from the contacts table it records, when that lies
    beside it (an empty trail otherwise); None for a retrieval of simulated runs."""
    meta = schema.read_metadata(retrieval_path)
    spec = (meta.get("params") or {}).get("target")
    if not spec:
        return None
    from pipeline.estimators.log_run import parse_target

    target = parse_target(spec)[0]
    ee = np.zeros((0, 2))
    path = _recorded_input(retrieval_path, meta, "contacts")
    if path is not None:
        t = schema.read_contacts(path)
        t = t.filter(pc.equal(t.column("run"), run))
        ee = np.column_stack([np.asarray(t.column(c).to_pylist(), dtype=float) for c in ("ee_x_m", "ee_y_m")]) \
            if t.num_rows else ee
    return {"spec": spec, "target": target, "ee": ee}


def _framed(info, log: dict | None, layer: dict) -> np.ndarray:
    """What a figure must hold besides its layer's points (M, 2): the run's trail, or a log's trail and estimated
    outline (nothing for a run drawn without its scene)."""
    if info is not None:
        return info.ee
    if log is None:
        return np.zeros((0, 2))
    r = layer.get("estimate")
    est = outline(log["target"], np.array([r["x_m"], r["y_m"], r["yaw_rad"]])) if r is not None and \
        r["segment"] >= 0 else np.zeros((0, 2))
    return np.vstack([log["ee"], est])


def _with_segments(retrieval_path: Path, run: str, layer: dict) -> None:
    """Add to a retrieval layer the final segments it was estimated from (its recorded segments file, beside it and
    byte for byte the recorded one), the chosen one ringed; nothing when that file is not found."""
    path = _recorded_input(retrieval_path, schema.read_metadata(retrieval_path), "segments")
    if path is None:
        return
    t = schema.read_segments(path)
    seg = _layer("segments", t.filter(pc.equal(t.column("run"), run)), run)
    layer.update(xy=seg["xy"], key=seg["key"], label="segment", truth=seg["truth"],
                 ringed=layer["estimate"]["segment"])
    layer["line"] += f"; segments of {path.name}, the chosen one ringed"


def _panel(ax, info, probe: np.ndarray | None, layer: dict, log: dict | None = None) -> list:
    """Draw one run's layer over its scene (``info`` None: no scene found, points only; with ``log``, a robot log's
    retrieval: its trail ``ee`` (K, 2) and its target ``target``, :func:`_log_of`); legend handles."""
    names = list(info.scene.body_names) if info is not None else None
    shapes = scene_shapes(info) if info is not None else []
    if info is not None:
        draw_scene(ax, shapes, names=True)
        draw_trail(ax, info.ee, probe)
    elif log is not None and len(log["ee"]):
        draw_trail(ax, log["ee"])
    handles = []
    if len(layer["xy"]) or "estimate" not in layer or "label" in layer:
        if layer.get("by_object"):
            handles = draw_points(ax, layer["xy"], layer["key"], "object", truth=None, body_names=names,
                                  colour_names=names)
        else:
            handles = draw_points(ax, layer["xy"], layer["key"], layer["label"], truth=layer.get("truth"),
                                  body_names=names, ringed=layer.get("ringed"))
    r = layer.get("estimate")
    if r is not None and r["segment"] >= 0 and (info is not None or log is not None):
        pose = np.array([r["x_m"], r["y_m"], r["yaw_rad"]])
        draw_estimate(ax, info.target if info is not None else log["target"], pose, label=f"{r['estimator']} estimate")
        if info is not None:
            draw_grasp(ax, info.scene, info.target, pose, r["grasp_success"])
    lo, hi = window(shapes, layer["xy"], _framed(info, log, layer))
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)", fontsize=7)
    ax.set_ylabel("y (m)", fontsize=7)
    ax.tick_params(labelsize=6)
    return handles


def _read(path: Path) -> tuple[str, pa.Table]:
    kind = schema.read_metadata(path).get("schema")
    if kind not in PLOTTABLE:
        raise ValueError(f"{path}: a {kind or 'table without stucco.schema metadata'} table; `stucco plot` draws "
                         f"{', '.join(PLOTTABLE.values())} tables (a scores table has no geometry: `stucco score "
                         f"--print`)")
    return kind, schema.read_run(path) if kind == "sim_run" else schema.read_table(path, kind)


def plot_table(in_path: str | Path, out_path: str | Path, run: str | None = None,
               runs: str | Path | None = None) -> tuple[Path, str, str]:
    """Draw one run (``run``, default the table's first) of the table at ``in_path`` over its scene into
    ``out_path`` (PNG, or the suffix's format), atomically. Returns (path, run, table kind)."""
    in_path, out_path = Path(in_path), Path(out_path)
    kind, t = _read(in_path)
    names = list(dict.fromkeys(t.column("run").to_pylist()))
    if not names:
        raise ValueError(f"{in_path}: the table has no rows to draw")
    run = names[0] if run is None else run
    if run not in names:
        shown = ", ".join(names[:6]) + (", ..." if len(names) > 6 else "")
        raise ValueError(f"--run {run}: not in {in_path} (its runs: {shown})")
    rows = t.filter(pc.equal(t.column("run"), run))
    log = _log_of(in_path, run) if kind == "retrieval" else None
    run_path = None if log is not None else in_path if kind == "sim_run" else find_run_file(in_path, run, runs)
    info = None if run_path is None else load_run(run_path)
    probe = None if run_path is None else probe_actions(run_path, len(info.ee) - 1)
    layer = _layer(kind, rows, run)
    if kind == "retrieval":
        _with_segments(in_path, run, layer)
    lo, hi = window(scene_shapes(info) if info is not None else [], layer["xy"], _framed(info, log, layer))
    ratio = float(np.clip((hi[1] - lo[1]) / (hi[0] - lo[0]), 0.6, 1.6))
    fig, ax = pyplot().subplots(figsize=(5.0 + 2.8, 5.0 * ratio + 1.2))
    handles = _panel(ax, info, probe, layer, log)
    legend_outside(ax, handles)
    where = f"scene {info.scene.name}, seed {info.seed}, {info.policy} policy" if info is not None else \
        f"a robot log, target {log['spec']}, no scene"
    title = f"{in_path.name}: {PLOTTABLE[kind]} table, run {run} ({where})\n{layer['line']}"
    fig.suptitle(wrap(title, 7.4, 9), fontsize=9)
    fig.tight_layout()
    save_figure(fig, out_path, dpi=110, image_format=out_path.suffix.lstrip(".") or "png")
    return out_path, run, kind


def segments_figure(segments: pa.Table, tracks_path: str | Path, path: str | Path, runs: str | Path | None = None,
                    max_runs: int = 6, image_format: str | None = None) -> list[str]:
    """The final segments of up to ``max_runs`` runs, one panel each over its scene (the run files found as
    :func:`find_run_file` says, from the tracks the segments were made from). Returns a note per run drawn
    without its scene (no run file found)."""
    plt = pyplot()
    final = final_estimates(segments)
    run_names = list(dict.fromkeys(final.column("run").to_pylist()))[:max_runs]
    n = max(1, len(run_names))
    fig, axes = plt.subplots(1, n, figsize=(max(6.5, 5.2 * n), 5.0), squeeze=False)
    notes = []
    for ax, run in zip(axes[0], run_names or [None]):
        if run is None:
            ax.set_title("(no contacts)", fontsize=9)
            continue
        rows = final.filter(pc.equal(final.column("run"), run))
        try:
            run_path = find_run_file(tracks_path, run, runs)
            info = load_run(run_path)
            probe = probe_actions(run_path, len(info.ee) - 1)
        except (ValueError, schema.SchemaError) as e:
            info, probe = None, None
            notes.append(f"{run}: drawn without its scene ({' '.join(str(e).split())})")
        layer = _layer("segments", rows, run)
        handles = _panel(ax, info, probe, layer)
        ax.legend(handles=ax.get_legend_handles_labels()[0] + handles, fontsize=6, loc="upper center",
                  bbox_to_anchor=(0.5, -0.14), ncol=3, frameon=False)
        ax.set_title(wrap(f"{run}: {layer['line']}", 5.0, 8), fontsize=8)
    fig.suptitle("final tracked points: colour = segment, marker = true object (named as in the scene)", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path, dpi=110, image_format=image_format)
    return notes


def segments_with_plot(in_path: str | Path, out_path: str | Path, plot_path: str | Path, *, seed: int,
                       runs: str | Path | None = None, **segment_options) -> tuple[pa.Table, list[str]]:
    """The segment stage (:func:`pipeline.segment.segment_file`) and :func:`segments_figure` of its table: both
    files or neither (:func:`pipeline.atomic.all_or_none`). Returns the segments table and the figure's notes."""
    with all_or_none([out_path, plot_path]) as (table_tmp, plot_tmp):
        segments = segment_file(in_path, table_tmp, seed=seed, **segment_options)
        notes = segments_figure(segments, in_path, plot_tmp, runs=runs,
                                image_format=Path(plot_path).suffix.lstrip(".") or "png")
    return segments, notes
