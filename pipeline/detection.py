"""Contact detection from the wrench residual and isolation on the gripper surface: the kernels on arrays
(docs/simulation.md, "`stucco isolate`"; the stage that turns run files into the contacts table is
:mod:`pipeline.isolate`).

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
from dataclasses import dataclass

import numpy as np

from pipeline.constraints import Params
from pipeline.portable import argmin_tolerant

__all__ = ["DetectionParams", "IsolationParams", "scene_detection", "TORQUE_TIE_NM", "residual", "step_in_contact",
           "window_force",
           "window_in_contact", "contact_window", "isolate_point", "contact_forces", "fixed_column"]

#: Torque errors (N m) closer than this are a tie between surface points (the lower index wins): far above the
#: last-bit differences between CPUs (~1e-16 N m), far below the errors that separate points 1 mm apart.
TORQUE_TIE_NM = 1e-9


@dataclass(frozen=True)
class DetectionParams(Params):
    """Residual detector of the simulation (docs/simulation.md, "`stucco isolate`").

    Attributes
    ----------
    sigma_inv : tuple of 6 float
        Diagonal of S^-1 for (f_x, f_y, f_z [1/N^2], tau_x, tau_y, tau_z [1/(N m)^2]).
    threshold : float
        A sim step is in contact if the residual exceeds it.
    window : int
        An action is in contact if any of its last ``window`` sim steps is.
    min_force_n : float, N
        A detected contact whose in-plane force stays under this over the isolation window is not isolated (as a
        contact no surface point explains): too weak to be placed against a noisy wrench. 0 (the simulator's
        exact wrench): every detected contact is isolated.
    """

    sigma_inv: tuple[float, ...] = (1.0, 1.0, 1.0, 50.0, 50.0, 50.0)
    threshold: float = 1.0
    window: int = 5
    min_force_n: float = 0.0


def scene_detection(scene) -> DetectionParams:
    """The detector a scene's robot was tuned with: its ``[detection]`` (``scene.hardware.detection``) over the
    defaults (docs/simulation.md, "Tactile fingertips and a noisy wrench")."""
    return DetectionParams.from_dict(dict(scene.hardware.detection))


@dataclass(frozen=True)
class IsolationParams(Params):
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


def contact_forces(table, det: DetectionParams = DetectionParams(), iso: IsolationParams = IsolationParams()
                   ) -> np.ndarray:
    """The contact force each action of a collected run (``sim_run`` table) met, N, shape (K,): the largest
    in-plane magnitude of the sensed wrench over the sim steps isolation uses (:func:`contact_window`); NaN where
    no contact was detected. How hard the touched object resisted (docs/estimators.md, "Which segment resisted")."""
    n = table.num_rows
    win = fixed_column(table, "win_wrench", (n, -1, 6))
    flags = step_in_contact(win, det)  # every row's at once: per row it costs five times as much
    return np.array([_flagged_force(win[i], flags[i], det, iso) for i in range(n)], dtype=np.float64).reshape(n)


def window_force(win: np.ndarray, det: DetectionParams = DetectionParams(),
                 iso: IsolationParams = IsolationParams()) -> float:
    """The contact force one action met, N: the largest in-plane magnitude of its sensed wrenches ``win`` (S, 6)
    over the sim steps isolation uses (:func:`contact_window`); NaN where no contact was detected. What a policy
    reads of the action it just made (:meth:`pipeline.policies.ScriptedPolicy.observe`), as the later stages read
    it from the run (:func:`contact_forces`)."""
    win = np.asarray(win, dtype=np.float64).reshape(-1, 6)
    return _flagged_force(win, step_in_contact(win, det), det, iso)


def _flagged_force(win: np.ndarray, flags: np.ndarray, det: DetectionParams, iso: IsolationParams) -> float:
    """:func:`window_force` of one action's wrenches (S, 6) given their contact flags (S,)."""
    idx = contact_window(flags, iso.max_wrenches, det.window)
    return float(np.max(np.hypot(win[idx, 0], win[idx, 1]))) if len(idx) else math.nan


def fixed_column(table, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """A (nested) fixed-size-list column as a float array of ``shape``."""
    col = table.column(name).combine_chunks()
    while hasattr(col, "flatten") and hasattr(col.type, "list_size"):
        col = col.flatten()
    return np.asarray(col.to_numpy(zero_copy_only=False), dtype=np.float64).reshape(shape)
