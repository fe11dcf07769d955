"""The Parquet tables the stages exchange: their columns, units and rules, validation on read, atomic writes.

Tables (long format, one row per (run, step[, contact])):

``contacts``
    Input of ``stucco track``; written by ``collect`` or by hand from a real robot log.
``tracks``
    Output of ``stucco track``: tracked contact point positions and the tracker's hard labels.
``segments``
    Output of ``stucco segment``: the tracks columns plus ``segment``.
``diagnostics``
    Side output of ``stucco track``: one row per control step describing the filter update.

Each table is described once, as data (:data:`CONTACTS_COLUMNS`, :data:`TRACKS_COLUMNS`, ...; gathered in
:data:`TABLES`), and both validation and ``docs/tables.md`` are derived from those descriptions. Validation
fails with a one-line :class:`SchemaError` naming the file, the column and the first bad row.

Every file a stage writes goes through :func:`write_table`, which validates, attaches provenance
(``stucco.*`` schema metadata: stage, version, parameters, seed, input digests, table kind) and writes to a
temporary name in the target directory before renaming it onto the target, so a reader never sees a partial
file. Writing the same table with the same metadata twice gives identical bytes.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import secrets
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

__all__ = [
    "SchemaError",
    "Column",
    "TableSpec",
    "CONTACTS_COLUMNS",
    "TRACKS_COLUMNS",
    "SEGMENTS_COLUMNS",
    "DIAGNOSTICS_COLUMNS",
    "CONTACTS",
    "TRACKS",
    "SEGMENTS",
    "DIAGNOSTICS",
    "TABLES",
    "METADATA_KEYS",
    "WRITER_OPTIONS",
    "read_contacts",
    "validate_contacts",
    "read_tracks",
    "validate_tracks",
    "read_segments",
    "validate_segments",
    "read_diagnostics",
    "validate_diagnostics",
    "read_table",
    "validate_table",
    "write_table",
    "read_metadata",
    "file_digest",
    "RunContacts",
    "contacts_by_run",
    "columns_markdown",
    "table_markdown",
]

# Values beyond these are almost certainly millimetres (or centimetres) passed as metres: the paper's
# workspace is well under a metre across and a control step moves the gripper by millimetres.
MAX_POSITION_M = 100.0
MAX_STEP_DISPLACEMENT_M = 1.0


# --------------------------------------------------------------------------------------------------------
# Errors


class SchemaError(ValueError):
    """A table does not follow its schema.

    The message is always one line: ``"{file}: column '{col}', row {i}: {what}"``; the row part is left out
    when the whole column is at fault (missing, mistyped) and the column part when the whole file is
    (not found, not Parquet). Rows are 0-based indices into the file.

    Attributes
    ----------
    path : str
        The file (or ``"<table>"`` for an in-memory table).
    column : str or None
    row : int or None
    what : str
        What is wrong and what was expected.
    """

    def __init__(self, path: str | os.PathLike, column: str | None, row: int | None, what: str):
        self.path = str(path)
        self.column = column
        self.row = None if row is None else int(row)
        self.what = " ".join(str(what).split())  # one line, whatever pyarrow put in it
        super().__init__(self._format())

    def _format(self) -> str:
        if self.column is None:
            return f"{self.path}: {self.what}"
        if self.row is None:
            return f"{self.path}: column '{self.column}': {self.what}"
        return f"{self.path}: column '{self.column}', row {self.row}: {self.what}"

    def __reduce__(self):  # keep the attributes across process pools
        return (type(self), (self.path, self.column, self.row, self.what))


# --------------------------------------------------------------------------------------------------------
# Column descriptions (the single source for validation and docs)


@dataclass(frozen=True)
class Column:
    """One column of a table.

    Parameters
    ----------
    name : str
    type : pyarrow.DataType
        Canonical type after reading. Accepted on input: any string type or dictionary of strings for
        ``string``; any integer type for ``int64``; any float or integer type for ``float64``; only
        ``bool`` for ``bool``. An all-null column of type ``null`` is accepted for any type.
    unit : str
        Unit of the values ("" when unitless).
    nullable : bool
        Whether nulls may appear at all (conditional rules, e.g. "null when not in contact", are table rules).
    meaning : str
    required : bool
        False for optional columns, which are validated when present.
    finite : bool
        Non-null values must be finite (no NaN, no inf).
    minimum, maximum : float or None
        Inclusive bounds on non-null values.
    exclusive_minimum : bool
        Makes ``minimum`` exclusive.
    values : str
        Human-readable value rule for the docs; derived from the fields above when empty.
    """

    name: str
    type: pa.DataType
    unit: str
    nullable: bool
    meaning: str
    required: bool = True
    finite: bool = False
    minimum: float | None = None
    maximum: float | None = None
    exclusive_minimum: bool = False
    values: str = ""

    @property
    def value_rule(self) -> str:
        if self.values:
            return self.values
        parts = []
        if self.finite:
            parts.append("finite")
        lo, hi = self.minimum, self.maximum
        if lo is not None and hi is not None:
            parts.append(f"{'(' if self.exclusive_minimum else '['}{_num(lo)}, {_num(hi)}]")
        elif lo is not None:
            parts.append(f"{'>' if self.exclusive_minimum else '≥'} {_num(lo)}")
        elif hi is not None:
            parts.append(f"≤ {_num(hi)}")
        return ", ".join(parts)


@dataclass(frozen=True)
class TableSpec:
    """A table kind: its columns in canonical order and the rules that involve several columns or rows.

    ``rules`` are the human-readable statements of the checks in ``check`` (used by the docs).
    Columns not described here are allowed and carried through unchanged, after the described ones.
    """

    name: str
    columns: tuple[Column, ...]
    rules: tuple[str, ...]
    check: Callable[["_Columns"], None] | None = dataclasses.field(default=None, repr=False, compare=False)

    def column(self, name: str) -> Column:
        for c in self.columns:
            if c.name == name:
                return c
        raise KeyError(name)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.columns)


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else repr(float(x))


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
)

TRACKS_COLUMNS: tuple[Column, ...] = (
    _RUN,
    Column("step", pa.int64(), "", False, "Step the contact was observed at."),
    Column("contact_index", pa.int64(), "", False, "Order of the contact within its step (0..K-1).", minimum=0),
    Column("estimate_step", pa.int64(), "", False,
           "Step after which this estimate was made; the final estimate of a run has estimate_step = the "
           "run's last step."),
    Column("x_m", pa.float64(), "m", False, "Tracked x position of the contact point.", finite=True),
    Column("y_m", pa.float64(), "m", False, "Tracked y position of the contact point.", finite=True),
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
    Column("update_ms", pa.float64(), "ms", False, "Wall time of the update.", finite=True, minimum=0.0),
)

METADATA_KEYS: tuple[tuple[str, str], ...] = (
    ("stucco.stage", "Stage that wrote the file (e.g. `track`)."),
    ("stucco.version", "`pipeline.__version__` of the writer."),
    ("stucco.params", "JSON object of the stage's parameters, keys sorted."),
    ("stucco.seed", "JSON integer root seed, or `null`."),
    ("stucco.inputs", "JSON object role -> {\"file\": file name, \"sha256\": hex digest of the file bytes}."),
    ("stucco.schema", "Table kind: `contacts`, `tracks`, `segments`, `diagnostics` (or a stage's own kind)."),
)

# Fixed writer options: same bytes for the same table (no timestamps are written by parquet-cpp; the
# `created_by` string depends only on the pyarrow version).
WRITER_OPTIONS: dict[str, Any] = dict(
    compression="zstd",
    compression_level=3,
    version="2.6",
    use_dictionary=True,
    write_statistics=True,
    row_group_size=1 << 20,
)


# --------------------------------------------------------------------------------------------------------
# Generic validation


@dataclass
class _Columns:
    """Numpy views of the canonical columns of a table under validation (passed to table rules)."""

    path: str
    n: int
    values: dict[str, np.ndarray]  # floats with NaN for null; other types only when the column has no nulls
    null: dict[str, np.ndarray]  # bool (n,)
    run_codes: np.ndarray  # int64 (n,), runs numbered by first appearance
    run_names: list[str]

    def fail(self, column: str | None, row: int | None, what: str) -> None:
        raise SchemaError(self.path, column, row, what)


def _type_name(t: pa.DataType) -> str:
    return {pa.string(): "string", pa.int64(): "int64", pa.float64(): "float64", pa.bool_(): "bool"}.get(t, str(t))


def _accepts(target: pa.DataType, t: pa.DataType) -> bool:
    if pa.types.is_null(t):
        return True
    if target == pa.string():
        if pa.types.is_dictionary(t):
            t = t.value_type
        return pa.types.is_string(t) or pa.types.is_large_string(t) or pa.types.is_string_view(t)
    if target == pa.int64():
        return pa.types.is_integer(t)
    if target == pa.float64():
        return pa.types.is_floating(t) or pa.types.is_integer(t)
    if target == pa.bool_():
        return pa.types.is_boolean(t)
    return t == target


_ACCEPTED = {
    pa.string(): "string (string, large_string or dictionary of strings)",
    pa.int64(): "int64 (any integer type is accepted)",
    pa.float64(): "float64 (any float or integer type is accepted)",
    pa.bool_(): "bool",
}


def _run_codes(col: pa.ChunkedArray) -> tuple[np.ndarray, list[str]]:
    # dictionary_encode numbers values by first appearance, which is the run order we promise.
    enc = col.combine_chunks().dictionary_encode()
    return enc.indices.to_numpy(zero_copy_only=False).astype(np.int64), enc.dictionary.to_pylist()


def _fmt(v: Any) -> str:
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, (np.integer,)):
        return str(int(v))
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    return repr(v)


def _first(mask: np.ndarray) -> int | None:
    idx = np.flatnonzero(mask)
    return int(idx[0]) if idx.size else None


def validate_spec(table: pa.Table, spec: TableSpec, path: str | os.PathLike = "<table>") -> pa.Table:
    """Validate a table against any :class:`TableSpec` (stages that own their tables use this)."""
    return _validate(table, spec, path)


def _validate(table: pa.Table, spec: TableSpec, path: str | os.PathLike) -> pa.Table:
    path = str(path)
    if not isinstance(table, pa.Table):
        raise TypeError(f"expected a pyarrow.Table, got {type(table).__name__}")
    names = table.column_names
    for c in spec.columns:
        k = names.count(c.name)
        if k == 0 and c.required:
            raise SchemaError(path, c.name, None,
                              f"missing; expected {_type_name(c.type)}"
                              f"{f' in {c.unit}' if c.unit else ''} ({c.meaning.rstrip('.')})")
        if k > 1:
            raise SchemaError(path, c.name, None, f"appears {k} times; expected once")
    present = [c for c in spec.columns if c.name in names]
    for c in present:
        t = table.schema.field(c.name).type
        if not _accepts(c.type, t):
            raise SchemaError(path, c.name, None, f"has type {t}; expected {_ACCEPTED.get(c.type, c.type)}")

    n = table.num_rows
    arrays: dict[str, pa.ChunkedArray] = {}
    values: dict[str, np.ndarray] = {}
    null: dict[str, np.ndarray] = {}
    for c in present:
        col = table.column(c.name)
        if pa.types.is_uint64(col.type) and c.type == pa.int64():
            big = np.asarray(col.to_numpy(zero_copy_only=False)) > np.iinfo(np.int64).max
            if (r := _first(big)) is not None:
                raise SchemaError(path, c.name, r, f"{col[r].as_py()} does not fit in int64")
        if col.type != c.type:
            col = col.cast(c.type)
        arrays[c.name] = col
        isnull = col.is_null().to_numpy(zero_copy_only=False) if col.null_count else np.zeros(n, bool)
        null[c.name] = np.asarray(isnull, dtype=bool)
        if not c.nullable and (r := _first(null[c.name])) is not None:
            raise SchemaError(path, c.name, r, "is null; expected a value (this column is never null)")
        if c.type == pa.float64():
            v = np.asarray(col.to_numpy(zero_copy_only=False), dtype=np.float64)  # null -> NaN
        elif c.type == pa.string():
            v = None  # runs are handled through codes
        else:
            v = np.asarray(col.to_numpy(zero_copy_only=False))
        if v is not None:
            values[c.name] = v
            ok = ~null[c.name]
            if c.finite and (r := _first(ok & ~np.isfinite(v))) is not None:
                raise SchemaError(path, c.name, r, f"is {_fmt(v[r])}; expected a finite value")
            if c.minimum is not None:
                below = (v <= c.minimum) if c.exclusive_minimum else (v < c.minimum)
                if (r := _first(ok & below)) is not None:
                    bound = ("greater than " if c.exclusive_minimum else "at least ") + _num(c.minimum)
                    raise SchemaError(path, c.name, r, f"is {_fmt(v[r])}; expected {bound}")
            if c.maximum is not None and (r := _first(ok & (v > c.maximum))) is not None:
                raise SchemaError(path, c.name, r, f"is {_fmt(v[r])}; expected at most {_num(c.maximum)}")

    codes, run_names = _run_codes(arrays["run"]) if "run" in arrays else (np.zeros(n, np.int64), [])
    cols = _Columns(path, n, values, null, codes, run_names)
    if spec.check is not None:
        spec.check(cols)

    extra = [i for i, name in enumerate(names) if name not in spec.names]  # by index: names may repeat
    out_fields = [pa.field(c.name, c.type, nullable=True) for c in present]
    out_fields += [table.schema.field(i) for i in extra]
    return pa.Table.from_arrays([arrays[c.name] for c in present] + [table.column(i) for i in extra],
                                schema=pa.schema(out_fields))


def _sorted_by_run(cols: _Columns) -> tuple[np.ndarray, np.ndarray]:
    """(order, same): rows grouped by run in first-appearance order, file order kept within a run; `same[i]`
    says sorted rows i and i+1 belong to the same run."""
    order = np.argsort(cols.run_codes, kind="stable")
    rc = cols.run_codes[order]
    return order, rc[1:] == rc[:-1]


def _check_steps_nondecreasing(cols: _Columns, strict: bool, why: str) -> tuple[np.ndarray, np.ndarray]:
    step = cols.values["step"]
    order, same = _sorted_by_run(cols)
    s = step[order]
    bad = same & ((s[1:] <= s[:-1]) if strict else (s[1:] < s[:-1]))
    if bad.any():
        rows, prev = order[1:][bad], order[:-1][bad]
        i = int(np.argmin(rows))
        r, p = int(rows[i]), int(prev[i])
        cols.fail("step", r, f"step {step[r]} follows step {step[p]} (row {p}) in run "
                             f"{cols.run_names[cols.run_codes[r]]!r}; {why}")
    return order, same


# --------------------------------------------------------------------------------------------------------
# Table rules


_CONDITIONAL = ("contact_x_m", "contact_y_m", "dx_m", "dy_m")


def _check_contacts(cols: _Columns) -> None:
    v, null = cols.values, cols.null
    inc = v["in_contact"].astype(bool)
    for name in _CONDITIONAL:
        x, isnull = v[name], null[name]
        nan = ~isnull & np.isnan(x)
        need = inc & isnull
        nonfinite = inc & ~isnull & ~np.isfinite(x)
        nan_free = ~inc & nan
        value_free = ~inc & ~isnull & ~nan
        r = _first(need | nonfinite | nan_free | value_free)
        if r is None:
            continue
        if need[r]:
            what = ("is null while in_contact is true: contact without displacement; expected the end-effector "
                    "displacement during the step in metres" if name in ("dx_m", "dy_m") else
                    "is null while in_contact is true; expected the contact point in metres")
        elif nonfinite[r]:
            what = f"is {_fmt(x[r])} while in_contact is true; expected a finite value"
        elif nan_free[r]:
            what = "is NaN while in_contact is false; use null (not NaN) when there is no contact"
        else:
            what = f"is {_fmt(x[r])} while in_contact is false; expected null when there is no contact"
        cols.fail(name, r, what)

    for name, limit, what in (
        ("ee_x_m", MAX_POSITION_M, "positions"), ("ee_y_m", MAX_POSITION_M, "positions"),
        ("contact_x_m", MAX_POSITION_M, "positions"), ("contact_y_m", MAX_POSITION_M, "positions"),
        ("dx_m", MAX_STEP_DISPLACEMENT_M, "displacements per step"),
        ("dy_m", MAX_STEP_DISPLACEMENT_M, "displacements per step"),
    ):
        x = v[name]
        with np.errstate(invalid="ignore"):
            r = _first(np.abs(np.nan_to_num(x)) > limit)
        if r is not None:
            cols.fail(name, r, f"is {_fmt(x[r])}, which looks like the wrong unit ({what} beyond "
                               f"{_num(limit)} m); metres are expected")

    order, same = _check_steps_nondecreasing(
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
            cols.fail(name, r, f"is {_fmt(v[name][r])} but row {head} of the same step {v['step'][r]} "
                               f"(run {cols.run_names[cols.run_codes[r]]!r}) has {_fmt(v[name][head])}; all rows "
                               f"of one step must share the end-effector position")


def _check_tracks(cols: _Columns) -> None:
    v = cols.values
    step, est, ci = v["step"], v["estimate_step"], v["contact_index"]
    if (r := _first(est < step)) is not None:
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


def _check_diagnostics(cols: _Columns) -> None:
    v = cols.values
    inc, k = v["in_contact"].astype(bool), v["n_contacts"]
    if (r := _first(inc & (k < 1))) is not None:
        cols.fail("n_contacts", r, f"is {k[r]} while in_contact is true; expected at least 1")
    if (r := _first(~inc & (k != 0))) is not None:
        cols.fail("n_contacts", r, f"is {k[r]} while in_contact is false; expected 0")
    _check_steps_nondecreasing(cols, strict=True,
                               why="diagnostics have one row per step, with steps increasing within a run")


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
        "Units: |`ee_*`| and |`contact_*`| above 100 m or |`dx_m`|, |`dy_m`| above 1 m per step are rejected "
        "as the wrong unit (metres are expected).",
        "`object_id` is optional; if present it has no nulls.",
        "Any other column is allowed and carried through unchanged, after the columns above.",
    ),
    check=_check_contacts,
)

TRACKS = TableSpec(
    "tracks", TRACKS_COLUMNS,
    rules=(
        "`estimate_step` ≥ `step`: a contact is estimated only after it was observed.",
        "For each (`run`, `estimate_step`, `step`) the `contact_index` values are 0..K-1, each once.",
        "Other columns of the contact row (e.g. `object_id`) are carried through unchanged.",
    ),
    check=_check_tracks,
)

SEGMENTS = TableSpec("segments", SEGMENTS_COLUMNS, rules=TRACKS.rules, check=_check_tracks)

DIAGNOSTICS = TableSpec(
    "diagnostics", DIAGNOSTICS_COLUMNS,
    rules=(
        "One row per control step: `step` strictly increasing within a run.",
        "`n_contacts` ≥ 1 when `in_contact`, 0 otherwise.",
    ),
    check=_check_diagnostics,
)

TABLES: dict[str, TableSpec] = {t.name: t for t in (CONTACTS, TRACKS, SEGMENTS, DIAGNOSTICS)}


# --------------------------------------------------------------------------------------------------------
# Reading


def _read_parquet(path: str | os.PathLike) -> pa.Table:
    p = Path(path)
    if not p.exists():
        raise SchemaError(p, None, None, "file not found")
    if not p.is_file():
        raise SchemaError(p, None, None, "is not a file; expected a Parquet file")
    try:
        return pq.ParquetFile(p).read()
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError, OSError) as e:
        raise SchemaError(p, None, None, f"not a Parquet file ({e})") from None


def validate_table(table: pa.Table, kind: str, path: str | os.PathLike = "<table>") -> pa.Table:
    """Validate `table` as a table of kind `kind` (a key of :data:`TABLES`).

    Returns
    -------
    pyarrow.Table
        Canonical types, described columns in canonical order, then any other columns unchanged.
        Schema metadata is dropped (read provenance with :func:`read_metadata`).

    Raises
    ------
    SchemaError
    """
    return _validate(table, TABLES[kind], path)


def read_table(path: str | os.PathLike, kind: str) -> pa.Table:
    """Read and validate a Parquet file of table kind `kind`; see :func:`validate_table`."""
    return validate_table(_read_parquet(path), kind, path)


def validate_contacts(table: pa.Table, path: str | os.PathLike = "<table>") -> pa.Table:
    """Validate a contacts table; see :func:`validate_table` and :data:`CONTACTS`."""
    return _validate(table, CONTACTS, path)


def read_contacts(path: str | os.PathLike) -> pa.Table:
    """Read and validate a contacts file (the input of ``stucco track``)."""
    return read_table(path, "contacts")


def validate_tracks(table: pa.Table, path: str | os.PathLike = "<table>") -> pa.Table:
    return _validate(table, TRACKS, path)


def read_tracks(path: str | os.PathLike) -> pa.Table:
    return read_table(path, "tracks")


def validate_segments(table: pa.Table, path: str | os.PathLike = "<table>") -> pa.Table:
    return _validate(table, SEGMENTS, path)


def read_segments(path: str | os.PathLike) -> pa.Table:
    return read_table(path, "segments")


def validate_diagnostics(table: pa.Table, path: str | os.PathLike = "<table>") -> pa.Table:
    return _validate(table, DIAGNOSTICS, path)


def read_diagnostics(path: str | os.PathLike) -> pa.Table:
    return read_table(path, "diagnostics")


# --------------------------------------------------------------------------------------------------------
# Writing with provenance


def file_digest(path: str | os.PathLike) -> str:
    """Hex SHA-256 of the file's bytes."""
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (Path, os.PathLike)):
        return os.fspath(o)
    if isinstance(o, (set, frozenset)):
        return sorted(o)
    if dataclasses.is_dataclass(o) and not isinstance(o, type):
        return dataclasses.asdict(o)
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


