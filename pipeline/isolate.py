"""Contact detection from the wrench residual and isolation on the gripper surface (docs/simulation.md).

Kernels are pure functions on arrays; :func:`isolate_runs` turns the Parquet files written by
:mod:`pipeline.collect` into the ``contacts`` table of :mod:`pipeline.schema`, with the ground-truth object id,
and measures the isolation error against the recorded true contact point.

Detection: residual ``e = w^T S^-1 w`` with ``S^-1 = diag(1, 1, 1, 50, 50, 50)`` on the 6-D contact wrench of
every sim step; a step is in contact if ``e > 1``; an action is in contact if any of its last 5 sim steps is.

Isolation: the most recent in-contact step among the last 5 plus up to 3 immediately preceding in-contact
steps give up to 4 wrenches; a candidate surface point (from :func:`pipeline.robot.surface_points`, on the same
grid the tracker uses as pxpen) is valid if its outward normal is within 50 deg of ``-F_k`` for every wrench k
(dropping the oldest wrench while none is valid); among valid points the one whose torque
``tau_z = -r_y F_x + r_x F_y`` best matches the measured ``T_z`` (sum of absolute errors) is the contact.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline import schema
from pipeline.geometry import gripper_yaw, rotate
from pipeline.portable import argmin_tolerant
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
    "isolate_runs",
    "isolate_file",
    "IsolationResult",
]

#: Torque errors (N m) closer than this are a tie between surface points (the lower index wins): far above the
#: last-bit differences between CPUs (~1e-16 N m), far below the errors that separate points 1 mm apart.
TORQUE_TIE_NM = 1e-9


@dataclass(frozen=True)
class DetectionParams:
    """Residual detector of the simulation (docs/simulation.md, "`stucco isolate`").

    Attributes
    ----------
    sigma_inv : tuple of 6 float
        Diagonal of S^-1 for (f_x, f_y, f_z [1/N^2], tau_x, tau_y, tau_z [1/(N m)^2]).
    threshold : float
        A sim step is in contact if the residual exceeds it.
    window : int
        An action is in contact if any of its last ``window`` sim steps is.
    """

    sigma_inv: tuple[float, ...] = (1.0, 1.0, 1.0, 50.0, 50.0, 50.0)
    threshold: float = 1.0
    window: int = 5


@dataclass(frozen=True)
class IsolationParams:
    """Brute-force isolation over surface points (docs/simulation.md, "`stucco isolate`").

    Attributes
    ----------
    friction_cone_deg : float
        Maximum angle between a candidate's outward normal and the reversed contact force.
    max_wrenches : int
        Most recent in-contact wrenches used (the latest plus up to ``max_wrenches - 1`` preceding ones).
    n_query, radius, min_separation
        Arguments of :func:`pipeline.robot.surface_points` (100 query points on a 0.115 m circle, 5 mm apart).
    robot : str
        Robot grid for :func:`pipeline.robot.load_robot`.
    """

    friction_cone_deg: float = 50.0
    max_wrenches: int = 4
    n_query: int = 100
    radius: float = 0.115
    min_separation: float = 0.005
    robot: str = "panda"


# ---------------------------------------------------------------------------------------------------------------
# Detection kernels
# ---------------------------------------------------------------------------------------------------------------


def residual(w: np.ndarray, sigma_inv: tuple[float, ...] = DetectionParams.sigma_inv) -> np.ndarray:
    """Residual ``w^T S^-1 w`` of wrenches.

    Parameters
    ----------
    w : ndarray, shape (..., 6), N and N m
    sigma_inv : 6 floats, the diagonal of S^-1

    Returns
    -------
    ndarray, shape (...)
        NaN where the wrench is NaN (not computed).
    """
    w = np.asarray(w, dtype=np.float64)
    # Element-wise and summed in a fixed order (no einsum/BLAS): a residual near the threshold is a decision.
    return np.sum(w * np.asarray(sigma_inv, dtype=np.float64) * w, axis=-1)


def step_in_contact(w: np.ndarray, params: DetectionParams = DetectionParams()) -> np.ndarray:
    """bool (...): per-sim-step contact flags ``residual(w) > threshold`` (NaN wrenches are not in contact)."""
    e = residual(w, params.sigma_inv)
    with np.errstate(invalid="ignore"):
        return np.nan_to_num(e, nan=-np.inf) > params.threshold


def window_in_contact(flags: np.ndarray, window: int = DetectionParams.window) -> bool:
    """Whether any of the last ``window`` sim-step flags (shape (S,)) is set."""
    return bool(np.any(np.asarray(flags)[-window:]))


def contact_window(flags: np.ndarray, max_wrenches: int = IsolationParams.max_wrenches,
                   window: int = DetectionParams.window) -> np.ndarray:
    """Indices of the wrenches isolation uses, oldest first (the authors' get_last_contact_location;
    docs/simulation.md, "`stucco isolate`").

    The most recent in-contact step among the last ``window`` plus the immediately preceding steps while they
    are still in contact, at most ``max_wrenches`` in all.

    Parameters
    ----------
    flags : ndarray, shape (S,), bool
        Per-step contact flags of the steps available (at least the last ``window``).

    Returns
    -------
    ndarray, shape (K,), int64
        0 <= K <= max_wrenches indices into ``flags``; empty if none of the last ``window`` is in contact.
    """
    flags = np.asarray(flags, dtype=bool)
    n = len(flags)
    recent = np.flatnonzero(flags[max(0, n - window):])
    if len(recent) == 0:
        return np.zeros(0, dtype=np.int64)
    last = max(0, n - window) + int(recent[-1])
    first = last
    while first - 1 >= 0 and flags[first - 1] and last - (first - 1) < max_wrenches:
        first -= 1
    return np.arange(first, last + 1, dtype=np.int64)


# ---------------------------------------------------------------------------------------------------------------
# Isolation kernel
# ---------------------------------------------------------------------------------------------------------------


def isolate_point(forces: np.ndarray, torques: np.ndarray, points: np.ndarray, normals: np.ndarray,
                  cone_deg: float = IsolationParams.friction_cone_deg) -> int | None:
    """Index of the surface point that explains the wrenches best, or None.

    Parameters
    ----------
    forces : ndarray, shape (K, 2), N
        In-plane contact forces on the gripper, oldest first, in the frame of ``points``.
    torques : ndarray, shape (K,), N m
        Torques about the vertical axis through the gripper origin.
    points : ndarray, shape (P, 2), metres
        Candidate contact points relative to the gripper origin (world axes).
    normals : ndarray, shape (P, 2)
        Their outward unit normals.
    cone_deg : float
        Friction-cone half angle: valid iff angle(normal, -F_k) < cone_deg for every k.

    Returns
    -------
    int or None
        Point index. While no point is valid for all K wrenches the oldest wrench is dropped; None if no
        point is valid even for the latest one alone (or K = 0).
    """
    forces = np.asarray(forces, dtype=np.float64).reshape(-1, 2)
    torques = np.asarray(torques, dtype=np.float64).reshape(-1)
    cos_lim = math.cos(math.radians(cone_deg))
    fn = np.linalg.norm(forces, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        # cos of the angle between each normal and each -F_k: (P, K)
        dots = normals[:, None, 0] * forces[None, :, 0] + normals[:, None, 1] * forces[None, :, 1]
        cos = -dots / np.where(fn > 0, fn, np.nan)[None, :]
    ok = np.nan_to_num(cos, nan=-2.0) > cos_lim
    # expected torque of a contact at r: tau_z = -r_y F_x + r_x F_y  (P, K)
    tau = -points[:, 1:2] * forces[None, :, 0] + points[:, 0:1] * forces[None, :, 1]
    err = np.abs(tau - torques[None, :])
    for start in range(len(forces)):
        valid = ok[:, start:].all(axis=1)
        if valid.any():
            e = err[:, start:].sum(axis=1)
            e = np.where(valid, e, np.inf)
            # Neighbouring surface points can fit within rounding of each other: ties go to the lower index.
            return argmin_tolerant(e, TORQUE_TIE_NM)
    return None


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
    win = _fixed(table, "win_wrench", (n, -1, 6))
    pose = _fixed(table, "win_pose", (n, -1, 7))
    truth = _fixed(table, "win_true_contact_m", (n, -1, 2))
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


def _fixed(table, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """A (nested) fixed-size-list column as a float array of ``shape``."""
    col = table.column(name).combine_chunks()
    while hasattr(col, "flatten") and hasattr(col.type, "list_size"):
        col = col.flatten()
    return np.asarray(col.to_numpy(zero_copy_only=False), dtype=np.float64).reshape(shape)


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
