"""The `track` stage: a contacts table in, a tracks table and a diagnostics table out.

Every run of the contacts table is tracked independently with its own random stream,
``SeedSequence([seed, run_key(run)])``, so results do not depend on the order of runs or on ``jobs``.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from pipeline import registry, schema
from pipeline.atomic import all_or_none
from pipeline.constraints import Params, plain
from pipeline.parallel import in_process, run_calls
from pipeline.robot import load_robot
from pipeline.seeds import run_rng
from pipeline.track.base import ContactTracker, StepResult

# Columns of the contacts table that the tracks table does not carry through (they are consumed or replaced).
_CONSUMED = {c.name for c in schema.CONTACTS_COLUMNS} - {"object_id"}
# Columns the tracks table computes; an extra contacts column with one of these names would be ambiguous.
_PRODUCED = {c.name for c in schema.TRACKS_COLUMNS} - {c.name for c in schema.CONTACTS_COLUMNS}


@dataclass(frozen=True)
class TrackConfig(Params):
    """What `stucco track` was asked to do; serialised into the output metadata."""

    method: str = "stucco"
    robot: str = "panda"
    params: dict[str, Any] = field(default_factory=dict)
    every_step: bool = False

    def __post_init__(self) -> None:
        registry.tracker(self.method)  # ValueError naming the registered methods
        super().__post_init__()


def build_tracker(method: str, params: dict | Any | None, robot, rng: np.random.Generator) -> ContactTracker:
    """A fresh tracker by name, from its registry entry (:mod:`pipeline.registry`).

    Parameters
    ----------
    method : str
        A registered tracking method.
    params : dict, parameter dataclass instance or None
        Overrides of the method's parameter fields (None = its defaults).
    robot : GridSDF or None
        The gripper grid (trackers that do not use it accept None).
    rng : numpy.random.Generator
        The run's stream; e.g. k-means draws its ``random_state`` from it, BIRCH, DBSCAN and GM-PHD draw nothing.

    Raises
    ------
    ValueError
        Unknown method or parameter, or a parameter out of range. TypeError if ``rng`` is not a Generator.
    """
    spec = registry.tracker(method)
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    return registry.resolve(spec.factory)(registry.build_params(spec, params), robot, rng)


def make_tracker(config: TrackConfig, robot, rng: np.random.Generator) -> ContactTracker:
    """Build a fresh tracker for one run."""
    return build_tracker(config.method, config.params, robot, rng)


def method_params(config: TrackConfig) -> dict[str, Any]:
    """The method's full parameter set (defaults filled in), recorded in the output metadata.

    Raises ValueError for an unknown or out-of-range parameter, before any run is tracked.
    """
    prm = registry.build_params(registry.tracker(config.method), config.params)
    return {} if prm is None else plain(prm)


#: (method, robot) pairs whose kernels this process has loaded or compiled.
_WARM: set[tuple[str, str]] = set()
#: The contact log replayed by :func:`warm_up`.
WARM_UP_LOG = Path(__file__).resolve().parents[2] / "data" / "contacts" / "FB-000.parquet"
#: A warm-up longer than this compiled the kernels (a cache load takes well under a second).
_COMPILE_NOTICE_S = 3.0


def warm_up(config: TrackConfig, robot) -> float:
    """Load, or on a fresh machine compile, the tracker's numba kernels in this process, before any timed update.

    A throwaway tracker (4 particles) replays the stored log ``data/contacts/FB-000.parquet`` (40 contacts: free
    space, contacts, resampling and replaced points), which reaches every kernel with the argument types of a real
    run. numba caches the compiled code on disk, so only a machine's first process pays the compilation
    (docs/evaluation.md, "Parallelism"); ``make setup`` pays it there. Trackers whose registry entry does not
    need ``"numba"`` skip it. A compilation says so in one line on stderr; none of it is booked as
    tracking time. Idempotent per process and (method, robot). Returns the seconds spent.
    """
    key = (config.method, config.robot)
    if "numba" not in registry.tracker(config.method).needs or key in _WARM:
        return 0.0
    t0 = time.perf_counter()
    (_, contacts), = schema.contacts_by_run(schema.read_contacts(WARM_UP_LOG))
    tracker = make_tracker(dataclasses.replace(config, params={"n_particles": 4}), robot, np.random.default_rng(0))
    for s in range(contacts.n_steps):
        tracker.update(*contacts.observation(s))
    tracker.labels()
    _WARM.add(key)
    seconds = time.perf_counter() - t0
    if seconds > _COMPILE_NOTICE_S:
        logging.getLogger("stucco").warning("compiled the tracker's numba kernels in %.0f s (once per machine; "
                                            "cached, not booked as tracking time)", seconds)
    return seconds


def warm_up_kernels() -> float:
    """:func:`warm_up` for STUCCO (the default method) on the default robot (``make setup`` calls it once per
    machine)."""
    config = TrackConfig()
    return warm_up(config, load_robot(config.robot))


def warm_up_kernels_but_contact() -> float:
    """Compile or load STUCCO's kernels other than the contact step's on the default robot
    (:meth:`~pipeline.track.soft.SoftTracker.warm_up_without_contacts`): ``make setup`` runs it in a second
    process beside :func:`warm_up_kernels`, which then loads them from numba's cache instead of compiling them
    after the contact step's kernel. Returns the seconds spent."""
    t0 = time.perf_counter()
    config = TrackConfig()
    tracker = make_tracker(dataclasses.replace(config, params={"n_particles": 4}), load_robot(config.robot),
                           np.random.default_rng(0))
    tracker.warm_up_without_contacts()
    tracker.labels()
    return time.perf_counter() - t0


