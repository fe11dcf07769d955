"""The ``score`` stage: one row per (scene, seed, method) with the metrics of the paper's Table II.

* **Contact error** (docs/retrieval.md, "Scoring"): for every final tracked point, the signed distance to the nearest
  true surface among all objects **and walls** at their poses after the last action (negative inside),
  and CE = mean |distance|, reported in cm. Computed analytically on the horizontal slice of the scene's
  primitives (boxes and upright cylinders have one cross-section over their height, so this equals the
  authors' pybullet closest-point query on objects extruded in z; pybullet's 1 mm collision margin is not
  added).
* **FMI** (paper §III): ``sklearn.metrics.fowlkes_mallows_score`` between the ground-truth object id and the segment
  over the final tracked points with a known object (``object_id >= 0``). An unassigned point (segment -1)
  counts as its own cluster.
* **Grasp success and pose error**: from the retrieval table (:mod:`pipeline.retrieve`, :mod:`pipeline.grasp`);
  the position error in cm (``position_error_cm``, the retrieval table's metres x 100), like the contact error, so
  the table has one length unit; the yaw error stays in rad.
* **Scene**: ``scene_sha256``, the digest of the scene the run was collected in, by which the report tells the
  shipped tasks (compared with the paper) from a user's scene of the same name.
* **Timings**: ``track_s`` (sum of the tracker's per-step update times, from the track diagnostics table when it
  is found), ``retrieve_s`` (ICP and selection), ``grasp_s`` (grasp simulation); ``wall_s`` is their sum (the
  collect and isolate stages record no per-run time).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from pipeline import schema
from pipeline.geometry import Primitive, primitive_of
from pipeline.metrics import fmi
from pipeline.retrieve import check_runs, load_run, read_retrieval, run_files_by_name
from pipeline.scenes.files import scene_digest
from pipeline.schema.results import SCORES, SCORES_COLUMNS
from pipeline.segment import final_estimates, recorded_tracking, tracking_record

__all__ = ["scene_signed_distance", "contact_error_cm", "fmi", "score", "SCORES_COLUMNS", "SCORES",
           "validate_scores", "read_scores", "diagnostics_beside", "summary_lines", "check_score_inputs",
           "score_file"]


def scene_signed_distance(points: np.ndarray, scene, poses: np.ndarray,
                          primitive: Callable[[Any], Primitive] = primitive_of) -> np.ndarray:
    """Signed distance (m) of world points to the nearest object or wall of a scene.

    Parameters
    ----------
    points : ndarray, shape (M, 2), metres
    scene : pipeline.scenes.Scene
    poses : ndarray, shape (B, 3)
        Every body's (x, y, yaw) in ``scene.body_names`` order (objects: inertial frame; walls: centre). Rows
        with NaN (bodies not built) are skipped.
    primitive : callable
        Body spec -> its horizontal slice (:class:`pipeline.retrieve.Primitive`); :func:`primitive_of`, which
        refuses bodies that are not upright, unless the caller approximates those (the training study,
        docs/studies.md).

    Returns
    -------
    ndarray, shape (M,)
        min over bodies of the signed distance (negative inside a body); inf if no body was built.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    specs = list(scene.objects) + list(scene.walls)
    if len(specs) != len(poses):
        raise ValueError(f"scene {scene.name} has {len(specs)} bodies but {len(poses)} poses were given")
    best = np.full(len(pts), np.inf)
    for spec, pose in zip(specs, poses):
        if not np.all(np.isfinite(pose)):
            continue
        best = np.minimum(best, primitive(spec).signed_distance(pts, pose))
    return best


def contact_error_cm(points: np.ndarray, scene, poses: np.ndarray,
                     primitive: Callable[[Any], Primitive] = primitive_of) -> float | None:
    """Mean |signed distance| of the points (M, 2), metres, to the scene's surfaces at ``poses`` (B, 3), in cm;
    None without points. ``primitive`` as in :func:`scene_signed_distance`."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(pts) == 0:
        return None
    return float(np.mean(np.abs(scene_signed_distance(pts, scene, poses, primitive))) * 100.0)


def diagnostics_beside(segments_path: str | Path) -> Path | None:
    """The track diagnostics file next to a segments file, found through the segments' recorded input
    (``inputs.tracks.file``) and ``stucco track``'s default name; None if there is none."""
    segments_path = Path(segments_path)
    try:
        meta = schema.read_metadata(segments_path)
    except schema.SchemaError:
        return None
    tracks = ((meta.get("inputs") or {}).get("tracks") or {}).get("file")
    if not tracks:
        return None
    cand = segments_path.parent / (tracks.removesuffix(".parquet") + ".diagnostics.parquet")
    return cand if cand.is_file() else None


