"""Table specs: the stage tables (contacts, tracks, segments, diagnostics; sim_run from runs.py; retrieval,
candidates and scores from results.py) as data, and their validators.

Each table is described once here (:data:`CONTACTS_COLUMNS`, ... and the :class:`TableSpec` objects
:data:`CONTACTS`, ...; gathered in :data:`TABLES`); validation and ``docs/tables.md`` are derived from these
descriptions. Units are in the column names and ``unit`` fields (metres, milliseconds).
"""
from __future__ import annotations

import os

import pyarrow as pa

from pipeline.schema.columns import Column, TableSpec
from pipeline.schema.results import CANDIDATES, RETRIEVAL, SCORES
from pipeline.schema.rules import MAX_POSITION_M, MAX_SECONDS, check_contacts, check_diagnostics, check_tracks
from pipeline.schema.runs import SIM_RUN
from pipeline.schema.validate import validate_spec

__all__ = [
    "CONTACTS_COLUMNS",
    "TRACKS_COLUMNS",
    "SEGMENTS_COLUMNS",
    "DIAGNOSTICS_COLUMNS",
    "CONTACTS",
    "TRACKS",
    "SEGMENTS",
    "DIAGNOSTICS",
    "TABLES",
    "validate_table",
    "validate_contacts",
    "validate_tracks",
    "validate_segments",
    "validate_diagnostics",
]

_RUN = Column("run", pa.string(), "", False, "Run (episode) identifier; rows of one run need not be contiguous.")

CONTACTS_COLUMNS: tuple[Column, ...] = (
    _RUN,
    Column("step", pa.int64(), "", False,
           "Control step index; non-decreasing within a run; equal consecutive steps are the simultaneous "
           "contacts of one step."),
    Column("ee_x_m", pa.float64(), "m", False, "End-effector x position after the step.", finite=True,
           values="finite, |x| ≤ 100"),
    Column("ee_y_m", pa.float64(), "m", False, "End-effector y position after the step.", finite=True,
           values="finite, |y| ≤ 100"),
    Column("in_contact", pa.bool_(), "", False, "Whether the end effector was in contact during the step."),
    Column("contact_x_m", pa.float64(), "m", True, "Contact point x (observed at the end of the step).",
           values="finite, |x| ≤ 100 when in contact; null otherwise"),
    Column("contact_y_m", pa.float64(), "m", True, "Contact point y (observed at the end of the step).",
           values="finite, |y| ≤ 100 when in contact; null otherwise"),
    Column("dx_m", pa.float64(), "m", True, "End-effector x displacement while in contact during the step.",
           values="finite, |dx| ≤ 1 when in contact; null otherwise"),
    Column("dy_m", pa.float64(), "m", True, "End-effector y displacement while in contact during the step.",
           values="finite, |dy| ≤ 1 when in contact; null otherwise"),
    Column("object_id", pa.int64(), "", False, "Ground-truth object touched (-1 unknown).", required=False,
           minimum=-1),
    Column("ee_start_x_m", pa.float64(), "m", True, "End-effector x position before the step (a log's start; "
           "null: the previous step's end).", required=False, finite=True, minimum=-MAX_POSITION_M,
           maximum=MAX_POSITION_M),
    Column("ee_start_y_m", pa.float64(), "m", True, "End-effector y position before the step (a log's start; "
           "null: the previous step's end).", required=False, finite=True, minimum=-MAX_POSITION_M,
           maximum=MAX_POSITION_M),
    Column("force_n", pa.float64(), "N", True, "The contact force the step met (largest in-plane wrench over "
           "the isolation window); null: none detected, or not measured.", required=False, finite=True,
           minimum=0.0),
    Column("sensor", pa.int64(), "", True, "Which sensor gave the contact: -1 isolation from the wrist wrench, 0, "
           "1, ... a fingertip sensor (docs/simulation.md, \"Tactile fingertips and a noisy wrench\"); null in "
           "free space. Written for runs with fingertip sensors.", required=False, minimum=-1),
)

TRACKS_COLUMNS: tuple[Column, ...] = (
    _RUN,
    Column("step", pa.int64(), "", False, "Step the contact was observed at."),
    Column("contact_index", pa.int64(), "", False, "Order of the contact within its step (0..K-1).", minimum=0),
    Column("estimate_step", pa.int64(), "", False,
           "Step after which this estimate was made; the final estimate of a run has estimate_step = the "
           "run's last step."),
    # bounded like the contacts they come from: 1e300 would overflow the estimators (issue 17)
    Column("x_m", pa.float64(), "m", False, "Tracked x position of the contact point.", finite=True,
           minimum=-MAX_POSITION_M, maximum=MAX_POSITION_M),
    Column("y_m", pa.float64(), "m", False, "Tracked y position of the contact point.", finite=True,
           minimum=-MAX_POSITION_M, maximum=MAX_POSITION_M),
    Column("tracker_label", pa.int64(), "", False, "The tracker's own hard object assignment.", minimum=0),
    Column("object_id", pa.int64(), "", False,
           "Ground-truth object, carried from the contacts table (-1 unknown).", required=False, minimum=-1),
)

SEGMENTS_COLUMNS: tuple[Column, ...] = TRACKS_COLUMNS + (
    Column("segment", pa.int64(), "", False, "Object segment the point is assigned to (-1 unassigned).",
           minimum=-1),
)

