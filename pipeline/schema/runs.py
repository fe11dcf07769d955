"""The ``sim_run`` table (one row per action of one collected run) as data, and its rule.

Written by ``stucco collect`` (docs/simulation.md), read by ``stucco isolate``, ``retrieve`` and ``score``.
Validated on write and on read like the stage tables, so a truncated, hand-edited or millimetre-scaled run
file is refused with one line naming the file, the column and the first bad row.
"""
from __future__ import annotations

import numpy as np
import pyarrow as pa

from pipeline.schema.columns import Column, ColumnViews, TableSpec
from pipeline.schema.rules import MAX_POSITION_M, MAX_STEP_DISPLACEMENT_M
from pipeline.schema.validate import check_steps_nondecreasing, first_row

__all__ = ["SIM_RUN_COLUMNS", "SIM_RUN", "MAX_WRENCH", "PAD_COLUMNS"]

#: Bound on every wrench component (N, N m) and representative force: a gripper pushing objects on a table
#: sees tens of newtons; beyond this the log is not a contact log (or its units are wrong).
MAX_WRENCH = 1e5

_F = pa.float64()
_I = pa.int64()
_POS = dict(finite=True, minimum=-MAX_POSITION_M, maximum=MAX_POSITION_M)
_STEP = dict(finite=True, minimum=-MAX_STEP_DISPLACEMENT_M, maximum=MAX_STEP_DISPLACEMENT_M)
_FORCE = dict(finite=True, minimum=-MAX_WRENCH, maximum=MAX_WRENCH)

SIM_RUN_COLUMNS: tuple[Column, ...] = (
    Column("run", pa.string(), "", False, "Run id '<scene>/<seed>'; one run per file."),
    Column("scene", pa.string(), "", False, "Scene name."),
    Column("seed", _I, "", False, "Run seed (the job's third SeedSequence entry).", minimum=0),
    Column("step", _I, "", False, "Action index, 0-based, strictly increasing.", minimum=0),
    Column("ee_start_x_m", _F, "m", False, "Gripper base x at the start of the action.", **_POS),
    Column("ee_start_y_m", _F, "m", False, "Gripper base y at the start of the action.", **_POS),
    Column("ee_x_m", _F, "m", False, "Gripper base x after the action.", **_POS),
    Column("ee_y_m", _F, "m", False, "Gripper base y after the action.", **_POS),
    Column("ee_z_m", _F, "m", False, "Gripper base z after the action.", **_POS),
    Column("ee_yaw_rad", _F, "rad", False, "In-plane rotation of the gripper from its fixed orientation, after "
                                          "the action.", finite=True),
    Column("cmd_ux", _F, "", False, "Commanded action x (noise included, clipped).", finite=True,
           minimum=-1.0, maximum=1.0),
    Column("cmd_uy", _F, "", False, "Commanded action y.", finite=True, minimum=-1.0, maximum=1.0),
    Column("cmd_dx_m", _F, "m", False, "Commanded displacement x = cmd_ux × action scale.", **_STEP),
    Column("cmd_dy_m", _F, "m", False, "Commanded displacement y.", **_STEP),
    Column("exec_dx_m", _F, "m", False, "Executed displacement x (after - start).", **_STEP),
    Column("exec_dy_m", _F, "m", False, "Executed displacement y.", **_STEP),
    Column("in_contact", pa.bool_(), "", False, "Detector verdict: residual > 1 at any of the action's last 5 "
                                               "sim steps (paper §IV-A)."),
    Column("contact_dx_m", _F, "m", True, "Sum of the gripper's per-sim-step x displacement over the in-contact "
                                          "sim steps; null when not in_contact.", **_STEP),
    Column("contact_dy_m", _F, "m", True, "Same for y.", **_STEP),
    Column("residual_max", _F, "", False, "Largest detection residual over the action's sim steps (NaN without "
                                          "wrench).", finite=True, nan_means_missing=True, minimum=0.0),
    Column("win_wrench", _F, "N, N m", False,
           "Last 8 sim steps' contact wrench on the gripper (f_x, f_y, f_z, τ_x, τ_y, τ_z), world frame, torque "
           "about the gripper base; NaN without wrench. Eight because isolation takes the latest in-contact "
           "step among the last 5 plus up to 3 preceding ones.", shape=(8, 6), nan_means_missing=True, **_FORCE),
    Column("win_pose", _F, "m, quaternion", False, "Last 8 sim steps' gripper base pose (x, y, z, qx, qy, qz, qw).",
           shape=(8, 7), **_POS),
    Column("win_true_contact_m", _F, "m", False, "Last 8 sim steps' true contact point on the gripper (x, y) of "
                                                 "the first object in contact; NaN without contact.",
           shape=(8, 2), nan_means_missing=True, **_POS),
    Column("win_true_object", _I, "", False, "Last 8 sim steps' object id of that contact (-1: none).",
           shape=(8,), minimum=-1),
    Column("true_contact_x_m", _F, "m", True, "True contact point x at the action's last sim step with contact; "
                                              "null if none.", **_POS),
    Column("true_contact_y_m", _F, "m", True, "Same for y.", **_POS),
    Column("object_id", _I, "", False, "Ground-truth label of the action (docs/simulation.md): index into the "
                                       "'bodies' metadata list, -1 for no contact.", minimum=-1),
    Column("force_rep_x_n", _F, "N", False, "Representative contact force x (docs/simulation.md): the force at the 6th "
                                            "sim step of each 20-step bucket, of the bucket with the median "
                                            "magnitude (NaN without wrench).", nan_means_missing=True, **_FORCE),
    Column("force_rep_y_n", _F, "N", False, "Same for y.", nan_means_missing=True, **_FORCE),
    Column("obj_pose", _F, "m, m, rad", False, "Every body's inertial-frame (x, y, yaw) after the action, in "
                                               "'bodies' order; NaN for bodies not built.",
           shape=(None, 3), nan_means_missing=True, **_POS),
    Column("obj_distance_m", _F, "m", False, "Every body's minimum distance to the gripper after the action "
                                             "(negative: penetration); NaN for bodies not built.",
           shape=(None,), nan_means_missing=True, **_POS),
    Column("pad_contact_m", _F, "m", False, "Each fingertip sensor's contact point (x, y) of the action, noise "
                                            "included (docs/simulation.md, \"Tactile fingertips and a noisy "
                                            "wrench\"); NaN for a pad that did not fire; absent from runs of "
                                            "scenes without fingertips.", shape=(None, 2), nan_means_missing=True,
           required=False, **_POS),
    Column("pad_dx_m", _F, "m", False, "The gripper's displacement summed over the sim steps each pad fired; NaN "
                                       "for a pad that did not fire.", shape=(None, 2), nan_means_missing=True,
           required=False, **_STEP),
    Column("pad_object", _I, "", False, "Ground truth: the object pressing each pad at its reported point (-1: "
                                        "none).", shape=(None,), minimum=-1, required=False),
    Column("pad_force_n", _F, "N", False, "Largest normal force on each pad over the action.", shape=(None,),
           required=False, finite=True, minimum=0.0, maximum=MAX_WRENCH),
    Column("probe", pa.bool_(), "", False, "The action is the probing policy's (`stucco collect --policy "
                                           "scripted+probe` or `explore`, docs/retrieval.md, \"Active "
                                           "retrieval\"), not the scripted part's (nor the explore policy's "
                                           "search); absent from runs of the other policies.",
           required=False),
)


