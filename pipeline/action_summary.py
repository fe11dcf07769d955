"""What the ``sim_run`` table keeps of one action, from its sim steps (:class:`pipeline.sim.world.ActionTrace`), and
the discard rule of training runs (docs/simulation.md, "World, gripper, stepping" and "`stucco collect`"). The
collect stage (:mod:`pipeline.collect`) builds a run's rows with these.
"""
from __future__ import annotations

import numpy as np

from pipeline.detection import DetectionParams, residual, step_in_contact, window_in_contact
from pipeline.geometry import gripper_yaw
from pipeline.sim import NO_CONTACT
from pipeline.sim.world import ActionTrace

__all__ = ["WINDOW_STEPS", "BUCKET", "BUCKET_SAMPLE", "MIN_REP_FORCE_N", "MAX_NO_CONTACT_FRACTION", "action_label",
           "representative_force", "summarize_action", "step_residual_max", "discard_reason"]

#: Sim steps of each action kept for detection/isolation: the detector looks at the last 5, isolation takes the
#: latest in-contact one among them plus up to 3 preceding in-contact steps, so it can reach 8 steps back.
WINDOW_STEPS = 8
#: Observations per bucket for labels and the representative force, and the observation used in a bucket.
BUCKET = 20
BUCKET_SAMPLE = 5
#: Discard rule thresholds (docs/simulation.md, "`stucco collect`").
MIN_REP_FORCE_N = 0.1
MAX_NO_CONTACT_FRACTION = 0.95


def action_label(ids: np.ndarray, bucket: int = BUCKET) -> int:
    """Ground-truth object of an action (docs/simulation.md, "World, gripper, stepping").

    Parameters
    ----------
    ids : ndarray, shape (S,), int
        Per sim step, the (last-found = highest) object id in contact, NO_CONTACT = -1 otherwise.

    Returns
    -------
    int
        Mode over the ceil(S / bucket) buckets of each bucket's id (that of its last step with contact, -1 if
        none), ties broken toward the smallest value (``scipy.stats.mode``), so -1 wins any tie.
    """
    ids = np.asarray(ids)
    labels = []
    for b in range(0, len(ids), bucket):
        chunk = ids[b:b + bucket]
        hit = np.flatnonzero(chunk != NO_CONTACT)
        labels.append(int(chunk[hit[-1]]) if len(hit) else NO_CONTACT)
    vals, counts = np.unique(np.asarray(labels), return_counts=True)
    return int(vals[np.argmax(counts)])  # unique sorts ascending and argmax takes the first maximum


def representative_force(wrench: np.ndarray, bucket: int = BUCKET, sample: int = BUCKET_SAMPLE) -> np.ndarray:
    """Representative in-plane contact force of an action (MEDIAN_OVER_MINI_STEPS; docs/simulation.md, "World,
    gripper, stepping").

    Parameters
    ----------
    wrench : ndarray, shape (S, 6)

    Returns
    -------
    ndarray, shape (2,), N
        The force (f_x, f_y) sampled at index ``sample`` of each bucket, of the bucket with the median
        magnitude (upper median for an even count); NaN if the wrench was not computed.
    """
    idx = np.arange(sample, len(wrench), bucket)
    f = np.asarray(wrench)[idx, :2]
    mag = np.linalg.norm(f, axis=1)
    if not np.all(np.isfinite(mag)):
        return np.full(2, np.nan)
    return f[np.argsort(mag, kind="stable")[len(mag) // 2]]


def summarize_action(trace: ActionTrace, det: DetectionParams = DetectionParams()) -> dict:
    """Everything the sim_run table keeps of one action (columns not involving the policy or objects)."""
    flags = step_in_contact(trace.wrench, det)
    in_contact = window_in_contact(flags, det.window)
    steps = np.diff(np.vstack([trace.start[None, :2], trace.pos[:, :2]]), axis=0)
    cdx = steps[flags].sum(axis=0) if in_contact else None
    res = step_residual_max(trace.wrench, det)
    w = slice(len(trace.pos) - WINDOW_STEPS, None)
    has = np.flatnonzero(trace.truth_first != NO_CONTACT)
    true_pt = trace.truth_xy[has[-1]] if len(has) else None
    end = trace.pos[-1]
    return {
        "ee_start_x_m": float(trace.start[0]), "ee_start_y_m": float(trace.start[1]),
        "ee_x_m": float(end[0]), "ee_y_m": float(end[1]), "ee_z_m": float(end[2]),
        "ee_yaw_rad": gripper_yaw(trace.quat[-1]),
        "exec_dx_m": float(end[0] - trace.start[0]), "exec_dy_m": float(end[1] - trace.start[1]),
        "in_contact": in_contact,
        "contact_dx_m": None if cdx is None else float(cdx[0]),
        "contact_dy_m": None if cdx is None else float(cdx[1]),
        "residual_max": res,
        "win_wrench": trace.wrench[w], "win_pose": np.hstack([trace.pos[w], trace.quat[w]]),
        "win_true_contact_m": trace.truth_xy[w], "win_true_object": trace.truth_first[w],
        "true_contact_x_m": None if true_pt is None else float(true_pt[0]),
        "true_contact_y_m": None if true_pt is None else float(true_pt[1]),
        "object_id": action_label(trace.truth_last),
        "force_rep": representative_force(trace.wrench),
        **({} if trace.pads is None else {"pad_contact_m": trace.pads["point"], "pad_dx_m": trace.pads["dx"],
                                          "pad_object": trace.pads["object"], "pad_force_n": trace.pads["force"]}),
    }


def step_residual_max(wrench: np.ndarray, det: DetectionParams) -> float:
    """Largest residual over the sim steps of an action (NaN if the wrench was not computed)."""
    e = residual(wrench, det.sigma_inv)
    return float(np.max(e)) if np.all(np.isfinite(e)) else float("nan")


def discard_reason(object_id: np.ndarray, force_rep: np.ndarray) -> str | None:
    """Why a training run is discarded, or None to keep it (docs/simulation.md, "`stucco collect`").

    Labels of actions whose representative force is below 0.1 N become -1 and one -1 is appended; the run
    is rejected with fewer than 2 distinct labels, more than 95 % of -1 labels, or fewer than 2 in-contact
    actions.

    Parameters
    ----------
    object_id : ndarray, shape (A,), int
    force_rep : ndarray, shape (A, 2), N
    """
    labels = np.asarray(object_id, dtype=np.int64).copy()
    mag = np.linalg.norm(np.asarray(force_rep, dtype=np.float64).reshape(-1, 2), axis=1)
    labels[~(mag >= MIN_REP_FORCE_N)] = NO_CONTACT
    labels = np.append(labels, NO_CONTACT)
    if len(np.unique(labels)) < 2:
        return "fewer than 2 distinct labels"
    if np.mean(labels == NO_CONTACT) > MAX_NO_CONTACT_FRACTION:
        return "in contact less than 5% of the time"
    if np.sum(labels != NO_CONTACT) < 2:
        return "fewer than 2 in-contact actions"
    return None