def _dumps(o: Any) -> str:
    return json.dumps(o, sort_keys=True, separators=(",", ":"), allow_nan=False, default=_json_default)


def _infer_kind(names: list[str]) -> str | None:
    s = set(names)
    if "ess" in s and "n_replaced" in s:
        return "diagnostics"
    if "segment" in s and "tracker_label" in s:
        return "segments"
    if "tracker_label" in s and "estimate_step" in s:
        return "tracks"
    if "in_contact" in s and "contact_x_m" in s:
        return "contacts"
    return None


def _write_parquet(table: pa.Table, sink) -> None:
    """The one place bytes are written (patched in tests to fail midway)."""
    pq.write_table(table, sink, **WRITER_OPTIONS)


def write_table(
    table: pa.Table,
    path: str | os.PathLike,
    *,
    stage: str,
    params: Mapping[str, Any],
    seed: int | None,
    inputs: Mapping[str, str | os.PathLike] | None = None,
    kind: str | None = None,
) -> Path:
    """Validate `table`, attach provenance and write it atomically to `path`.

    Parameters
    ----------
    table : pyarrow.Table
    path : path-like
        Target file; parent directories are created.
    stage : str
        Name of the writing stage (``stucco.stage``).
    params : mapping (or dataclass)
        The stage's parameters; stored as JSON with sorted keys (``stucco.params``). numpy scalars and
        arrays, paths and dataclasses are converted; NaN/inf are refused.
    seed : int or None
        Root seed (``stucco.seed``).
    inputs : mapping role -> path, optional
        Input files; each is recorded by file name and SHA-256 of its bytes (``stucco.inputs``).
    kind : str, optional
        Table kind (``stucco.schema``). Inferred from the columns when omitted; a kind of :data:`TABLES` is
        validated (and written in canonical form), any other kind is written as given.

    Returns
    -------
    pathlib.Path
        `path`.

    Notes
    -----
    The file is written under a temporary name in the target directory and renamed onto `path`
    (``os.replace``), so `path` is either the old file or the complete new one; on any error the temporary
    file is removed. The table's own schema metadata is replaced by the ``stucco.*`` keys. The same table
    and metadata give byte-identical files (fixed :data:`WRITER_OPTIONS`, chunks combined, no timestamps).
    """
    path = Path(path)
    if kind is None:
        kind = _infer_kind(table.column_names)
        if kind is None:
            raise ValueError(f"{path}: cannot tell the table kind from columns {table.column_names}; pass kind=")
    if kind in TABLES:
        table = validate_table(table, kind, path)
    if dataclasses.is_dataclass(params) and not isinstance(params, type):
        params = dataclasses.asdict(params)
    from pipeline import __version__

    recorded = {role: {"file": Path(p).name, "sha256": file_digest(p)} for role, p in (inputs or {}).items()}
    meta = {
        "stucco.stage": stage,
        "stucco.version": __version__,
        "stucco.params": _dumps(dict(params)),
        "stucco.seed": _dumps(None if seed is None else int(seed)),
        "stucco.inputs": _dumps(recorded),
        "stucco.schema": kind,
    }
    table = table.replace_schema_metadata(meta).combine_chunks()

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        with open(tmp, "xb") as f:  # default permissions (umask), unlike mkstemp's 0600
            _write_parquet(table, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def read_metadata(path: str | os.PathLike) -> dict[str, Any]:
    """Decoded ``stucco.*`` schema metadata of a Parquet file, keys without the prefix.

    Returns
    -------
    dict
        Present keys among ``stage``, ``version``, ``schema`` (str), ``params``, ``inputs`` (dict), ``seed``
        (int or None). A file written by other tools gives ``{}``.
    """
    p = Path(path)
    if not p.is_file():
        raise SchemaError(p, None, None, "file not found" if not p.exists() else "is not a file")
    try:
        raw = pq.read_schema(p).metadata or {}
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError, OSError) as e:
        raise SchemaError(p, None, None, f"not a Parquet file ({e})") from None
    out: dict[str, Any] = {}
    for k, v in raw.items():
        key = k.decode()
        if not key.startswith("stucco."):
            continue
        name, text = key[len("stucco."):], v.decode()
        if name in ("params", "inputs", "seed"):
            try:
                out[name] = json.loads(text)
            except json.JSONDecodeError as e:
                raise SchemaError(p, None, None, f"metadata {key} is not valid JSON ({e})") from None
        else:
            out[name] = text
    return out