def _check_sim_run(cols: ColumnViews) -> None:
    if cols.n == 0:
        cols.fail(None, None, "has no actions; expected at least one row (a run file written by stucco collect)")
    if len(cols.run_names) > 1:
        r = first_row(cols.run_codes != 0)
        cols.fail("run", r, f"is {cols.run_names[cols.run_codes[r]]!r} after {cols.run_names[0]!r}; expected one "
                            "run per file")
    seed = cols.values["seed"]
    if (r := first_row(seed != seed[0])) is not None:
        cols.fail("seed", r, f"is {int(seed[r])} after {int(seed[0])}; expected one seed per file")
    check_steps_nondecreasing(cols, strict=True, why="expected strictly increasing action indices")
    inc = cols.values["in_contact"].astype(bool)
    for name in ("contact_dx_m", "contact_dy_m"):
        if (r := first_row(~inc & ~cols.null[name])) is not None:
            cols.fail(name, r, f"is {float(cols.values[name][r])!r} while in_contact is false; expected null")
    wrench = cols.values["win_wrench"]
    if (r := first_row(np.isnan(wrench).any(axis=(1, 2)) & inc)) is not None:
        cols.fail("win_wrench", r, "has NaN while in_contact is true; the detector needs the wrench")


#: The fingertip sensors' columns, written together or not at all.
PAD_COLUMNS = ("pad_contact_m", "pad_dx_m", "pad_object", "pad_force_n")


SIM_RUN = TableSpec(
    "sim_run",
    SIM_RUN_COLUMNS,
    (
        "One run per file: one value of `run` and of `seed`; at least one row.",
        "`step` strictly increasing.",
        "`contact_dx_m`, `contact_dy_m` null when `in_contact` is false.",
        "`win_wrench` has no NaN in an action detected as in contact.",
        f"Positions within ±{MAX_POSITION_M:g} m and displacements per action within "
        f"±{MAX_STEP_DISPLACEMENT_M:g} m (larger values are almost certainly millimetres); wrench components "
        f"within ±{MAX_WRENCH:g}.",
    ),
    _check_sim_run,
)
