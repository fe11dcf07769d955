"""The ``retrieve`` stage: segments of tracked contact points and the collected runs in, the target's planar pose,
the simulated grasp and the candidate poses out (:mod:`~pipeline.retrieve.stage`, :func:`retrieve_file`).

The pose estimators it runs live in :mod:`pipeline.estimators` (docs/estimators.md), the tables' specs in
:mod:`pipeline.schema.results` and their building in :mod:`pipeline.schema.retrieval`. This package re-exports the
names that the stages after it (score, evaluate, figures) use, so they need not know where each one lives.
"""
from pipeline.estimators.estimate import (
    DEFAULT_ESTIMATOR,
    Segment,
    estimate,
    estimate_plausible,
    plausible_notes,
    retrieval_metadata,
)
from pipeline.estimators.paper.choice import (
    Choice,
    Estimate,
    choose_segment,
    confidence_notes,
    estimate_run,
    min_clearance,
)
from pipeline.estimators.paper.icp import IcpResult, icp_error, icp_restarts, initial_transforms
from pipeline.estimators.params import RetrievalParams
from pipeline.estimators.plausible.fit import PlausibleParams, SegmentFit, fit_segment
from pipeline.estimators.run_info import RunInfo, check_runs, load_run, retrieval_rng, run_files_by_name
from pipeline.estimators.target_model import (
    model_normals,
    model_points,
    pose_error,
    project_to_outline,
    target_primitive,
)
from pipeline.geometry import Primitive, apply_pose, primitive_of, rot2, rots2, wrap_angle
from pipeline.retrieve.stage import RetrieveConfig, final_segments_by_run, retrieve, retrieve_file, tracking_robot
from pipeline.schema.retrieval import (
    CANDIDATES,
    CANDIDATES_COLUMNS,
    RETRIEVAL,
    RETRIEVAL_COLUMNS,
    candidates_table,
    read_retrieval,
    retrieval_table,
    validate_candidates,
    validate_retrieval,
)

__all__ = [
    "DEFAULT_ESTIMATOR", "Segment", "estimate", "estimate_plausible", "plausible_notes",
    "retrieval_metadata", "IcpResult", "icp_error", "icp_restarts", "initial_transforms",
    "Primitive", "apply_pose", "model_normals", "model_points", "pose_error", "primitive_of",
    "project_to_outline", "rot2", "rots2", "target_primitive", "wrap_angle", "Choice", "Estimate", "choose_segment",
    "confidence_notes", "estimate_run", "min_clearance", "RetrievalParams", "PlausibleParams", "SegmentFit",
    "fit_segment", "RunInfo", "load_run", "retrieval_rng", "run_files_by_name", "check_runs", "RetrieveConfig",
    "final_segments_by_run", "retrieve",
    "retrieve_file", "tracking_robot", "CANDIDATES", "CANDIDATES_COLUMNS", "RETRIEVAL", "RETRIEVAL_COLUMNS",
    "candidates_table",
    "read_retrieval", "retrieval_table", "validate_candidates", "validate_retrieval",
]