@dataclass
class TrackResult:
    """Rows of one tracked run, as column arrays."""

    run: str
    tracks: dict[str, np.ndarray]
    source_rows: np.ndarray  # row of the contacts table each tracks row comes from (for carried columns)
    diagnostics: dict[str, np.ndarray]


def track_run(run: str, contacts: schema.RunContacts, config: TrackConfig, robot, seed: int) -> TrackResult:
    """Replay one run through a fresh tracker.

    Returns the estimate after the last step (or after every step with ``config.every_step``) and per-step
    diagnostics. Point i of the tracker is the i-th contact row of the run, so its observation step, index within
    the step and source row are known without asking the tracker.
    """
    warm_up(config, robot)
    tracker = make_tracker(config, robot, run_rng(seed, run))
    n_steps = contacts.n_steps
    point_step: list[np.ndarray] = []
    point_index: list[np.ndarray] = []
    point_row: list[np.ndarray] = []
    out: dict[str, list] = {"step": [], "contact_index": [], "estimate_step": [], "x_m": [], "y_m": [],
                            "tracker_label": []}
    rows_out: list[np.ndarray] = []
    diag = {k: np.zeros(n_steps, dtype=t) for k, t in
            (("step", np.int64), ("in_contact", bool), ("n_contacts", np.int64), ("ess", np.float64),
             ("resampled", bool), ("n_replaced", np.int64), ("update_ms", np.float64))}
    for s in range(n_steps):
        x, dx, p = contacts.observation(s)
        t0 = time.perf_counter()
        info = tracker.update(x, dx, p)
        diag["update_ms"][s] = (time.perf_counter() - t0) * 1e3
        if not isinstance(info, StepResult):
            raise TypeError(f"{config.method}: update must return a StepResult (pipeline.track.base), got "
                            f"{type(info).__name__}")
        diag["step"][s] = contacts.step[s]
        diag["in_contact"][s] = contacts.in_contact[s]
        diag["n_contacts"][s] = 0 if dx is None else len(dx)
        diag["ess"][s] = info.ess
        diag["resampled"][s] = info.resampled
        diag["n_replaced"][s] = info.n_replaced
        if dx is not None:
            rows = contacts.rows(s)
            k = rows.stop - rows.start
            point_step.append(np.full(k, contacts.step[s], np.int64))
            point_index.append(np.arange(k, dtype=np.int64))
            point_row.append(contacts.row_index[rows])
        if (config.every_step or s == n_steps - 1) and point_step:
            pts = tracker.points_
            out["step"].append(np.concatenate(point_step))
            out["contact_index"].append(np.concatenate(point_index))
            out["estimate_step"].append(np.full(len(pts), contacts.step[s], np.int64))
            out["x_m"].append(pts[:, 0])
            out["y_m"].append(pts[:, 1])
            out["tracker_label"].append(np.asarray(tracker.labels(), np.int64))
            rows_out.append(np.concatenate(point_row))
    tracks = {k: (np.concatenate(v) if v else np.zeros(0)) for k, v in out.items()}
    for k in ("step", "contact_index", "estimate_step", "tracker_label"):
        tracks[k] = tracks[k].astype(np.int64)
    source = np.concatenate(rows_out) if rows_out else np.zeros(0, np.int64)
    return TrackResult(run, tracks, source, diag)


def _track_one(run: str, contacts: schema.RunContacts, config: TrackConfig, seed: int, robot=None) -> TrackResult:
    # In a worker process `robot` is None and the grid is read from its cache (a millisecond) rather than pickled
    # with every run; in this process it is loaded once for all runs.
    return track_run(run, contacts, config, robot if robot is not None else load_robot(config.robot), seed)


