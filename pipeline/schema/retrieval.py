"""The ``retrieval`` and ``candidates`` tables: validation, reading and building (their specs, columns with units,
are in :mod:`pipeline.schema.results`, with the other stage tables)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from pipeline import schema
from pipeline.schema.results import CANDIDATES, CANDIDATES_COLUMNS, RETRIEVAL, RETRIEVAL_COLUMNS

__all__ = ["RETRIEVAL_COLUMNS", "CANDIDATES_COLUMNS", "RETRIEVAL", "CANDIDATES", "validate_retrieval",
           "validate_candidates", "read_retrieval", "retrieval_table", "candidates_table", "run_candidates",
           "CANDIDATE_FIELDS"]

#: The columns an estimator gives for each candidate: every candidates column but ``run`` (the stage adds it).
CANDIDATE_FIELDS: tuple[str, ...] = tuple(c.name for c in CANDIDATES_COLUMNS if c.name != "run")


def validate_retrieval(table: pa.Table, path: str | Path = "<table>") -> pa.Table:
    """Validate a retrieval table (one-line SchemaError)."""
    return schema.validate_spec(table, RETRIEVAL, path)


def validate_candidates(table: pa.Table, path: str | Path = "<table>") -> pa.Table:
    return schema.validate_spec(table, CANDIDATES, path)


def read_retrieval(path: str | Path) -> pa.Table:
    """Read and validate a retrieval table written by ``stucco retrieve`` (a file of another kind is refused by
    name, :func:`pipeline.schema.read_table`)."""
    return schema.read_table(path, "retrieval")


def retrieval_table(rows: list[dict[str, Any]]) -> pa.Table:
    """Rows (dicts keyed by :data:`RETRIEVAL_COLUMNS`) -> validated retrieval table."""
    arrays = {c.name: pa.array([r[c.name] for r in rows], type=c.type) for c in RETRIEVAL_COLUMNS}
    return validate_retrieval(pa.table(arrays))


def run_candidates(**columns) -> dict[str, np.ndarray]:
    """One run's candidates, as an estimator returns them
    (:attr:`pipeline.estimators.paper.choice.Estimate.candidates`): every column of :data:`CANDIDATES_COLUMNS` but
    ``run`` (the stage adds it), each an array of one length. ValueError naming a missing or unknown column, or a length
    that differs."""
    names = CANDIDATE_FIELDS
    missing = [n for n in names if n not in columns]
    extra = sorted(set(columns) - set(names))
    if missing or extra:
        raise ValueError(f"candidates: missing column(s) {missing}, unknown column(s) {extra}; expected "
                         f"{', '.join(names)}")
    out = {n: np.asarray(columns[n]) for n in names}
    lengths = {len(v) for v in out.values()}
    if len(lengths) > 1:
        raise ValueError(f"candidates: columns of different lengths {sorted(lengths)}")
    return out


def candidates_table(parts: list[dict[str, np.ndarray]]) -> pa.Table:
    """Per-run candidate columns -> validated candidates table."""
    arrays = {}
    for c in CANDIDATES_COLUMNS:
        vals = [p[c.name] for p in parts if len(p[c.name])]
        data = np.concatenate(vals) if vals else np.zeros(0)
        if c.type == pa.string():
            arrays[c.name] = pa.array(data.tolist() if len(data) else [], type=pa.string())
        elif c.name == "position_var_m2":
            data = np.asarray(data, dtype=np.float64)
            arrays[c.name] = pa.array(data, type=pa.float64(), mask=~np.isfinite(data))
        else:
            arrays[c.name] = pa.array(np.asarray(data).astype(c.type.to_pandas_dtype()), type=c.type)
    return validate_candidates(pa.table(arrays))
