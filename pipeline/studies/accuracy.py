"""``stucco bench accuracy``: every setting of the sweep on every (scene, seed) of the BOR tasks, timed.

Runs are collected and isolated once per (scene, seed) into ``DIR/runs`` and ``DIR/contacts`` with
:func:`pipeline.evaluate.prepare_run` (the same files as ``stucco evaluate``); every setting then tracks, segments,
retrieves and scores them in memory. Time per run (``compute_s``) = track + segment + ICP (the grasp simulation
stands in for the robot's motion, not for computation, and is reported apart as ``grasp_s``); docs/studies.md.

Every random stream comes from the stages' own derivations (collect: ``[root, scene, seed]``; track:
``[root, run_key(run)]``; retrieve: :func:`pipeline.estimators.run_info.retrieval_rng` of each estimator stream asked
for), so a setting's result does not depend on the order or the process it runs in. With several estimator
streams, each setting's segments are estimated once per stream and its grasp success is their mean
(docs/evaluation.md, "The estimator's own randomness").
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa
from tqdm import tqdm

from pipeline import registry, schema
from pipeline.estimators.estimate import needs_every_step
from pipeline.evaluate import EvalConfig, map_jobs, prepare_run, single_threaded
from pipeline.grasp import GraspParams
from pipeline.layout import partition
from pipeline.retrieve import PlausibleParams, RetrievalParams, RetrieveConfig, retrieve
from pipeline.robot import load_robot
from pipeline.score import score
from pipeline.seeds import check_stream
from pipeline.segment import segment_table, segmentation_params
from pipeline.studies.accuracy_settings import Setting
from pipeline.studies.tables import write_csv

__all__ = ["accuracy_bench"]


def _run_setting(runs: Path, contacts: pa.Table, s: Setting, root_seed: int,
                 streams: Sequence[int] = (0,)) -> list[dict[str, Any]]:
    """Track, segment, then retrieve (with the grasp) and score one (scene, seed) with one setting for each
    estimator stream; one row of ``accuracy.csv`` per stream (times in seconds)."""
    # Imported here: the trackers load numba's kernels, which only the processes that track need.
    from pipeline.track.stage import TrackConfig, track_table

    # The online paper estimator reads the estimate after every in-contact step (docs/estimators.md).
    config = TrackConfig(method=s.method, robot=s.robot, params=dict(s.params),
                         every_step=needs_every_step([s.estimator]))
    t0 = time.perf_counter()
    tracks, diagnostics = track_table(contacts, config, seed=root_seed, jobs=1)
    t1 = time.perf_counter()
    length, alpha = segmentation_params(s.method, dict(s.params))
    segments = segment_table(tracks, length=length, alpha=alpha, by="auto", method=s.method)
    t2 = time.perf_counter()
    # The sweep's hypotheses and free-space spacing are the plausible estimator's knobs.
    own = (PlausibleParams(n_hypotheses=s.hypotheses, free_resolution=s.free_resolution)
           if registry.resolve(registry.estimator(s.estimator).params) is PlausibleParams
           else dict(s.estimator_params) or None)
    track_s, segment_s = t1 - t0, t2 - t1
    rows = []
    for stream in streams:
        config = RetrieveConfig(method=s.method, estimator=s.estimator, estimator_params=own, grasp=True,
                                params=RetrievalParams(n_restarts=s.restarts, robot=s.robot),
                                grasp_params=GraspParams(), stream=stream)
        # the one run file: its directory holds every (scene, seed) of the sweep
        retrieval, _ = retrieve(segments, runs, config, root_seed=root_seed, jobs=1)
        table = score(segments, retrieval, runs, diagnostics=diagnostics).to_pylist()[0]
        rows.append(dict(setting=s.name, method=s.method, knob=s.knob, value=s.value, scene=table["scene"],
                         seed=table["seed"], stream=stream, fmi=table["fmi"],
                         contact_error_cm=table["contact_error_cm"], grasp_success=table["grasp_success"],
                         position_error_m=retrieval.column("position_error_m")[0].as_py(),  # scores: in cm
                         track_s=track_s, segment_s=segment_s,
                         icp_s=table["retrieve_s"], grasp_s=table["grasp_s"],
                         compute_s=track_s + segment_s + table["retrieve_s"]))
    return rows


def _bench_pair(out: Path, scene: str, seed: int, settings: list[Setting], root_seed: int,
                streams: Sequence[int] = (0,)) -> list[dict]:
    """Prepare one (scene, seed) and run every setting on it (each estimator stream), on one thread per
    library."""
    cfg = EvalConfig(root_seed=root_seed)
    prepare_run(out, scene, seed, cfg)
    runs = partition(out, "runs", scene, seed)
    contacts = schema.read_contacts(partition(out, "contacts", scene, seed))
    with single_threaded():
        return [row for s in settings for row in _run_setting(runs, contacts, s, root_seed, streams)]


def _warm_up(settings: list[Setting]) -> None:
    """Build every robot grid (cached on disk) and compile the kernels before any clock starts."""
    for spec in dict.fromkeys(s.robot for s in settings):
        load_robot(spec)


def accuracy_bench(out: str | Path, scenes: Sequence[str], seeds: Sequence[int], settings: list[Setting], *,
                   root_seed: int = 0, jobs: int = 1, progress: bool | None = None,
                   streams: Sequence[int] = (0,)) -> pa.Table:
    """Every setting on every (scene, seed); one row per (setting, scene, seed, estimator stream), also in
    ``out/accuracy.csv``. ``streams``: the estimators' random streams (distinct non-negative integers; 0 the
    default), each setting's pose estimated once per stream on the same segments.

    The first (scene, seed) is run once untimed in this process to compile the numba kernels (the timed rows
    then exclude compilation, which every long-running process pays once).
    """
    streams = tuple(dict.fromkeys(check_stream(k) for k in streams))
    if not streams:
        raise ValueError("streams: at least one estimator stream is needed")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    _warm_up(settings)
    pairs = [(out, sc, int(s), settings, root_seed, streams) for sc in scenes for s in seeds]
    if jobs <= 1:
        _bench_pair(*pairs[0])  # compile (numba) outside the timed rows
    with tqdm(total=len(pairs), desc="bench accuracy", unit="run", disable=progress) as bar:
        rows = [r for chunk in map_jobs(_bench_pair, pairs, jobs, bar) for r in chunk]
    order = {s.name: i for i, s in enumerate(settings)}
    rows.sort(key=lambda r: (order[r["setting"]], r["scene"], r["seed"], r["stream"]))
    table = pa.Table.from_pylist(rows)
    write_csv(table, out / "accuracy.csv")
    return table