def track_table(table: pa.Table, config: TrackConfig, *, seed: int, jobs: int = 1,
                progress: Callable | None = None) -> tuple[pa.Table, pa.Table]:
    """Track every run of a validated contacts table.

    Parameters
    ----------
    table : pyarrow.Table
        A contacts table (see :data:`pipeline.schema.CONTACTS_COLUMNS`).
    config : TrackConfig
    seed : int
        Root seed.
    jobs : int
        Runs tracked in parallel processes.
    progress : callable, optional
        Wraps the iterable of finished runs (e.g. a tqdm factory taking ``total=``).

    Returns
    -------
    tracks, diagnostics : pyarrow.Table
        Rows in the order the runs first appear in the input.
    """
    clash = sorted(set(table.column_names) & _PRODUCED)
    if clash:
        raise ValueError(f"the contacts table has column(s) {', '.join(map(repr, clash))}, which the tracks table "
                         "writes itself; rename them")
    runs = schema.contacts_by_run(table)
    robot = load_robot(config.robot) if in_process(jobs, len(runs)) else None
    results = run_calls(_track_one, [(run, rc, config, seed, robot) for run, rc in runs], jobs)
    if progress is not None:
        results = progress(results, total=len(runs))
    results = list(results)
    return _tracks_table(table, results), _diagnostics_table(results)


def _tracks_table(contacts: pa.Table, results: list[TrackResult]) -> pa.Table:
    n = [len(r.tracks["step"]) for r in results]
    cols: dict[str, pa.Array] = {
        "run": pa.array(np.repeat([r.run for r in results], n).astype(object) if results else [], pa.string()),
    }
    for name, dtype in (("step", pa.int64()), ("contact_index", pa.int64()), ("estimate_step", pa.int64()),
                        ("x_m", pa.float64()), ("y_m", pa.float64()), ("tracker_label", pa.int64())):
        values = np.concatenate([r.tracks[name] for r in results]) if results else np.zeros(0)
        cols[name] = pa.array(values, dtype)
    source = np.concatenate([r.source_rows for r in results]).astype(np.int64) if results else np.zeros(0, np.int64)
    carried = [c for c in contacts.column_names if c not in _CONSUMED]
    taken = contacts.select(carried).take(pa.array(source)) if carried else None
    for c in carried:
        cols[c] = taken.column(c)
    return pa.table(cols)


def _diagnostics_table(results: list[TrackResult]) -> pa.Table:
    n = [len(r.diagnostics["step"]) for r in results]
    cols: dict[str, Any] = {"run": pa.array(np.repeat([r.run for r in results], n).astype(object)
                                            if results else [], pa.string())}
    for name in ("step", "in_contact", "n_contacts", "ess", "resampled", "n_replaced", "update_ms"):
        cols[name] = pa.array(np.concatenate([r.diagnostics[name] for r in results]) if results else [])
    return pa.table(cols)


def default_diagnostics_path(out_path: str | Path) -> Path:
    """Where the diagnostics side table of a tracks file goes by default: ``<name>.diagnostics.parquet``."""
    out_path = Path(out_path)
    return out_path.with_name(out_path.name.removesuffix(".parquet") + ".diagnostics.parquet")


def track_file(in_path, out_path, config: TrackConfig, *, seed: int, jobs: int = 1, diagnostics_path=None,
               progress: Callable | None = None) -> tuple[pa.Table, pa.Table]:
    """The `track` stage on files: read and validate a contacts table, track it, write the tracks table and its
    diagnostics side table (atomically, with provenance metadata). Returns both tables.

    Parameter errors (unknown method, robot or parameter) raise ValueError before anything is read; input errors
    raise :class:`pipeline.schema.SchemaError`.
    """
    grid = load_robot(config.robot)
    full_params = method_params(config)
    contacts = schema.read_contacts(in_path)
    try:
        tracks, diagnostics = track_table(contacts, config, seed=seed, jobs=jobs, progress=progress)
    except ValueError as e:  # a problem with this file's contents: say which file
        raise ValueError(f"{in_path}: {e}") from e
    meta = dict(method=config.method, robot=config.robot, robot_digest=grid.digest, every_step=config.every_step,
                **full_params)
    inputs = {"contacts": str(in_path)}
    # Both outputs or neither (pipeline/atomic.py). The diagnostics hold wall times, so unlike the tracks they
    # differ between two identical runs.
    with all_or_none([diagnostics_path or default_diagnostics_path(out_path), out_path]) as (diag_tmp, tracks_tmp):
        schema.write_table(diagnostics, diag_tmp, stage="track", params=meta, seed=seed, inputs=inputs,
                           kind="diagnostics")
        schema.write_table(tracks, tracks_tmp, stage="track", params=meta, seed=seed, inputs=inputs, kind="tracks")
    return tracks, diagnostics
