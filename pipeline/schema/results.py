"""Table specs of the results: ``retrieval`` and ``candidates`` (the retrieve stage) and ``scores`` (the score stage).

Described once here, as data, like the other stage tables (:mod:`pipeline.schema.specs` gathers them in
``TABLES``), so they are validated on write and read and ``docs/tables.md`` is generated from them.
:data:`NOTES` is every low-confidence reason an estimator writes into the ``notes`` column (docs/retrieval.md).
"""
from __future__ import annotations

import numpy as np
import pyarrow as pa

from pipeline.schema.columns import Column, ColumnViews, TableSpec
from pipeline.schema.rules import MAX_SECONDS

__all__ = ["NOTES", "RETRIEVAL_COLUMNS", "CANDIDATES_COLUMNS", "SCORES_COLUMNS", "RETRIEVAL", "CANDIDATES",
           "SCORES"]

#: Low-confidence reasons of a pose estimate: the paper's estimator (``no_points`` ... ``no_valid_icp``,
#: :func:`pipeline.estimators.paper.choice.confidence_notes`) and the plausible-set estimator's own (``no_free_space``,
#: ``ambiguous_yaw``, ``wide_set``, :func:`pipeline.estimators.estimate.plausible_notes`), and the active
#: protocol's (``no_segment``, ``wide_set``, :mod:`pipeline.probe.retrieval`, which also writes ``probes=N``).
NOTES: tuple[str, ...] = ("no_points", "few_points", "collinear", "poor_fit", "penetrating", "no_valid_icp",
                          "no_free_space", "ambiguous_yaw", "wide_set", "no_segment", "no_reachable_grasp")

_C = Column
_RUN = _C("run", pa.string(), "", False, "Run id '<scene>/<seed>' (as in the contacts, tracks, segments tables).")

RETRIEVAL_COLUMNS: tuple[Column, ...] = (
    _RUN,
    _C("scene", pa.string(), "", False, "Scene of the run."),
    _C("seed", pa.int64(), "", False, "Run seed."),
    _C("method", pa.string(), "", False, "Tracking method that produced the segments."),
    _C("estimator", pa.string(), "", False, "Pose estimator, a name of pipeline/registry.py: plausible (shape, "
       "contacts and free space) or paper (the paper's ICP procedure); docs/retrieval.md."),
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
    _C("notes", pa.string(), "", False, f"Comma-separated low-confidence reasons ({', '.join(NOTES)}; "
       "docs/retrieval.md); empty when confident. Runs of the active protocol start with probes=N, the probes "
       "made."),
    _C("true_x_m", pa.float64(), "m", True, "True target COM x after the last action (null: a robot's log).",
       finite=True),
    _C("true_y_m", pa.float64(), "m", True, "True target COM y after the last action (null: a robot's log).",
       finite=True),
    _C("true_yaw_rad", pa.float64(), "rad", True, "True target yaw after the last action (null: a robot's log).",
       finite=True),
    _C("position_error_m", pa.float64(), "m", True, "Distance between estimated and true primitive centres "
       "(null: a robot's log, no truth).",
       finite=True, minimum=0.0),
    _C("yaw_error_rad", pa.float64(), "rad", True, "Yaw error modulo the target's symmetry (pi box, any can; "
       "null: a robot's log).",
       finite=True, minimum=0.0),
    _C("grasp_success", pa.bool_(), "", True, "Simulated grasp at the estimate succeeded (null: not simulated)."),
    _C("grasp_outcome", pa.string(), "", False, "Why the grasp succeeded or failed ('' if not simulated); the "
       "active protocol's attempts numbered '1: ...; 2: ...'."),
    _C("grasp_attempts", pa.int64(), "", True, "Attempts of the active protocol's planned grasp, each re-planned "
       "after a felt miss (null: the one scripted grasp, or not simulated).", minimum=0),
    _C("grasp_success_any", pa.bool_(), "", True, "The planned grasp held the target within its attempts "
       "(null: the one scripted grasp, or not simulated); grasp_success is the first attempt."),
    _C("icp_s", pa.float64(), "s", False, "Wall time of model sampling, ICP, scoring and choice.", finite=True,
       minimum=0.0, maximum=MAX_SECONDS),
    _C("grasp_s", pa.float64(), "s", True, "Wall time of the grasp simulation (null: not simulated).",
       finite=True, minimum=0.0, maximum=MAX_SECONDS),
)

