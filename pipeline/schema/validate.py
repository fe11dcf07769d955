"""Validation engine: checks a ``pyarrow.Table`` against any :class:`~pipeline.schema.columns.TableSpec`.

Per column: presence, accepted type (cast to the canonical one), nulls, finiteness and bounds; then the spec's
own rule (``TableSpec.check``, e.g. :mod:`pipeline.schema.rules`) on numpy views of the columns. The first
problem raises a one-line :class:`~pipeline.schema.errors.SchemaError` naming the file, the column and the
first bad row (``docs/tables.md``). Also the helpers the table rules share (first bad row, value formatting,
run grouping, step order).
"""
from __future__ import annotations

import os
from typing import Any

import numpy as np
import pyarrow as pa

from pipeline.schema.columns import Column, ColumnViews, TableSpec, format_bound
from pipeline.schema.errors import SchemaError

__all__ = ["validate_spec", "encode_runs", "format_value", "first_row", "check_steps_nondecreasing"]


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
        return pa.types.is_boolean(t) or pa.types.is_integer(t)  # integers: 0/1 only (checked on cast)
    return t == target


def _accepts_column(c: Column, t: pa.DataType) -> bool:
    """Whether a column of type `t` is accepted for `c` (nested fixed-size lists of `c.shape` for a list column)."""
    for size in c.shape:
        if size is None and (pa.types.is_list(t) or pa.types.is_large_list(t)):
            t = t.value_type  # one length per file, checked on the values
            continue
        if not pa.types.is_fixed_size_list(t) or (size is not None and t.list_size != size):
            return False
        t = t.value_type
    return _accepts(c.type, t) and not pa.types.is_null(t) if c.shape else _accepts(c.type, t)


def _list_values(col: pa.ChunkedArray, c: Column, path: str) -> np.ndarray:
    """A nested-list column as a float array (rows, *sizes); null elements become NaN. A variable-size level
    (``None`` in ``c.shape``) must have one length in the whole file."""
    arr = col.combine_chunks()
    sizes = []
    for _ in c.shape:
        if pa.types.is_fixed_size_list(arr.type):
            sizes.append(arr.type.list_size)
        else:
            lengths = np.asarray(arr.value_lengths().fill_null(0).to_numpy(zero_copy_only=False))
            rows = int(np.prod(sizes)) if sizes else 1
            if lengths.size and (r := first_row(lengths != lengths[0])) is not None:
                raise SchemaError(path, c.name, r // rows, f"has {int(lengths[r])} elements where the first row has "
                                                           f"{int(lengths[0])}; expected one length in a file")
            sizes.append(int(lengths[0]) if lengths.size else 0)
        arr = arr.flatten()
    v = np.asarray(arr.to_numpy(zero_copy_only=False), dtype=np.float64)
    return v.reshape((len(col), *sizes))


_ACCEPTED = {
    pa.string(): "string (string, large_string or dictionary of strings)",
    pa.int64(): "int64 (any integer type is accepted)",
    pa.float64(): "float64 (any float or integer type is accepted)",
    pa.bool_(): "bool (or integers 0/1)",
}


def encode_runs(col: pa.ChunkedArray) -> tuple[np.ndarray, list[str]]:
    # dictionary_encode numbers values by first appearance, which is the run order we promise.
    enc = col.combine_chunks().dictionary_encode()
    return enc.indices.to_numpy(zero_copy_only=False).astype(np.int64), enc.dictionary.to_pylist()


def format_value(v: Any) -> str:
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, (np.integer,)):
        return str(int(v))
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    return repr(v)


def _rows(mask: np.ndarray) -> np.ndarray:
    """A per-row mask from a per-row or (rows, elements) mask."""
    return mask if mask.ndim == 1 else mask.any(axis=1)


def _what(value: Any, bad: Any, shape: tuple[int, ...]) -> str:
    """'is X' for a scalar value; 'has X at [i, j]' for a list column's row (flattened `value`, `bad`)."""
    if not shape:
        return f"is {format_value(value)}"
    i = int(np.flatnonzero(bad)[0])
    index = ", ".join(str(int(k)) for k in np.unravel_index(i, shape))
    return f"has {format_value(value[i])} at [{index}]"


def first_row(mask: np.ndarray) -> int | None:
    idx = np.flatnonzero(mask)
    return int(idx[0]) if idx.size else None


