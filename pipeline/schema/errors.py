"""Errors: :class:`SchemaError`, the one-line error every table check raises.

See ``docs/tables.md`` for the message format users see.
"""
from __future__ import annotations

import os

__all__ = ["SchemaError"]


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

