"""Table rules: the checks of the stage tables that involve several columns or rows (``TableSpec.check``).

Each rule receives the :class:`~pipeline.schema.columns.ColumnViews` views built by the validation engine and
raises a one-line :class:`~pipeline.schema.errors.SchemaError` at the first bad row. Their human-readable
statements are the ``rules`` of the specs in :mod:`pipeline.schema.specs` (listed in ``docs/tables.md``).
"""
from __future__ import annotations

import numpy as np

from pipeline.schema.columns import ColumnViews, format_bound
from pipeline.schema.validate import check_steps_nondecreasing, first_row, format_value

__all__ = ["MAX_POSITION_M", "MAX_SECONDS", "MAX_STEP_DISPLACEMENT_M", "check_contacts", "check_tracks",
           "check_diagnostics"]

# Values beyond these are almost certainly millimetres (or centimetres) passed as metres: the paper's
# workspace is well under a metre across (a scene's walls lie within 1 m of the origin) and a control step moves
# the gripper by millimetres. One bound for every table that holds positions (runs, contacts, tracks, segments):
# a run or segments file in centimetres puts its positions at tens of units and is refused by name and column.
MAX_POSITION_M = 5.0
#: Longest wall time a timing column may record (one day, s): sums of such times stay finite.
MAX_SECONDS = 86_400.0
MAX_STEP_DISPLACEMENT_M = 1.0


# Values when in contact, null in free space (the contacts table's conditional columns).
_CONDITIONAL = ("contact_x_m", "contact_y_m", "dx_m", "dy_m")


def check_contacts(cols: ColumnViews) -> None:
    v, null = cols.values, cols.null
    inc = v["in_contact"].astype(bool)
    for name in _CONDITIONAL:
        x, isnull = v[name], null[name]
        nan = ~isnull & np.isnan(x)
        need = inc & isnull
        nonfinite = inc & ~isnull & ~np.isfinite(x)
        nan_free = ~inc & nan
        value_free = ~inc & ~isnull & ~nan
        r = first_row(need | nonfinite | nan_free | value_free)
        if r is None:
            continue
        if need[r]:
            what = ("is null while in_contact is true: contact without displacement; expected the end-effector "
                    "displacement during the step in metres" if name in ("dx_m", "dy_m") else
                    "is null while in_contact is true; expected the contact point in metres")
        elif nonfinite[r]:
            what = f"is {format_value(x[r])} while in_contact is true; expected a finite value"
        elif nan_free[r]:
            what = "is NaN while in_contact is false; use null (not NaN) when there is no contact"
        else:
            what = f"is {format_value(x[r])} while in_contact is false; expected null when there is no contact"
        cols.fail(name, r, what)

    for name, limit, what in (
        ("ee_x_m", MAX_POSITION_M, "positions"), ("ee_y_m", MAX_POSITION_M, "positions"),
        ("contact_x_m", MAX_POSITION_M, "positions"), ("contact_y_m", MAX_POSITION_M, "positions"),
        ("dx_m", MAX_STEP_DISPLACEMENT_M, "displacements per step"),
        ("dy_m", MAX_STEP_DISPLACEMENT_M, "displacements per step"),
    ):
        x = v[name]
        with np.errstate(invalid="ignore"):
            r = first_row(np.abs(np.nan_to_num(x)) > limit)
        if r is not None:
            cols.fail(name, r, f"is {format_value(x[r])}, which looks like the wrong unit ({what} beyond "
                               f"{format_bound(limit)} m); metres are expected")

    order, same = check_steps_nondecreasing(
        cols, strict=False, why="steps must be non-decreasing within a run")
    if cols.n == 0:
        return
    s = v["step"][order]
    new = np.r_[True, ~same | (s[1:] != s[:-1])]
    gid = np.cumsum(new) - 1
    first_sorted = np.flatnonzero(new)[gid]  # sorted position of each row's step head
    size = np.bincount(gid)[gid]
    bad = (size > 1) & ~inc[order]
    if bad.any():
        r = int(order[bad].min())
        cols.fail("in_contact", r,
                  f"is false but step {v['step'][r]} of run {cols.run_names[cols.run_codes[r]]!r} has several "
                  f"rows; a free-space step is exactly one row and every row of a multi-contact step must be "
                  f"in contact")
    for name in ("ee_x_m", "ee_y_m"):
        x = v[name][order]
        bad = x != x[first_sorted]
        if bad.any():
            r = int(order[bad].min())
            head = int(order[first_sorted[np.flatnonzero(order == r)[0]]])
            cols.fail(name, r, f"is {format_value(v[name][r])} but row {head} of the same step {v['step'][r]} "
                               f"(run {cols.run_names[cols.run_codes[r]]!r}) has {format_value(v[name][head])}; "
                               f"all rows of one step must share the end-effector position")


def check_tracks(cols: ColumnViews) -> None:
    v = cols.values
    step, est, ci = v["step"], v["estimate_step"], v["contact_index"]
    if (r := first_row(est < step)) is not None:
        cols.fail("estimate_step", r, f"is {est[r]}, before the contact was observed (step {step[r]}); "
                                      f"expected estimate_step ≥ step")
    if cols.n == 0:
        return
    order = np.lexsort((np.arange(cols.n), ci, step, est, cols.run_codes))
    key = np.stack([cols.run_codes[order], est[order], step[order]])
    new = np.r_[True, (key[:, 1:] != key[:, :-1]).any(axis=0)]
    start = np.flatnonzero(new)[np.cumsum(new) - 1]
    rank = np.arange(cols.n) - start
    bad = ci[order] != rank
    if bad.any():
        r = int(order[bad].min())
        cols.fail("contact_index", r,
                  f"is {ci[r]} for step {step[r]}, estimate_step {est[r]}, run "
                  f"{cols.run_names[cols.run_codes[r]]!r}; the contacts of one step in one estimate must be "
                  f"numbered 0..K-1 without gaps or repeats")


def check_diagnostics(cols: ColumnViews) -> None:
    v = cols.values
    inc, k = v["in_contact"].astype(bool), v["n_contacts"]
    if (r := first_row(inc & (k < 1))) is not None:
        cols.fail("n_contacts", r, f"is {k[r]} while in_contact is true; expected at least 1")
    if (r := first_row(~inc & (k != 0))) is not None:
        cols.fail("n_contacts", r, f"is {k[r]} while in_contact is false; expected 0")
    check_steps_nondecreasing(cols, strict=True,
                               why="diagnostics have one row per step, with steps increasing within a run")
