"""The ``isolate`` stage: collected run files -> the ``contacts`` table (docs/simulation.md, "`stucco isolate`").

:func:`isolate_runs` runs contact detection and isolation (the kernels of :mod:`pipeline.detection`, re-exported
here) on every action of the Parquet files written by :mod:`pipeline.collect`, with the ground-truth object id,
and measures the isolation error against the recorded true contact point.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline import schema
from pipeline.detection import (DetectionParams, IsolationParams, contact_forces, contact_window, fixed_column,
                                isolate_point, residual, step_in_contact, window_in_contact)
from pipeline.geometry import gripper_yaw, rotate
from pipeline.robot import load_robot, surface_points

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
    """

    table: object
    errors: np.ndarray
    n_runs: int
    n_actions: int
    n_contact: int
    n_unisolated: int

    def error_summary(self) -> dict[str, float | int | None]:
        """Median and 90th percentile of the isolation error (m), and the number of errors."""
        if len(self.errors) == 0:
            return {"median_m": None, "p90_m": None, "mean_m": None, "n": 0}
        return {"median_m": float(np.median(self.errors)), "p90_m": float(np.percentile(self.errors, 90)),
                "mean_m": float(np.mean(self.errors)), "n": int(len(self.errors))}


_SURFACES: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}


def isolation_surface(sdf, params: IsolationParams = IsolationParams()) -> tuple[np.ndarray, np.ndarray]:
    """The candidate contact points (Q, 2) and normals (Q, 2) of a gripper grid for isolation
    (:func:`pipeline.robot.surface_points` with ``params``' query), built once per process for each grid and
    query: they depend on nothing else."""
    key = (sdf.digest, params.n_query, params.radius, params.min_separation)
    if key not in _SURFACES:
        points, normals = surface_points(sdf, n_query=params.n_query, radius=params.radius,
                                         min_separation=params.min_separation)
        points.flags.writeable = normals.flags.writeable = False  # shared by every caller of this process
        _SURFACES[key] = (points, normals)
    return _SURFACES[key]


def _surface(params: IsolationParams) -> tuple[np.ndarray, np.ndarray]:
    return isolation_surface(load_robot(params.robot), params)


def isolate_run(table, points: np.ndarray, normals: np.ndarray, det: DetectionParams = DetectionParams(),
                iso: IsolationParams = IsolationParams()) -> tuple[dict[str, list], list[float], int]:
    """Detection and isolation for one collected run (a table written by :mod:`pipeline.collect`).

    Returns
    -------
    columns : dict of lists
        The contacts-table columns for the run's actions.
    errors : list of float, metres
        Isolation errors of the in-contact actions with a known true contact point.
    n_unisolated : int
    """
    n = table.num_rows
    run = table.column("run").to_pylist()
    step = np.asarray(table.column("step").to_numpy(), dtype=np.int64)
    ee_x = table.column("ee_x_m").to_numpy()
    ee_y = table.column("ee_y_m").to_numpy()
    cdx = table.column("contact_dx_m").to_numpy(zero_copy_only=False)
    cdy = table.column("contact_dy_m").to_numpy(zero_copy_only=False)
    oid = table.column("object_id").to_numpy()
    win = fixed_column(table, "win_wrench", (n, -1, 6))
    pose = fixed_column(table, "win_pose", (n, -1, 7))
    truth = fixed_column(table, "win_true_contact_m", (n, -1, 2))
    flags_all = step_in_contact(win, det)
    cols: dict[str, list] = {k: [] for k in ("run", "step", "ee_x_m", "ee_y_m", "in_contact", "contact_x_m",
                                             "contact_y_m", "dx_m", "dy_m", "object_id")}
    errors: list[float] = []
    unisolated = 0
    for i in range(n):
        flags = flags_all[i]
        idx = contact_window(flags, iso.max_wrenches, det.window)
        point = None
        if len(idx):
            last = idx[-1]
            yaw = gripper_yaw(pose[i, last, 3:])
            # express the forces in the gripper's frame (world axes when the gripper is not turned)
            f = rotate(win[i, idx, :2], yaw, inverse=True)
            k = isolate_point(f, win[i, idx, 5], points, normals, iso.friction_cone_deg)
            if k is None:
                unisolated += 1
            else:
                point = pose[i, last, :2] + rotate(points[k], yaw)
                t = truth[i, last]
                if np.all(np.isfinite(t)):
                    errors.append(float(np.hypot(*(point - t))))
        inc = point is not None
        cols["run"].append(run[i])
        cols["step"].append(int(step[i]))
        cols["ee_x_m"].append(float(ee_x[i]))
        cols["ee_y_m"].append(float(ee_y[i]))
        cols["in_contact"].append(inc)
        cols["contact_x_m"].append(float(point[0]) if inc else None)
        cols["contact_y_m"].append(float(point[1]) if inc else None)
        dxi, dyi = float(cdx[i]), float(cdy[i])
        if inc and not (math.isfinite(dxi) and math.isfinite(dyi)):
            dxi = dyi = 0.0  # contact found in the window but none of its steps moved while in contact
        cols["dx_m"].append(dxi if inc else None)
        cols["dy_m"].append(dyi if inc else None)
        cols["object_id"].append(int(oid[i]))
    return cols, errors, unisolated