def _track_seconds(diagnostics: pa.Table | None) -> dict[str, float]:
    if diagnostics is None or diagnostics.num_rows == 0:
        return {}
    run = np.asarray(diagnostics.column("run").to_pylist(), dtype=object)
    ms = diagnostics.column("update_ms").to_numpy()
    out: dict[str, float] = {}
    for r in dict.fromkeys(run):
        out[r] = float(ms[run == r].sum() / 1e3)
    return out


def score(segments: pa.Table, retrieval: pa.Table, run_dir: str | Path, *, diagnostics: pa.Table | None = None,
          segments_path: str = "<segments>", retrieval_path: str = "<retrieval>") -> pa.Table:
    """Score every run of a retrieval table.

    Parameters
    ----------
    segments : pyarrow.Table
        The segments table the retrieval was made from (final estimate per run is scored).
    retrieval : pyarrow.Table
        A validated retrieval table (one row per run).
    run_dir : path
        Directory of the collected run files, or one of them (final object poses for the contact error).
    diagnostics : pyarrow.Table, optional
        The track diagnostics table (per-run tracking time).

    Returns
    -------
    pyarrow.Table
        The scores table (:data:`SCORES_COLUMNS`), one row per run of ``retrieval``, in its order.
    """
    files = run_files_by_name(run_dir)
    final = final_estimates(segments)
    run = np.asarray(final.column("run").to_pylist(), dtype=object)
    xy = np.column_stack([final.column("x_m").to_numpy(), final.column("y_m").to_numpy()]) if final.num_rows \
        else np.zeros((0, 2))
    seg = final.column("segment").to_numpy() if final.num_rows else np.zeros(0, np.int64)
    truth = final.column("object_id").to_numpy() if "object_id" in final.column_names else None
    rrun = retrieval.column("run").to_pylist()
    extra = sorted(set(run.tolist()) - set(rrun))
    if extra:
        raise ValueError(f"{segments_path}: run {extra[0]!r} has no row in {retrieval_path}; were they made from "
                         f"the same segments?")
    track_s = _track_seconds(diagnostics)
    rows: list[dict[str, Any]] = []
    R = retrieval.to_pylist()
    for r in R:
        name = r["run"]
        if name not in files:
            raise ValueError(f"{retrieval_path}: run {name!r} has no collected run file in {run_dir}")
        info = load_run(files[name])
        m = run == name
        ce = contact_error_cm(xy[m], info.scene, info.final_poses)
        f = fmi(truth[m], seg[m]) if truth is not None and m.any() else None
        ts = track_s.get(name)
        parts = [v for v in (ts, r["icp_s"], r["grasp_s"]) if v is not None]
        rows.append(dict(scene=r["scene"], seed=r["seed"], method=r["method"], estimator=r["estimator"], run=name,
                         grasp_success=r["grasp_success"], grasp_attempts=r["grasp_attempts"],
                         grasp_success_any=r["grasp_success_any"], fmi=f, contact_error_cm=ce,
                         position_error_cm=r["position_error_m"] * 100.0, yaw_error_rad=r["yaw_error_rad"],
                         low_confidence=r["low_confidence"], n_points=int(m.sum()), n_segments=r["n_segments"],
                         track_s=ts, retrieve_s=r["icp_s"], grasp_s=r["grasp_s"], wall_s=float(sum(parts)),
                         scene_sha256=scene_digest(info.scene.source)))
    arrays = {c.name: pa.array([row[c.name] for row in rows], type=c.type) for c in SCORES_COLUMNS}
    return validate_scores(pa.table(arrays), "the scores computed from the retrieval, segments and diagnostics")


def validate_scores(table: pa.Table, path: str | Path = "<table>") -> pa.Table:
    """Validate a scores table (one-line SchemaError; the spec :data:`SCORES` is in :mod:`pipeline.schema.results`)."""
    return schema.validate_spec(table, SCORES, path)


def read_scores(path: str | Path) -> pa.Table:
    return schema.read_table(path, "scores")