# --------------------------------------------------------------------------------------------------------
# Access for the stages


@dataclass(frozen=True, eq=False)
class RunContacts:
    """The contacts of one run, grouped by step, as read-only numpy arrays.

    S is the number of steps, R the number of rows (free-space steps have one row, in-contact steps K ≥ 1).

    Attributes
    ----------
    run : str
    step : ndarray, shape (S,), int64
    ee : ndarray, shape (S, 2), metres
        End-effector position after each step.
    in_contact : ndarray, shape (S,), bool
    row_start, row_count : ndarray, shape (S,), int64
        Rows ``row_start[s] : row_start[s] + row_count[s]`` of the row-level arrays belong to step s.
    contact : ndarray, shape (R, 2), metres
        Contact point; NaN on free-space rows.
    dx : ndarray, shape (R, 2), metres
        End-effector displacement while in contact; NaN on free-space rows.
    row_index : ndarray, shape (R,), int64
        Row in the original table (to carry its other columns into outputs).
    object_id : ndarray, shape (R,), int64, or None
        Ground truth when the table has it.
    """

    run: str
    step: np.ndarray
    ee: np.ndarray
    in_contact: np.ndarray
    row_start: np.ndarray
    row_count: np.ndarray
    contact: np.ndarray
    dx: np.ndarray
    row_index: np.ndarray
    object_id: np.ndarray | None = None

    @property
    def n_steps(self) -> int:
        return int(self.step.shape[0])

    @property
    def n_rows(self) -> int:
        return int(self.row_index.shape[0])

    def rows(self, s: int) -> slice:
        """Slice of the row-level arrays for step `s`."""
        start = int(self.row_start[s])
        return slice(start, start + int(self.row_count[s]))

    def observation(self, s: int) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Arguments of ``ContactTracker.update`` for step `s`: ``x (2,)``, ``dx (K, 2)``, ``p (K, 2)``,
        the last two None in free space."""
        if not self.in_contact[s]:
            return self.ee[s], None, None
        r = self.rows(s)
        return self.ee[s], self.dx[r], self.contact[r]


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


def contacts_by_run(table: pa.Table) -> list[tuple[str, RunContacts]]:
    """Split a contacts table into runs (in order of first appearance), grouped by step.

    The table is validated first (cheap), so any contacts table may be passed.

    Returns
    -------
    list of (run, RunContacts)
    """
    table = validate_contacts(table)
    n = table.num_rows
    if n == 0:
        return []
    codes, names = _run_codes(table.column("run"))

    def f64(name):
        return np.asarray(table.column(name).to_numpy(zero_copy_only=False), dtype=np.float64)

    step = np.asarray(table.column("step").to_numpy(), dtype=np.int64)
    ee = np.stack([f64("ee_x_m"), f64("ee_y_m")], axis=1)
    inc = np.asarray(table.column("in_contact").to_numpy(zero_copy_only=False), dtype=bool)
    contact = np.stack([f64("contact_x_m"), f64("contact_y_m")], axis=1)
    dx = np.stack([f64("dx_m"), f64("dy_m")], axis=1)
    oid = (np.asarray(table.column("object_id").to_numpy(), dtype=np.int64)
           if "object_id" in table.column_names else None)

    order = np.argsort(codes, kind="stable")
    bounds = np.searchsorted(codes[order], np.arange(len(names) + 1))
    out = []
    for c, name in enumerate(names):
        rows = order[bounds[c]:bounds[c + 1]]
        s = step[rows]
        starts = np.flatnonzero(np.r_[True, s[1:] != s[:-1]])
        counts = np.diff(np.r_[starts, rows.size])
        head = rows[starts]
        out.append((name, RunContacts(
            run=name,
            step=_readonly(step[head]),
            ee=_readonly(ee[head]),
            in_contact=_readonly(inc[head]),
            row_start=_readonly(starts.astype(np.int64)),
            row_count=_readonly(counts.astype(np.int64)),
            contact=_readonly(contact[rows]),
            dx=_readonly(dx[rows]),
            row_index=_readonly(rows.astype(np.int64)),
            object_id=None if oid is None else _readonly(oid[rows]),
        )))
    return out


# --------------------------------------------------------------------------------------------------------
# Docs


def columns_markdown(kind: str) -> str:
    """Markdown table of the columns of table kind `kind` (used in ``docs/tables.md``)."""
    lines = ["| column | type | unit | required | nullable | values | meaning |",
             "|---|---|---|---|---|---|---|"]
    def cell(text: str) -> str:
        return text.replace("|", "\\|") or "–"

    for c in TABLES[kind].columns:
        lines.append(f"| `{c.name}` | {_type_name(c.type)} | {cell(c.unit)} | {'yes' if c.required else 'no'} "
                     f"| {'yes' if c.nullable else 'no'} | {cell(c.value_rule)} | {cell(c.meaning)} |")
    return "\n".join(lines) + "\n"


def table_markdown(kind: str) -> str:
    """Columns and rules of table kind `kind` as Markdown."""
    rules = "\n".join(f"- {r}" for r in TABLES[kind].rules)
    return f"{columns_markdown(kind)}\nRules:\n\n{rules}\n"