CANDIDATES_COLUMNS: tuple[Column, ...] = (
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
    _C("valid", pa.bool_(), "", False, "ICP kept the points within max_point_distance (median) of the model; "
       "invalid candidates keep their initial pose."),
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


RETRIEVAL = TableSpec("retrieval", RETRIEVAL_COLUMNS,
                             rules=("One row per run.",
                                    "Timing columns (`icp_s`, `grasp_s`) are the only ones that differ between "
                                    "two identical runs."),
                             check=_check_one_per_run)
CANDIDATES = TableSpec("candidates", CANDIDATES_COLUMNS,
                              rules=("One row per (run, segment, restart).",
                                     "Exactly one row per run with a non-empty segmentation has `chosen` true."))


SCORES_COLUMNS: tuple[Column, ...] = (
    _C("scene", pa.string(), "", False, "Scene of the run."),
    _C("seed", pa.int64(), "", False, "Run seed."),
    _C("method", pa.string(), "", False, "Tracking method."),
    _C("estimator", pa.string(), "", False, "Pose estimator of the retrieval (a name of pipeline/registry.py)."),
    _C("run", pa.string(), "", False, "Run id '<scene>/<seed>'."),
    _C("grasp_success", pa.bool_(), "", True, "Simulated grasp succeeded (null: grasp not simulated); the first "
       "attempt for the active protocol."),
    _C("grasp_attempts", pa.int64(), "", True, "Attempts of the active protocol's planned grasp (null: the one "
       "scripted grasp, or not simulated).", minimum=0),
    _C("grasp_success_any", pa.bool_(), "", True, "The planned grasp held the target within its attempts (null: "
       "the one scripted grasp, or not simulated)."),
    _C("fmi", pa.float64(), "", True, "Fowlkes-Mallows index of segments vs ground-truth objects over points with "
                                      "a known object; null if none.", minimum=0.0, maximum=1.0),
    _C("contact_error_cm", pa.float64(), "cm", True, "Mean |distance| of final tracked points to the nearest true "
                                                     "surface (objects and walls); null without points.",
       minimum=0.0),
    _C("position_error_cm", pa.float64(), "cm", False, "Distance between estimated and true target centres (the "
       "retrieval table's `position_error_m` x 100: lengths in cm, like `contact_error_cm`).", finite=True,
       minimum=0.0),
    _C("yaw_error_rad", pa.float64(), "rad", False, "Target yaw error modulo its symmetry.", finite=True,
       minimum=0.0),
    _C("low_confidence", pa.bool_(), "", False, "The pose estimate was flagged (see the retrieval table)."),
    _C("n_points", pa.int64(), "", False, "Final tracked points of the run.", minimum=0),
    _C("n_segments", pa.int64(), "", False, "Segments of the final segmentation.", minimum=0),
    _C("track_s", pa.float64(), "s", True, "Tracking time (sum of update times); null if no diagnostics.",
       minimum=0.0),
    _C("retrieve_s", pa.float64(), "s", False, "Pose estimation time.", finite=True, minimum=0.0),
    _C("grasp_s", pa.float64(), "s", True, "Grasp simulation time; null if not simulated.", minimum=0.0),
    _C("wall_s", pa.float64(), "s", False, "Sum of the known stage times of the run.", finite=True, minimum=0.0),
    _C("scene_sha256", pa.string(), "", True, "SHA-256 of the scene the run was collected in (its run file's "
       "`params.scene_sha256`): the report compares a scene with the paper only when this is the shipped scene's "
       "(null or absent in tables written before scores recorded it).", required=False),
)


def _check_one_per_key(cols: ColumnViews) -> None:
    keys = list(zip(*(cols.arrays[c].to_pylist() for c in ("scene", "seed", "method", "estimator"))))
    seen: dict[tuple, int] = {}
    for i, k in enumerate(keys):
        if k in seen:
            cols.fail("seed", i, f"(scene, seed, method, estimator) = {k} repeats row {seen[k]}; expected one row "
                                 f"per (scene, seed, method, estimator)")
        seen[k] = i


SCORES = TableSpec("scores", SCORES_COLUMNS, rules=("One row per (scene, seed, method, estimator).",),
                   check=_check_one_per_key)
