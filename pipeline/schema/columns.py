"""Column and table spec types: :class:`Column`, :class:`TableSpec` and the column views table rules receive.

A table is described once, as data, with these types (the stage tables in :mod:`pipeline.schema.specs`,
stage-owned tables such as scores and retrieval in their stages); validation (:mod:`pipeline.schema.validate`)
and the column tables of ``docs/tables.md`` (:mod:`pipeline.schema.docs`) are derived from the descriptions.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from pipeline.schema.errors import SchemaError

__all__ = ["Column", "TableSpec", "ColumnViews", "format_bound"]


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
    shape : tuple of int or None
        Empty for a scalar column. Otherwise the column holds nested fixed-size lists of ``type`` elements
        with these sizes (outer first; None: any size, the same in every row), e.g. ``(8, 6)``; ``finite``
        and the bounds apply to every element.
    nan_means_missing : bool
        NaN marks a missing value (e.g. no wrench simulated), so ``finite`` and the bounds skip NaN; ±inf is
        still refused.
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
    shape: tuple[int | None, ...] = ()
    nan_means_missing: bool = False

    @property
    def type_label(self) -> str:
        """The type as messages and docs print it: ``float64``, or ``float64[8, 6]`` for a list column."""
        if not self.shape:
            return _type_name(self.type)
        return f"{_type_name(self.type)}[{', '.join('n' if k is None else str(k) for k in self.shape)}]"

    @property
    def value_rule(self) -> str:
        """The value rule as the docs print it (``values``, or one derived from finite and the bounds)."""
        if self.values:
            return self.values
        parts = []
        if self.finite:
            parts.append("finite or NaN (missing)" if self.nan_means_missing else "finite")
        lo, hi = self.minimum, self.maximum
        if lo is not None and hi is not None:
            parts.append(f"{'(' if self.exclusive_minimum else '['}{format_bound(lo)}, {format_bound(hi)}]")
        elif lo is not None:
            parts.append(f"{'>' if self.exclusive_minimum else '≥'} {format_bound(lo)}")
        elif hi is not None:
            parts.append(f"≤ {format_bound(hi)}")
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
    check: Callable[[ColumnViews], None] | None = dataclasses.field(default=None, repr=False, compare=False)

    def column(self, name: str) -> Column:
        for c in self.columns:
            if c.name == name:
                return c
        raise KeyError(name)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.columns)

    @property
    def required_names(self) -> tuple[str, ...]:
        """The columns every table of this kind has (the optional ones, e.g. ``sim_run``'s ``probe``, left out)."""
        return tuple(c.name for c in self.columns if c.required)


@dataclass
class ColumnViews:
    """Numpy views of the canonical columns of a table under validation (passed to table rules)."""

    path: str
    n: int
    values: dict[str, np.ndarray]  # floats with NaN for null; other types only when the column has no nulls
    null: dict[str, np.ndarray]  # bool (n,)
    run_codes: np.ndarray  # int64 (n,), runs numbered by first appearance
    run_names: list[str]
    arrays: dict = dataclasses.field(default_factory=dict)  # canonical pyarrow columns (for string keys)

    def fail(self, column: str | None, row: int | None, what: str) -> None:
        raise SchemaError(self.path, column, row, what)


def format_bound(x: float) -> str:
    """A bound as messages and docs print it: ``1`` rather than ``1.0``, ``0.5`` as is."""
    return str(int(x)) if float(x).is_integer() else repr(float(x))


def _type_name(t: pa.DataType) -> str:
    """Short name of a canonical column type (``string``, ``int64``, ``float64``, ``bool``), for messages/docs."""
    return {pa.string(): "string", pa.int64(): "int64", pa.float64(): "float64", pa.bool_(): "bool"}.get(t, str(t))