def validate_spec(table: pa.Table, spec: TableSpec, path: str | os.PathLike = "<table>") -> pa.Table:
    """Validate a table against any :class:`TableSpec` (stages that own their tables use this)."""
    path = str(path)
    if not isinstance(table, pa.Table):
        raise TypeError(f"expected a pyarrow.Table, got {type(table).__name__}")
    names = table.column_names
    for c in spec.columns:
        k = names.count(c.name)
        if k == 0 and c.required:
            raise SchemaError(path, c.name, None,
                              f"missing; expected {c.type_label}"
                              f"{f' in {c.unit}' if c.unit else ''} ({c.meaning.rstrip('.')})")
        if k > 1:
            raise SchemaError(path, c.name, None, f"appears {k} times; expected once")
    present = [c for c in spec.columns if c.name in names]
    for c in present:
        t = table.schema.field(c.name).type
        if not _accepts_column(c, t):
            expected = (f"nested fixed-size lists {c.type_label}" if c.shape else _ACCEPTED.get(c.type, c.type))
            raise SchemaError(path, c.name, None, f"has type {t}; expected {expected}")

    n = table.num_rows
    arrays: dict[str, pa.ChunkedArray] = {}
    values: dict[str, np.ndarray] = {}
    null: dict[str, np.ndarray] = {}
    for c in present:
        col = table.column(c.name)
        if pa.types.is_uint64(col.type) and c.type == pa.int64():
            big = np.asarray(col.to_numpy(zero_copy_only=False)) > np.iinfo(np.int64).max
            if (r := first_row(big)) is not None:
                raise SchemaError(path, c.name, r, f"{col[r].as_py()} does not fit in int64")
        if c.type == pa.bool_() and pa.types.is_integer(col.type):
            ints = np.asarray(col.fill_null(0).to_numpy(zero_copy_only=False))
            if (r := first_row((ints != 0) & (ints != 1))) is not None:
                raise SchemaError(path, c.name, r, f"is {int(ints[r])}; expected a boolean (true/false, or 1/0)")
        if col.type != c.type and not c.shape:
            col = col.cast(c.type)
        arrays[c.name] = col
        isnull = col.is_null().to_numpy(zero_copy_only=False) if col.null_count else np.zeros(n, bool)
        null[c.name] = np.asarray(isnull, dtype=bool)
        if not c.nullable and (r := first_row(null[c.name])) is not None:
            raise SchemaError(path, c.name, r, "is null; expected a value (this column is never null)")
        if c.shape:
            v = _list_values(col, c, path)
        elif c.type == pa.float64():
            v = np.asarray(col.to_numpy(zero_copy_only=False), dtype=np.float64)  # null -> NaN
        elif c.type == pa.string():
            v = None  # runs are handled through codes
        else:
            v = np.asarray(col.to_numpy(zero_copy_only=False))
        if v is not None:
            values[c.name] = v
            ok = ~null[c.name]
            shape = v.shape[1:]
            if c.shape:  # a row is bad when any of its elements is
                v = v.reshape(n, int(np.prod(shape)))
                ok = ok[:, None]
            if c.nan_means_missing:
                ok = ok & ~np.isnan(v)
            if c.finite and (r := first_row(_rows(ok & ~np.isfinite(v)))) is not None:
                raise SchemaError(path, c.name, r, f"{_what(v[r], ok[r] & ~np.isfinite(v[r]), shape)}; "
                                                   "expected a finite value")
            with np.errstate(invalid="ignore"):
                if c.minimum is not None:
                    below = ok & ((v <= c.minimum) if c.exclusive_minimum else (v < c.minimum))
                    if (r := first_row(_rows(below))) is not None:
                        bound = ("greater than " if c.exclusive_minimum else "at least ") + format_bound(c.minimum)
                        raise SchemaError(path, c.name, r, f"{_what(v[r], below[r], shape)}; expected {bound}"
                                                           f"{_unit_hint(c)}")
                if c.maximum is not None and (r := first_row(_rows(above := ok & (v > c.maximum)))) is not None:
                    raise SchemaError(path, c.name, r, f"{_what(v[r], above[r], shape)}; expected at most "
                                                       f"{format_bound(c.maximum)}{_unit_hint(c)}")

    codes, run_names = encode_runs(arrays["run"]) if "run" in arrays else (np.zeros(n, np.int64), [])
    cols = ColumnViews(path, n, values, null, codes, run_names, arrays)
    if spec.check is not None:
        spec.check(cols)

    extra = [i for i, name in enumerate(names) if name not in spec.names]  # by index: names may repeat
    out_fields = [pa.field(c.name, arrays[c.name].type if c.shape else c.type, nullable=True) for c in present]
    out_fields += [table.schema.field(i) for i in extra]
    return pa.Table.from_arrays([arrays[c.name] for c in present] + [table.column(i) for i in extra],
                                schema=pa.schema(out_fields))


def _sorted_by_run(cols: ColumnViews) -> tuple[np.ndarray, np.ndarray]:
    """(order, same): rows grouped by run in first-appearance order, file order kept within a run; `same[i]`
    says sorted rows i and i+1 belong to the same run."""
    order = np.argsort(cols.run_codes, kind="stable")
    rc = cols.run_codes[order]
    return order, rc[1:] == rc[:-1]


def check_steps_nondecreasing(cols: ColumnViews, strict: bool, why: str) -> tuple[np.ndarray, np.ndarray]:
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


def _unit_hint(c) -> str:
    """What a length out of its plausible range most likely is: another unit (a run or segments file in cm)."""
    return " (m; a length beyond it is almost certainly in cm or mm: metres are expected)" if c.unit.startswith("m") \
        and c.name.endswith("_m") else ""
