"""The ``retrieval`` and ``candidates`` tables: columns with units, validation, reading and building."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from pipeline import schema
from pipeline.schema.rules import MAX_SECONDS

__all__ = ["RETRIEVAL_COLUMNS", "CANDIDATES_COLUMNS", "RETRIEVAL", "CANDIDATES", "validate_retrieval",
           "validate_candidates", "read_retrieval", "retrieval_table", "candidates_table"]

_C = schema.Column
_RUN = _C("run", pa.string(), "", False, "Run id '<scene>/<seed>' (as in the contacts, tracks, segments tables).")

RETRIEVAL_COLUMNS: tuple[schema.Column, ...] = (
    _RUN,
    _C("scene", pa.string(), "", False, "Scene of the run."),
    _C("seed", pa.int64(), "", False, "Run seed."),
    _C("method", pa.string(), "", False, "Tracking method that produced the segments."),
    _C("estimator", pa.string(), "", False, "Pose estimator: plausible (shape, contacts and free space) or paper "
       "(the paper's ICP procedure); docs/retrieval.md."),
    _C("target", pa.string(), "", False, "Name of the target object."),
    _C("x_m", pa.float64(), "m", False, "Estimated target COM x (canonical under the target's symmetry).",
       finite=True),
    _C("y_m", pa.float64(), "m", False, "Estimated target COM y.", finite=True),
    _C("yaw_rad", pa.float64(), "rad", False, "Estimated target yaw: [-pi/2, pi/2) for a box, 0 for a can.",
       finite=True),
    _C("segment", pa.int64(), "", False, "Chosen segment (-1: none, the segmentation was empty).", minimum=-1),
    _C("n_points", pa.int64(), "", False, "Tracked points in the chosen segment.", minimum=0),
    _C("n_segments", pa.int64(), "", False, "Segments in the run's final segmentation.", minimum=0),
    _C("position_var_m2", pa.float64(), "m^2", True,
       "Unbiased variance (x + y) of the chosen segment's restart positions (those within agreement_tolerance "
       "of its best ICP error); null if undefined.", minimum=0.0),
    _C("icp_rmse_m", pa.float64(), "m", True, "ICP error of the chosen pose; null without points.", minimum=0.0),
    _C("penetration_m", pa.float64(), "m", False,
       "Deepest penetration of the chosen pose into a visited gripper pose (0: none).", finite=True, minimum=0.0),
    _C("low_confidence", pa.bool_(), "", False, "The estimate has a reason not to be trusted (see notes)."),
    _C("notes", pa.string(), "", False, "Comma-separated low-confidence reasons (no_points, few_points, "
       "collinear, poor_fit, penetrating, no_valid_icp); empty when confident."),
    _C("true_x_m", pa.float64(), "m", False, "True target COM x after the last action.", finite=True),
    _C("true_y_m", pa.float64(), "m", False, "True target COM y after the last action.", finite=True),
    _C("true_yaw_rad", pa.float64(), "rad", False, "True target yaw after the last action.", finite=True),
    _C("position_error_m", pa.float64(), "m", False, "Distance between estimated and true primitive centres.",
       finite=True, minimum=0.0),
    _C("yaw_error_rad", pa.float64(), "rad", False, "Yaw error modulo the target's symmetry (pi box, any can).",
       finite=True, minimum=0.0),
    _C("grasp_success", pa.bool_(), "", True, "Simulated grasp at the estimate succeeded (null: not simulated)."),
    _C("grasp_outcome", pa.string(), "", False, "Why the grasp succeeded or failed ('' if not simulated)."),
    _C("icp_s", pa.float64(), "s", False, "Wall time of model sampling, ICP, scoring and choice.", finite=True,
       minimum=0.0, maximum=MAX_SECONDS),
    _C("grasp_s", pa.float64(), "s", True, "Wall time of the grasp simulation (null: not simulated).",
       finite=True, minimum=0.0, maximum=MAX_SECONDS),
)

CANDIDATES_COLUMNS: tuple[schema.Column, ...] = (
    _RUN,
    _C("segment", pa.int64(), "", False, "Segment the candidate was fitted to.", minimum=0),
    _C("restart", pa.int64(), "", False, "ICP restart 0..n_restarts-1 (paper); pose hypothesis (plausible).",
       minimum=0),
    _C("n_points", pa.int64(), "", False, "Points in the segment.", minimum=1),
    _C("x_m", pa.float64(), "m", False, "Candidate target COM x.", finite=True),
    _C("y_m", pa.float64(), "m", False, "Candidate target COM y.", finite=True),
    _C("yaw_rad", pa.float64(), "rad", False, "Candidate yaw in [-pi, pi) (not canonicalised).", finite=True),
    _C("icp_rmse_m", pa.float64(), "m", False,
       "ICP error of the segment's points (point-to-plane by default, see icp_error).", finite=True, minimum=0.0),
    _C("penetration_m", pa.float64(), "m", False, "Deepest penetration into a visited gripper pose (0: none).",
       finite=True, minimum=0.0),
    _C("valid", pa.bool_(), "", False, "Open3D returned a rotation about z (always, by construction) keeping the "
       "points within max_point_distance (median) of the model; invalid candidates keep their initial pose."),
    _C("position_var_m2", pa.float64(), "m^2", True, "The segment's restart position variance (repeated).",
       minimum=0.0),
    _C("rank", pa.int64(), "", False, "Rank within the segment by (excess penetration, ICP error); 0 = best.",
       minimum=0),
    _C("segment_chosen", pa.bool_(), "", False,
       "The run's chosen segment (lowest position variance among the segments that fit)."),
    _C("chosen", pa.bool_(), "", False, "This candidate is the run's estimate (before canonicalisation)."),
)


def _check_one_per_run(cols) -> None:
    _, counts = np.unique(cols.run_codes, return_counts=True)
    if (counts > 1).any():
        name = cols.run_names[int(np.flatnonzero(counts > 1)[0])]
        r = int(np.flatnonzero(cols.run_codes == cols.run_names.index(name))[1])
        cols.fail("run", r, f"run {name!r} appears more than once; expected one row per run")


RETRIEVAL = schema.TableSpec("retrieval", RETRIEVAL_COLUMNS,
                             rules=("One row per run.",
                                    "Timing columns (`icp_s`, `grasp_s`) are the only ones that differ between "
                                    "two identical runs."),
                             check=_check_one_per_run)
CANDIDATES = schema.TableSpec("candidates", CANDIDATES_COLUMNS,
                              rules=("One row per (run, segment, restart).",
                                     "Exactly one row per run with a non-empty segmentation has `chosen` true."))


def validate_retrieval(table: pa.Table, path: str | Path = "<table>") -> pa.Table:
    """Validate a retrieval table (one-line SchemaError)."""
    return schema.validate_spec(table, RETRIEVAL, path)


def validate_candidates(table: pa.Table, path: str | Path = "<table>") -> pa.Table:
    return schema.validate_spec(table, CANDIDATES, path)


def read_retrieval(path: str | Path) -> pa.Table:
    """Read and validate a retrieval table written by ``stucco retrieve``."""
    return validate_retrieval(schema.read_parquet(path), path)


def retrieval_table(rows: list[dict[str, Any]]) -> pa.Table:
    """Rows (dicts keyed by :data:`RETRIEVAL_COLUMNS`) -> validated retrieval table."""
    arrays = {c.name: pa.array([r[c.name] for r in rows], type=c.type) for c in RETRIEVAL_COLUMNS}
    return validate_retrieval(pa.table(arrays))


def candidates_table(parts: list[dict[str, np.ndarray]]) -> pa.Table:
    """Per-run candidate columns -> validated candidates table."""
    arrays = {}
    for c in CANDIDATES_COLUMNS:
        vals = [p[c.name] for p in parts if len(p[c.name])]
        data = np.concatenate(vals) if vals else np.zeros(0)
        if c.type == pa.string():
            arrays[c.name] = pa.array(data.tolist() if len(data) else [], type=pa.string())
        elif c.name == "position_var_m2":
            data = np.asarray(data, dtype=np.float64)
            arrays[c.name] = pa.array(data, type=pa.float64(), mask=~np.isfinite(data))
        else:
            arrays[c.name] = pa.array(np.asarray(data).astype(c.type.to_pandas_dtype()), type=c.type)
    return validate_candidates(pa.table(arrays))
