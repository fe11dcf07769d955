"""Blind object retrieval, pose estimation: segments of tracked contact points -> the target's planar pose.

The paper's §V-C and our plausible-set estimator, one role per module (docs/retrieval.md):

* :mod:`~pipeline.retrieve.params`: the paper's estimation parameters;
* :mod:`~pipeline.retrieve.model`: the target's primitive in a scene, model points and normals, pose error;
* :mod:`~pipeline.retrieve.icp`: planar ICP in SE(2) from many restarts;
* :mod:`~pipeline.retrieve.paper`: the paper's choice of segment and pose;
* :mod:`~pipeline.retrieve.plausible`: SE(2) hypotheses fitted to the shape, the contacts and the free space;
* :mod:`~pipeline.retrieve.estimators`: the estimators behind ``--estimator``, one call per run;
* :mod:`~pipeline.retrieve.runs`: collected run files and the per-run random streams;
* :mod:`~pipeline.retrieve.tables`: the ``retrieval`` and ``candidates`` tables;
* :mod:`~pipeline.retrieve.stage`: the ``retrieve`` stage, on tables and on files (:func:`retrieve_file`).

The primitive and the planar rotations live in :mod:`pipeline.geometry`; this package's public names include them.
"""
from pipeline.geometry import Primitive, apply_pose, primitive_of, rot2, rots2, wrap_angle
from pipeline.retrieve.estimators import (DEFAULT_ESTIMATOR, Segment, estimate, estimate_plausible, plausible_notes,
                                          retrieval_metadata)
from pipeline.retrieve.icp import IcpResult, icp_error, icp_restarts, initial_transforms
from pipeline.retrieve.model import model_normals, model_points, pose_error, project_to_outline, target_primitive
from pipeline.retrieve.paper import Choice, Estimate, choose_segment, confidence_notes, estimate_run, min_clearance
from pipeline.retrieve.params import RetrievalParams
from pipeline.retrieve.plausible import PlausibleParams, SegmentFit, fit_segment
from pipeline.retrieve.runs import RunInfo, check_runs, load_run, retrieval_rng, run_files_by_name
from pipeline.retrieve.stage import RetrieveConfig, final_segments_by_run, retrieve, retrieve_file
from pipeline.retrieve.tables import (CANDIDATES, CANDIDATES_COLUMNS, RETRIEVAL, RETRIEVAL_COLUMNS, candidates_table,
                                      read_retrieval, retrieval_table, validate_candidates, validate_retrieval)

__all__ = [
    "DEFAULT_ESTIMATOR", "Segment", "estimate", "estimate_plausible", "plausible_notes",
    "retrieval_metadata", "IcpResult", "icp_error", "icp_restarts", "initial_transforms",
    "Primitive", "apply_pose", "model_normals", "model_points", "pose_error", "primitive_of",
    "project_to_outline", "rot2", "rots2", "target_primitive", "wrap_angle", "Choice", "Estimate", "choose_segment",
    "confidence_notes", "estimate_run", "min_clearance", "RetrievalParams", "PlausibleParams", "SegmentFit",
    "fit_segment", "RunInfo", "load_run", "retrieval_rng", "run_files_by_name", "check_runs", "RetrieveConfig",
    "final_segments_by_run", "retrieve",
    "retrieve_file", "CANDIDATES", "CANDIDATES_COLUMNS", "RETRIEVAL", "RETRIEVAL_COLUMNS", "candidates_table",
    "read_retrieval", "retrieval_table", "validate_candidates", "validate_retrieval",
]
