"""Segmentation of tracked contact points into objects (the paper's Algorithm 3).

Two points are connected when exp(-d^2 / l) > alpha, i.e. when d^2 < l * ln(1 / alpha); objects are the connected
components of that graph (a true connected-components search, unlike the authors' one-pass grouping). The test
is done on squared distances, so tiny ``l`` or ``alpha`` never underflow an exponential.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pipeline import registry, schema
from pipeline.atomic import all_or_none, save_figure

# Alg. 3's graph lives in pipeline/components.py (STUCCO's tracker uses it too); re-exported here.
from pipeline.components import DEFAULT_ALPHA, DEFAULT_LENGTH, connection_radius, segment_points  # noqa: F401
from pipeline.constraints import plain
from pipeline.labels import canonical_labels
from pipeline.metrics import fmi

SEGMENT_BY = ("auto", "components", "tracker")


def segment_table(tracks, *, length: float, alpha: float, by: str = "auto", method: str = "stucco"):
    """The `segment` stage: add a ``segment`` column to every estimate of a tracks table.

    Each (run, estimate_step) group is one estimate of a run's contact points and is segmented on its own.

    Parameters
    ----------
    tracks : pyarrow.Table
        A validated tracks table.
    length, alpha : float
        Alg. 3 parameters (used when segmenting by connected components).
    by : str
        "components" (Alg. 3 on the tracked points), "tracker" (the tracker's own ``tracker_label``) or "auto":
        what the method's registry entry says (:attr:`pipeline.registry.TrackerSpec.segment_by`): components for
        STUCCO, whose tracker labels *are* Alg. 3, and the tracker's labels for the baselines, whose clusters are
        their segmentation (and for a method not registered).
    method : str
        The tracking method that produced the table (from its metadata), used by ``by="auto"``.

    Returns
    -------
    pyarrow.Table
        The input rows, in order, plus ``segment`` (int64, 0..k-1 per estimate in order of first appearance).
    """
    use_components = resolved_by(by, method) == "components"
    run = np.asarray(tracks.column("run").to_pylist(), dtype=object)
    est = tracks.column("estimate_step").to_numpy()
    xy = np.column_stack([tracks.column("x_m").to_numpy(), tracks.column("y_m").to_numpy()])
    tracker_label = tracks.column("tracker_label").to_numpy()
    segment = np.zeros(len(run), dtype=np.int64)
    if len(run):
        _, group = np.unique(np.stack([np.unique(run, return_inverse=True)[1], est]), axis=1, return_inverse=True)
        group = group.ravel()
        order = np.argsort(group, kind="stable")
        bounds = np.flatnonzero(np.diff(group[order])) + 1
        for rows in np.split(order, bounds):
            if use_components:
                segment[rows] = segment_points(xy[rows], length, alpha)
            else:
                segment[rows] = canonical_labels(tracker_label[rows])
    return tracks.append_column("segment", pa.array(segment, pa.int64()))


def segmentation_params(method: str, overrides: dict | None = None) -> tuple[float, float]:
    """Alg. 3's (l, alpha) for tracks of ``method`` made with parameter ``overrides``: the method's own when its
    parameters have them (STUCCO's, defaults filled in), Table I's otherwise."""
    prm = registry.build_params(registry.tracker(method), dict(overrides or {}))
    values = plain(prm) if prm is not None else {}
    return float(values.get("length", DEFAULT_LENGTH)), float(values.get("alpha", DEFAULT_ALPHA))


def final_estimates(table):
    """Rows of the last estimate of each run (the whole table unless it was written with --every-step)."""
    if table.num_rows == 0:
        return table
    last = table.group_by("run").aggregate([("estimate_step", "max")])
    joined = table.append_column("_row", pa.array(np.arange(table.num_rows))).join(
        last, keys="run", join_type="inner")
    keep = joined.filter(pc.equal(joined["estimate_step"], joined["estimate_step_max"]))
    rows = np.sort(keep.column("_row").to_numpy())
    return table.take(pa.array(rows))


def summarise(segments) -> list[dict]:
    """One dict per (run, segment) of the final estimates: point count, centroid (m) and, when the table
    carries ground truth, the run's Fowlkes-Mallows index."""
    final = final_estimates(segments)
    run = np.asarray(final.column("run").to_pylist(), dtype=object)
    seg = final.column("segment").to_numpy()
    xy = np.column_stack([final.column("x_m").to_numpy(), final.column("y_m").to_numpy()])
    truth = final.column("object_id").to_numpy() if "object_id" in final.column_names else None
    rows = []
    for r in dict.fromkeys(run):
        mask = run == r
        run_fmi = fmi(truth[mask], seg[mask]) if truth is not None else None
        for s in np.unique(seg[mask]):
            sel = mask & (seg == s)
            c = xy[sel].mean(axis=0)
            rows.append(dict(run=r, segment=int(s), n_points=int(sel.sum()), centroid_x_m=float(c[0]),
                             centroid_y_m=float(c[1]), run_fmi=run_fmi))
    return rows


def plot_segments(segments, path, max_runs: int = 6, image_format: str | None = None) -> None:
    """PNG (or ``image_format``) of the final tracked points of up to ``max_runs`` runs, coloured by segment;
    where ground truth is carried, the marker shape shows the true object."""
    # Imported here, not at the top: matplotlib.pyplot takes 0.8 s to import (measured, -X importtime) and only
    # `stucco segment --plot` draws.
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    final = final_estimates(segments)
    run = np.asarray(final.column("run").to_pylist(), dtype=object)
    runs = list(dict.fromkeys(run))[:max_runs] or ["(no contacts)"]
    fig, axes = plt.subplots(1, len(runs), figsize=(max(6.0, 4.2 * len(runs)), 4.6), squeeze=False)
    markers = "osD^v<>phX*"
    truth = final.column("object_id").to_numpy() if "object_id" in final.column_names else None
    for ax, r in zip(axes[0], runs):
        mask = run == r
        x = final.column("x_m").to_numpy()[mask]
        y = final.column("y_m").to_numpy()[mask]
        seg = final.column("segment").to_numpy()[mask]
        cmap = plt.get_cmap("tab10")
        if truth is None:
            ax.scatter(x, y, c=[cmap(s % 10) for s in seg], s=18)
        else:
            t = truth[mask]
            for k, obj in enumerate(np.unique(t)):
                sel = t == obj
                ax.scatter(x[sel], y[sel], c=[cmap(s % 10) for s in seg[sel]], s=22, marker=markers[k % len(markers)],
                           label=f"object {obj}", edgecolors="k", linewidths=0.3)
            ax.legend(fontsize=7, loc="best")
        ax.set_title(f"{r}: {len(np.unique(seg))} segments, {mask.sum()} points", fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    fig.suptitle("tracked contact points: colour = segment" + ("" if truth is None else ", marker = true object"),
                 fontsize=10)
    fig.tight_layout()
    save_figure(fig, path, dpi=110, image_format=image_format)


def resolved_by(by: str, method: str) -> str:
    """What ``by`` (:data:`SEGMENT_BY`) means for a table tracked by ``method``: "components" or "tracker" ("auto":
    the method's registry entry; an unregistered method's own labels)."""
    if by not in SEGMENT_BY:
        raise ValueError(f"by must be one of {', '.join(SEGMENT_BY)}, got {by!r}")
    if by != "auto":
        return by
    known = method in registry.tracker_names()
    return "components" if known and registry.tracker(method).segment_by == "components" else "tracker"


def tracking_record(tracks_meta: dict) -> dict:
    """What a segments table keeps of the tracking behind it (``params.tracking``), from the tracks table's decoded
    metadata: its parameters, root seed and the SHA-256 of its contacts table (None where not recorded). The
    later stages check their other inputs against it: the robot whose trail is free space, a diagnostics file's
    timings, a log's contacts table."""
    contacts = (tracks_meta.get("inputs") or {}).get("contacts") or {}
    return {"params": tracks_meta.get("params") or {}, "seed": tracks_meta.get("seed"),
            "contacts_sha256": contacts.get("sha256")}


def recorded_tracking(segments_meta: dict) -> dict:
    """The tracking a segments file records (:func:`tracking_record`, its ``params.tracking``) from its decoded
    metadata (:func:`pipeline.schema.read_metadata`); {} for a file that records none (written before, or by
    another tool)."""
    return (segments_meta.get("params") or {}).get("tracking") or {}


def segment_file(in_path, out_path, *, seed: int, length: float | None = None, alpha: float | None = None,
                 by: str = "auto", plot_path=None):
    """The `segment` stage on files: segment a tracks table and write the segments table (and, with
    ``plot_path``, :func:`plot_segments` of it: both or neither, :func:`pipeline.atomic.all_or_none`).

    ``length`` and ``alpha`` default to the values the tracks were made with (their metadata), then to Table I;
    the tracking method recorded there decides what ``by="auto"`` means. Returns the segments table.
    """
    if plot_path is not None:
        with all_or_none([out_path, plot_path]) as (table_tmp, plot_tmp):
            segments = segment_file(in_path, table_tmp, seed=seed, length=length, alpha=alpha, by=by)
            plot_segments(segments, plot_tmp, image_format=Path(plot_path).suffix.lstrip(".") or "png")
        return segments
    tracks = schema.read_tracks(in_path)
    tmeta = schema.read_metadata(in_path)
    tparams = tmeta.get("params") or {}
    length = float(length if length is not None else
                   schema.recorded_number(in_path, tparams, "length", DEFAULT_LENGTH, above=0.0))
    alpha = float(alpha if alpha is not None else
                  schema.recorded_number(in_path, tparams, "alpha", DEFAULT_ALPHA, above=0.0, below=1.0))
    method = str(tparams.get("method", "stucco"))
    segments = segment_table(tracks, length=length, alpha=alpha, by=by, method=method)
    # What was used, as used: Alg. 3's length and alpha only when it ran (the tracker's labels need neither).
    used = resolved_by(by, method)
    params = dict(by=used, method=method, **(dict(length=length, alpha=alpha) if used == "components" else {}))
    # every_step: the tracks hold an estimate after every step, which the online estimator needs (docs/tables.md)
    params.update(every_step=bool(tparams.get("every_step")), tracking=tracking_record(tmeta))
    # Segmenting draws nothing: the table's seed is the tracks' (the root seed of their runs), not this command's.
    tseed = tmeta.get("seed")
    schema.write_table(segments, out_path, stage="segment", params=params,
                       seed=tseed if isinstance(tseed, int) else seed, inputs={"tracks": str(in_path)},
                       kind="segments")
    return segments
