"""The ``isolate`` stage: collected run files -> the ``contacts`` table (docs/simulation.md, "`stucco isolate`").

:func:`isolate_runs` runs contact detection and isolation (the kernels of :mod:`pipeline.detection`, re-exported
here) on every action of the Parquet files written by :mod:`pipeline.collect`, with the ground-truth object id,
and measures the isolation error against the recorded true contact point.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline import schema
from pipeline.contact_isolation import isolate_run, isolation_surface
from pipeline.detection import (
    DetectionParams,
    IsolationParams,
    contact_forces,
    contact_window,
    isolate_point,
    residual,
    step_in_contact,
    window_in_contact,
)
from pipeline.robot import load_robot

__all__ = [
    "DetectionParams",
    "IsolationParams",
    "isolation_surface",
    "residual",
    "step_in_contact",
    "window_in_contact",
    "contact_window",
    "isolate_point",
    "contact_forces",
    "isolate_run",
    "isolate_runs",
    "isolate_file",
    "detection_of",
    "IsolationResult",
]

# ---------------------------------------------------------------------------------------------------------------
# Runs -> contacts table
# ---------------------------------------------------------------------------------------------------------------


@dataclass
class IsolationResult:
    """Output of :func:`isolate_runs`.

    Attributes
    ----------
    table : pyarrow.Table
        The contacts table (one row per action).
    errors : ndarray, shape (C,), metres
        Isolation error of every in-contact action whose true contact point is known.
    n_runs, n_actions, n_contact, n_unisolated : int
        Runs, actions, in-contact actions, in-contact actions where isolation found no point (recorded as
        not in contact).
    detection : DetectionParams or None
        The detector of every run (None: the runs were collected with different ones).
    root_seeds : tuple of int
        The distinct root seeds the runs record they were collected with (``stucco.seed``), sorted.
    """

    table: object
    errors: np.ndarray
    n_runs: int
    n_actions: int
    n_contact: int
    n_unisolated: int
    detection: DetectionParams | None = None
    root_seeds: tuple[int, ...] = ()

    def error_summary(self) -> dict[str, float | int | None]:
        """Median and 90th percentile of the isolation error (m), and the number of errors."""
        if len(self.errors) == 0:
            return {"median_m": None, "p90_m": None, "mean_m": None, "n": 0}
        return {"median_m": float(np.median(self.errors)), "p90_m": float(np.percentile(self.errors, 90)),
                "mean_m": float(np.mean(self.errors)), "n": int(len(self.errors))}


def run_files(directory: str | Path) -> list[Path]:
    """Collected run files in ``directory`` (``*.parquet``, sorted)."""
    return sorted(Path(directory).glob("*.parquet"))


def isolate_runs(files: list[Path], det: DetectionParams | None = None,
                 iso: IsolationParams = IsolationParams()) -> IsolationResult:
    """Detection and isolation for collected run files -> contacts table and isolation errors.

    Parameters
    ----------
    files : list of Path
        Files written by :func:`pipeline.collect.collect` (any order; rows come out sorted by scene, seed,
        step).
    det : DetectionParams, optional
        The detector for every run; None: each run's own, as its metadata records it (the scene's
        ``[detection]``, docs/simulation.md).
    """
    points, normals = isolation_surface(load_robot(iso.robot), iso)
    allcols: dict[str, list] | None = None
    errors: list[float] = []
    unisolated = n_actions = 0
    tables = []
    seeds: set[int] = set()
    for path in files:
        t, meta = schema.read_run_and_metadata(path)
        if isinstance(meta.get("seed"), int):
            seeds.add(meta["seed"])
        key = (t.column("scene")[0].as_py(), t.column("seed")[0].as_py())
        tables.append((key, t, det or detection_of(meta)))
    per_run = []
    for _, t, run_det in sorted(tables, key=lambda kt: kt[0]):
        cols, errs, un = isolate_run(t, points, normals, run_det, iso)
        errors += errs
        unisolated += un
        n_actions += t.num_rows
        per_run.append(cols)
    # the sensor column when any run has fingertips (-1, the wrench, for the rows of runs without)
    sensors = any("sensor" in cols for cols in per_run)
    for cols in per_run:
        if sensors and "sensor" not in cols:
            cols["sensor"] = [-1 if inc else None for inc in cols["in_contact"]]
        if allcols is None:
            allcols = cols
        else:
            for k in allcols:
                allcols[k] += cols[k]
    # every column of the contacts table's spec, in its order (schema.CONTACTS_COLUMNS: one list of them)
    contacts_schema = pa.schema([(c.name, c.type) for c in schema.CONTACTS_COLUMNS
                                 if c.name != "sensor" or sensors])
    allcols = allcols or {name: [] for name in contacts_schema.names}
    table = pa.Table.from_pydict(allcols, schema=contacts_schema)
    # actions in contact (an action with two fingertip contacts has two rows)
    n_contact = len({(r, s) for r, s, inc in zip(allcols["run"], allcols["step"], allcols["in_contact"]) if inc})
    used = list(dict.fromkeys(d for _, _, d in tables)) or [det or DetectionParams()]
    return IsolationResult(table=table, errors=np.asarray(errors), n_runs=len(files), n_actions=n_actions,
                           n_contact=n_contact, n_unisolated=unisolated, detection=used[0] if len(used) == 1 else None,
                           root_seeds=tuple(sorted(seeds)))


def detection_of(meta: dict) -> DetectionParams:
    """The detector a run file's decoded metadata (:func:`pipeline.schema.read_metadata`) records; the defaults
    if absent."""
    rec = (meta.get("params") or {}).get("detection") or {}
    return DetectionParams.from_dict(rec)  # (a JSON list becomes the tuple field it was)


def params_dict(det: DetectionParams | None, iso: IsolationParams) -> dict:
    """Both parameter sets, JSON-friendly, for output metadata (``detection`` "per run" when each run's own)."""
    return {"detection": det.to_dict() if det is not None else "per run", "isolation": iso.to_dict()}


def isolate_file(files: list[Path], out_path: str | Path, *, seed: int, det: DetectionParams | None = None,
                 iso: IsolationParams = IsolationParams()) -> IsolationResult:
    """The `isolate` stage on files: detect and isolate the contacts of collected run files and write the contacts
    table (atomically), its metadata recording both parameter sets, the isolation error and the counts, and every
    run file as an input (by stem). Isolating draws nothing: the table's seed is the runs' root seed (``seed``, the
    command's, only for runs that record none); runs of different root seeds are refused (ValueError), as every
    later stage would refuse some of them. Returns the :class:`IsolationResult`."""
    res = isolate_runs(files, det, iso)
    if len(res.root_seeds) > 1:
        raise ValueError(f"the runs were collected with root seeds {', '.join(map(str, res.root_seeds))}: isolate "
                         "each root seed's runs apart")
    params = params_dict(res.detection, iso)
    params["isolation_error"] = res.error_summary()
    params["counts"] = {"runs": res.n_runs, "actions": res.n_actions, "in_contact": res.n_contact,
                        "unisolated": res.n_unisolated}
    schema.write_table(res.table, out_path, stage="isolate", params=params,
                       seed=res.root_seeds[0] if res.root_seeds else seed,
                       inputs={f.stem: f for f in files}, kind="contacts")
    return res