def run_files(directory: str | Path) -> list[Path]:
    """Collected run files in ``directory`` (``*.parquet``, sorted)."""
    return sorted(Path(directory).glob("*.parquet"))


def isolate_runs(files: list[Path], det: DetectionParams = DetectionParams(),
                 iso: IsolationParams = IsolationParams()) -> IsolationResult:
    """Detection and isolation for collected run files -> contacts table and isolation errors.

    Parameters
    ----------
    files : list of Path
        Files written by :func:`pipeline.collect.collect` (any order; rows come out sorted by scene, seed,
        step).
    """
    points, normals = _surface(iso)
    allcols: dict[str, list] | None = None
    errors: list[float] = []
    unisolated = n_actions = 0
    tables = []
    for path in files:
        t = schema.read_run(path)
        key = (t.column("scene")[0].as_py(), t.column("seed")[0].as_py())
        tables.append((key, t))
    for _, t in sorted(tables, key=lambda kt: kt[0]):
        cols, errs, un = isolate_run(t, points, normals, det, iso)
        errors += errs
        unisolated += un
        n_actions += t.num_rows
        if allcols is None:
            allcols = cols
        else:
            for k in allcols:
                allcols[k] += cols[k]
    allcols = allcols or {k: [] for k in ("run", "step", "ee_x_m", "ee_y_m", "in_contact", "contact_x_m",
                                          "contact_y_m", "dx_m", "dy_m", "object_id")}
    contacts_schema = pa.schema([("run", pa.string()), ("step", pa.int64()), ("ee_x_m", pa.float64()),
                        ("ee_y_m", pa.float64()), ("in_contact", pa.bool_()), ("contact_x_m", pa.float64()),
                        ("contact_y_m", pa.float64()), ("dx_m", pa.float64()), ("dy_m", pa.float64()),
                        ("object_id", pa.int64())])
    table = pa.Table.from_pydict(allcols, schema=contacts_schema)
    n_contact = int(np.sum(table.column("in_contact").to_numpy(zero_copy_only=False)))
    return IsolationResult(table=table, errors=np.asarray(errors), n_runs=len(files), n_actions=n_actions,
                           n_contact=n_contact, n_unisolated=unisolated)


def params_dict(det: DetectionParams, iso: IsolationParams) -> dict:
    """Both parameter sets, JSON-friendly, for output metadata."""
    return {"detection": asdict(det), "isolation": asdict(iso)}


def isolate_file(files: list[Path], out_path: str | Path, *, seed: int, det: DetectionParams = DetectionParams(),
                 iso: IsolationParams = IsolationParams()) -> IsolationResult:
    """The `isolate` stage on files: detect and isolate the contacts of collected run files and write the contacts
    table (atomically), its metadata recording both parameter sets, the isolation error and the counts, and every
    run file as an input (by stem). Returns the :class:`IsolationResult`."""
    res = isolate_runs(files, det, iso)
    params = params_dict(det, iso)
    params["isolation_error"] = res.error_summary()
    params["counts"] = {"runs": res.n_runs, "actions": res.n_actions, "in_contact": res.n_contact,
                        "unisolated": res.n_unisolated}
    schema.write_table(res.table, out_path, stage="isolate", params=params, seed=seed,
                       inputs={f.stem: f for f in files}, kind="contacts")
    return res
