"""Contacts tables given as CSV (a robot's log written by other tools): the same columns as the Parquet table,
read by the file's extension, then validated like any contacts table (docs/tables.md, "contacts")."""
from __future__ import annotations

import os
from pathlib import Path

import pyarrow as pa
import pyarrow.csv as pcsv

from pipeline.schema.errors import SchemaError

__all__ = ["is_csv", "read_csv"]


def is_csv(path: str | os.PathLike) -> bool:
    """Whether ``path`` names a CSV file (by its extension, ``.csv``)."""
    return Path(path).suffix.lower() == ".csv"


def read_csv(path: str | os.PathLike, columns) -> pa.Table:
    """The table of a CSV file with a header row (a regular file: the caller checks, as
    :func:`pipeline.schema.io.read_contacts` does); each of the spec's ``columns`` (:class:`Column`) it holds read as
    the spec's type (booleans as true/false or 1/0; empty cells are nulls). SchemaError (one line, naming the file
    and, where pyarrow says, the row) for a file that is not CSV of those types."""
    p = Path(path)
    types = {c.name: c.type for c in columns if not getattr(c, "shape", None)}
    convert = pcsv.ConvertOptions(column_types=types, strings_can_be_null=True,
                                  true_values=["true", "True", "TRUE", "1"],
                                  false_values=["false", "False", "FALSE", "0"])
    try:
        return pcsv.read_csv(p, convert_options=convert)
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError, OSError, UnicodeDecodeError) as e:
        raise SchemaError(p, None, None, f"not a CSV contacts table ({str(e).splitlines()[0]})") from None