DIAGNOSTICS_COLUMNS: tuple[Column, ...] = (
    _RUN,
    Column("step", pa.int64(), "", False, "Control step; one row per step, increasing within a run."),
    Column("in_contact", pa.bool_(), "", False, "Whether the step was in contact."),
    Column("n_contacts", pa.int64(), "", False, "Number of contact points observed at the step.", minimum=0),
    Column("ess", pa.float64(), "fraction of N", False,
           "Effective sample size after the update, before resampling, as a fraction of the number of "
           "particles.", finite=True, minimum=0.0, maximum=1.0, exclusive_minimum=True),
    Column("resampled", pa.bool_(), "", False, "Whether the particles were resampled after the update."),
    Column("n_replaced", pa.int64(), "", False, "Points replaced by ReplaceInconsistentPoints.", minimum=0),
    Column("update_ms", pa.float64(), "ms", False, "Wall time of the update.", finite=True, minimum=0.0,
           maximum=MAX_SECONDS * 1000.0),
)


CONTACTS = TableSpec(
    "contacts", CONTACTS_COLUMNS,
    rules=(
        "Rows of one run need not be contiguous; runs are taken in order of first appearance, and the rows of "
        "a run in file order.",
        "Within a run, `step` is non-decreasing; several consecutive rows with the same step are the "
        "simultaneous contacts of that step, in order.",
        "A free-space step (`in_contact` false) is exactly one row; every row of a step with several rows is "
        "in contact; all rows of one step share `ee_x_m`/`ee_y_m`.",
        "When `in_contact` is true, `contact_x_m`, `contact_y_m`, `dx_m`, `dy_m` are finite (a null `dx_m` is "
        "a contact without displacement); when false they are null (NaN is rejected: use null).",
        f"Units: |`ee_*`| and |`contact_*`| above {MAX_POSITION_M:g} m or |`dx_m`|, |`dy_m`| above 1 m per step are "
        "rejected as the wrong unit (metres are expected).",
        "`object_id` is optional; if present it has no nulls.",
        "Any other column is allowed and carried through unchanged, after the columns above.",
    ),
    check=check_contacts,
)

TRACKS = TableSpec(
    "tracks", TRACKS_COLUMNS,
    rules=(
        "`estimate_step` ≥ `step`: a contact is estimated only after it was observed.",
        "For each (`run`, `estimate_step`, `step`) the `contact_index` values are 0..K-1, each once.",
        "Other columns of the contact row (e.g. `object_id`) are carried through unchanged.",
        "Written with `--every-step` (metadata `every_step`; `stucco evaluate` does so when an estimator reads "
        "it, `--estimator paper`), a run holds one estimate after every step from its first contact on; the "
        "estimate after an in-contact step is the one with rows observed at that step (`step` = "
        "`estimate_step`). Without it, only the final estimate; readers of the final points take the rows with "
        "the run's largest `estimate_step`.",
    ),
    check=check_tracks,
)

SEGMENTS = TableSpec("segments", SEGMENTS_COLUMNS, rules=TRACKS.rules, check=check_tracks)

DIAGNOSTICS = TableSpec(
    "diagnostics", DIAGNOSTICS_COLUMNS,
    rules=(
        "One row per control step: `step` strictly increasing within a run.",
        "`n_contacts` ≥ 1 when `in_contact`, 0 otherwise.",
    ),
    check=check_diagnostics,
)

#: Every table kind a stage writes, in pipeline order (``sim_run`` is the runs table).
TABLES: dict[str, TableSpec] = {t.name: t for t in (SIM_RUN, CONTACTS, TRACKS, DIAGNOSTICS, SEGMENTS, RETRIEVAL,
                                                    CANDIDATES, SCORES)}


def validate_table(table: pa.Table, kind: str, path: str | os.PathLike = "<table>") -> pa.Table:
    """Validate `table` as a table of kind `kind` (a key of :data:`TABLES`).

    Returns
    -------
    pyarrow.Table
        Canonical types, described columns in canonical order, then any other columns unchanged.
        Schema metadata is dropped (read provenance with :func:`~pipeline.schema.io.read_metadata`).

    Raises
    ------
    SchemaError
    """
    return validate_spec(table, TABLES[kind], path)


def validate_contacts(table: pa.Table, path: str | os.PathLike = "<table>") -> pa.Table:
    """Validate a contacts table; see :func:`validate_table` and :data:`CONTACTS`."""
    return validate_spec(table, CONTACTS, path)


def validate_tracks(table: pa.Table, path: str | os.PathLike = "<table>") -> pa.Table:
    """Validate a tracks table; see :func:`validate_table` and :data:`TRACKS`."""
    return validate_spec(table, TRACKS, path)


def validate_segments(table: pa.Table, path: str | os.PathLike = "<table>") -> pa.Table:
    """Validate a segments table; see :func:`validate_table` and :data:`SEGMENTS`."""
    return validate_spec(table, SEGMENTS, path)


def validate_diagnostics(table: pa.Table, path: str | os.PathLike = "<table>") -> pa.Table:
    """Validate a diagnostics table; see :func:`validate_table` and :data:`DIAGNOSTICS`."""
    return validate_spec(table, DIAGNOSTICS, path)
