"""Detection and isolation of one collected run: its table -> the contacts table's columns (paper §IV-A, §IV-B).

The kernels are in :mod:`pipeline.detection`; the ``isolate`` stage (:mod:`pipeline.isolate`) runs this on every
run file, and the estimators that re-isolate a run's contacts at their own steps call it directly.
"""
from __future__ import annotations

import math

import numpy as np

from pipeline.detection import (
    DetectionParams,
    IsolationParams,
    contact_forces,
    contact_window,
    fixed_column,
    isolate_point,
    step_in_contact,
)
from pipeline.geometry import gripper_yaw, rotate
from pipeline.robot import surface_points

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


def isolate_run(table, points: np.ndarray, normals: np.ndarray, det: DetectionParams = DetectionParams(),
                iso: IsolationParams = IsolationParams()) -> tuple[dict[str, list], list[float], int]:
    """Detection and isolation for one collected run (a table written by :mod:`pipeline.collect`).

    A run with fingertip sensors (its ``pad_*`` columns) takes the points of the pads that fired first, one row
    each, and isolates from the wrench only the actions where none fired (paper §V-E's order), so an action may
    give several rows; the ``sensor`` column says which sensor gave each (-1: the wrench).

    Returns
    -------
    columns : dict of lists
        The contacts-table columns for the run's actions (``sensor`` only for a run with fingertips).
    errors : list of float, metres
        Isolation errors of the wrench-isolated in-contact actions with a known true contact point.
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
    start_x = table.column("ee_start_x_m").to_numpy()
    start_y = table.column("ee_start_y_m").to_numpy()
    force = contact_forces(table, det, iso)
    pads = _pad_arrays(table, n)
    names = ["run", "step", "ee_x_m", "ee_y_m", "in_contact", "contact_x_m", "contact_y_m", "dx_m", "dy_m",
             "object_id", "ee_start_x_m", "ee_start_y_m", "force_n"] + (["sensor"] if pads is not None else [])
    cols: dict[str, list] = {k: [] for k in names}
    errors: list[float] = []
    unisolated = 0
    for i in range(n):
        # (point, dx, object id, force N, sensor) of each contact of the action
        found: list[tuple[np.ndarray, tuple[float, float], int, float, int]] = []
        if pads is not None:
            point, pdx, pobj, pforce = (a[i] for a in pads)
            for j in np.flatnonzero(np.isfinite(point[:, 0])):
                found.append((point[j], (float(pdx[j, 0]), float(pdx[j, 1])), int(pobj[j]), float(pforce[j]),
                              int(j)))
        flags = flags_all[i]
        idx = contact_window(flags, iso.max_wrenches, det.window) if not found else ()
        if len(idx) and not force[i] >= det.min_force_n:  # too weak to place against the wrench's noise
            unisolated += 1
        elif len(idx):
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
                dxi, dyi = float(cdx[i]), float(cdy[i])
                if not (math.isfinite(dxi) and math.isfinite(dyi)):
                    dxi = dyi = 0.0  # contact found in the window but none of its steps moved while in contact
                found.append((point, (dxi, dyi), int(oid[i]), float(force[i]), -1))
        for point, (dxi, dyi), obj, f_n, sensor in found or [(None, (None, None), int(oid[i]), math.nan, None)]:
            inc = point is not None
            cols["run"].append(run[i])
            cols["step"].append(int(step[i]))
            cols["ee_x_m"].append(float(ee_x[i]))
            cols["ee_y_m"].append(float(ee_y[i]))
            cols["in_contact"].append(inc)
            cols["contact_x_m"].append(float(point[0]) if inc else None)
            cols["contact_y_m"].append(float(point[1]) if inc else None)
            cols["dx_m"].append(dxi)
            cols["dy_m"].append(dyi)
            cols["object_id"].append(obj)
            cols["ee_start_x_m"].append(float(start_x[i]))
            cols["ee_start_y_m"].append(float(start_y[i]))
            f_free = float(force[i]) if not inc else f_n
            cols["force_n"].append(f_free if math.isfinite(f_free) else None)
            if pads is not None:
                cols["sensor"].append(sensor)
    return cols, errors, unisolated


def _pad_arrays(table, n: int) -> tuple[np.ndarray, ...] | None:
    """The fingertip sensors' columns of a run as arrays (point (n, P, 2), dx (n, P, 2), object (n, P), force
    (n, P)), or None for a run without them."""
    if "pad_contact_m" not in table.column_names:
        return None
    point = fixed_column(table, "pad_contact_m", (n, -1, 2))
    n_pads = point.shape[1]
    return (point, fixed_column(table, "pad_dx_m", (n, n_pads, 2)),
            fixed_column(table, "pad_object", (n, n_pads)).astype(np.int64),
            fixed_column(table, "pad_force_n", (n, n_pads)))
