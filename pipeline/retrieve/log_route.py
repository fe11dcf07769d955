"""Retrieval from a robot's own log, no simulation: segments and the contacts table they were tracked from, the
target given by its shape (docs/retrieval.md, "Retrieval from a robot's log").

The gripper's trail in the contacts table is its free space, each step's contact point and in-contact
displacement are the log's own (:func:`pipeline.estimators.log_run.log_runs`); every registered estimator runs on
them as on a simulated run. The retrieval table's ground-truth columns and grasp columns are null: there is no
scene to simulate a grasp in, nor a true pose to compare with.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline import registry, schema
from pipeline.estimators.log_run import log_runs, parse_target
from pipeline.retrieve.stage import (
    RetrieveConfig,
    read_segments_for,
    retrieve_runs,
    write_retrieval_tables,
)
from pipeline.segment import recorded_tracking

__all__ = ["retrieve_log", "retrieve_log_file"]


def _check_segments_match(segments: pa.Table, contacts: pa.Table, segments_path: str, contacts_path: str) -> None:
    """ValueError (one line) when a run of the segments is not in the contacts table, or a segment's point was
    observed at a step the log does not have."""
    runs = np.asarray(contacts.column("run").to_pylist(), dtype=object)
    steps = np.asarray(contacts.column("step").to_numpy(zero_copy_only=False), dtype=np.int64)
    seg_runs = np.asarray(segments.column("run").to_pylist(), dtype=object)
    seg_steps = np.asarray(segments.column("step").to_numpy(zero_copy_only=False), dtype=np.int64)
    for run in dict.fromkeys(seg_runs):
        have = set(steps[runs == run].tolist())
        if not have:
            raise ValueError(f"{segments_path}: run {run!r} is not in the contacts table {contacts_path} "
                             f"(runs there: {', '.join(map(str, list(dict.fromkeys(runs))[:5]))})")
        missing = sorted(set(seg_steps[seg_runs == run].tolist()) - have)
        if missing:
            raise ValueError(f"{segments_path}: run {run!r} has points observed at step {missing[0]}, which "
                             f"{contacts_path} does not have: the segments were not tracked from this log")


def retrieve_log(segments: pa.Table, contacts: pa.Table, target: str, config: RetrieveConfig | None = None, *,
                 root_seed: int = 0, jobs: int = 1, progress: Callable | None = None,
                 segments_path: str = "<segments>", contacts_path: str = "<contacts>") -> tuple[pa.Table, pa.Table]:
    """The ``retrieve`` stage on a log: one retrieval row per run of ``contacts`` (its segments from
    ``segments``; a run without any is estimated as such), for the target spec ``target``
    (:func:`~pipeline.estimators.log_run.parse_target`). No grasp is simulated. Returns (retrieval, candidates)."""
    config = dataclasses.replace(config or RetrieveConfig(), grasp=False)
    if config.method is None:
        config = dataclasses.replace(config, method=registry.tracker_names()[0])
    prim, mass, grasp_scene = parse_target(target)
    _check_segments_match(segments, contacts, segments_path, contacts_path)
    infos = log_runs(contacts, prim, mass, grasp_scene)
    return retrieve_runs(list(infos.values()), segments, config, root_seed, jobs, progress)


def retrieve_log_file(segments_path: str | Path, contacts_path: str | Path, target: str, out_path: str | Path,
                      candidates_path: str | Path, config: RetrieveConfig, *, seed: int, jobs: int = 1,
                      progress: Callable | None = None) -> tuple[pa.Table, pa.Table]:
    """:func:`retrieve_log` on files (the contacts table Parquet or CSV), writing the candidates and retrieval
    tables both or neither, with the target spec, the segments and the contacts as provenance."""
    segments, config = read_segments_for(segments_path, config)
    contacts = schema.read_contacts(contacts_path)
    # the contacts table the segments were tracked from, byte for byte, when they record it (params.tracking)
    digest = recorded_tracking(schema.read_metadata(segments_path)).get("contacts_sha256")
    if digest and schema.file_digest(contacts_path) != digest:
        raise ValueError(f"{contacts_path}: not the contacts table {segments_path} was tracked from (it recorded "
                         f"SHA-256 {digest[:12]}…, this file differs)")
    config = dataclasses.replace(config, grasp=False)
    table, candidates = retrieve_log(segments, contacts, target, config, root_seed=seed, jobs=jobs, progress=progress,
                                     segments_path=str(segments_path), contacts_path=str(contacts_path))
    write_retrieval_tables(table, candidates, out_path, candidates_path, dict(config.metadata(), target=str(target)),
                           seed, {"segments": str(segments_path), "contacts": str(contacts_path)})
    return table, candidates