def summary_lines(scores: pa.Table) -> list[str]:
    """Human-readable per (scene, method) summary: GS %, FMI and CE mean (std), pose errors (median)."""
    lines = []
    scene = np.asarray(scores.column("scene").to_pylist(), dtype=object)
    method = np.asarray(scores.column("method").to_pylist(), dtype=object)
    gs = np.array([np.nan if v is None else float(v) for v in scores.column("grasp_success").to_pylist()])

    def col(n):
        return np.array([np.nan if v is None else v for v in scores.column(n).to_pylist()], dtype=np.float64)

    f, ce, pe, ye = col("fmi"), col("contact_error_cm"), col("position_error_cm"), col("yaw_error_rad")
    est = np.asarray(scores.column("estimator").to_pylist(), dtype=object)
    for key in dict.fromkeys(zip(scene.tolist(), method.tolist(), est.tolist())):
        m = (scene == key[0]) & (method == key[1]) & (est == key[2])

        def ms(a):
            a = a[m]
            a = a[np.isfinite(a)]
            return "  -  " if not len(a) else f"{a.mean():.2f} ({a.std():.2f})"

        g = gs[m]
        g = g[np.isfinite(g)]
        gtxt = "  -" if not len(g) else f"{100 * g.mean():3.0f}"
        pem = np.nanmedian(pe[m]) if np.isfinite(pe[m]).any() else math.nan
        yem = np.nanmedian(ye[m]) if np.isfinite(ye[m]).any() else math.nan
        lines.append(f"{key[0]:<6} {key[1]:<8} {key[2]:<9} runs {int(m.sum()):>3}  GS {gtxt} %  "
                     f"FMI {ms(f)}  CE {ms(ce)} cm  "
                     f"pos err median {pem:.1f} cm  yaw err median {yem:.2f} rad")
    return lines


def check_score_inputs(retrieval_path: str | Path, segments_path: str | Path, segments: pa.Table,
                       diagnostics: pa.Table | None = None, diagnostics_path: str | Path | None = None) -> None:
    """Refuse (:class:`pipeline.schema.SchemaError` naming the file) inputs that do not belong together: a segments
    file other than the one the retrieval recorded (its SHA-256 in the ``stucco.inputs`` metadata,
    docs/tables.md), or diagnostics that lack a run of the segments table or come from another tracking than the
    segments' (the parameters, seed and contacts the segments record of it). Scoring them would pair FMI and timings
    with the wrong run."""
    recorded = (schema.read_metadata(retrieval_path).get("inputs") or {}).get("segments") or {}
    digest = recorded.get("sha256")
    if digest and schema.file_digest(segments_path) != digest:
        raise schema.SchemaError(segments_path, None, None,
                                 f"not the segments table {retrieval_path} was made from (it recorded "
                                 f"{recorded.get('file', '?')} with SHA-256 {digest[:12]}…, this file differs)")
    if diagnostics is not None:
        missing = sorted(set(segments.column("run").to_pylist()) - set(diagnostics.column("run").to_pylist()))
        if missing:
            raise schema.SchemaError(diagnostics_path, None, None,
                                     f"no diagnostics for run {missing[0]!r} of {segments_path} "
                                     f"({len(missing)} run(s) missing); pass the diagnostics of the same tracking")
        # the tracking the segments record (pipeline.segment.tracking_record) against the diagnostics' own
        tracking = recorded_tracking(schema.read_metadata(segments_path))
        if tracking:
            own = tracking_record(schema.read_metadata(diagnostics_path))
            differs = [k for k in ("params", "seed", "contacts_sha256")
                       if tracking.get(k) is not None and own.get(k) is not None and tracking[k] != own[k]]
            if differs:
                raise schema.SchemaError(diagnostics_path, None, None,
                                         f"not the tracking {segments_path} was segmented from (its {differs[0]} "
                                         "differs); pass the diagnostics written beside those tracks")


def score_file(retrieval_path: str | Path, segments_path: str | Path, run_dir: str | Path, out_path: str | Path,
               *, seed: int, diagnostics_path: str | Path | None = None,
               amend: Callable[[pa.Table], pa.Table] | None = None) -> pa.Table:
    """The `score` stage on files: read and validate the retrieval, segments and (if given) track diagnostics
    tables, refuse inputs that do not belong together (:func:`check_score_inputs`), :func:`score` them and write
    the scores table (atomically, with provenance metadata: the run directory, every input file).

    ``amend``, if given, turns the scores table into the one written (``stucco evaluate`` adds its stage times,
    docs/evaluation.md). ``seed`` is the root seed. Returns the table written.
    """
    retrieval = read_retrieval(retrieval_path)
    segments = schema.read_segments(segments_path)
    diagnostics = schema.read_diagnostics(diagnostics_path) if diagnostics_path is not None else None
    check_score_inputs(retrieval_path, segments_path, segments, diagnostics, diagnostics_path)
    check_runs(segments_path, segments, run_files_by_name(run_dir))
    table = score(segments, retrieval, run_dir, diagnostics=diagnostics, segments_path=str(segments_path),
                  retrieval_path=str(retrieval_path))
    if amend is not None:
        table = amend(table)
    inputs = {"retrieval": str(retrieval_path), "segments": str(segments_path)}
    if diagnostics_path is not None:
        inputs["diagnostics"] = str(diagnostics_path)
    schema.write_table(table, out_path, stage="score", params={"runs": str(run_dir)}, seed=seed, inputs=inputs,
                       kind="scores")
    return table
