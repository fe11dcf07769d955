"""Small table helpers shared by the studies: statistics that skip nulls, and CSV files written atomically."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pcsv

from pipeline.atomic import atomic_path

__all__ = ["write_csv", "median_of", "mean_of", "percentile_of"]


def write_csv(table: pa.Table, path: Path) -> None:
    """``table`` as CSV at ``path`` (pyarrow's writer), written to a temporary name and renamed."""
    with atomic_path(path) as tmp:
        pcsv.write_csv(table, tmp)


def median_of(v: list) -> float:
    """Median of the finite values of ``v`` (None and NaN left out); NaN if there are none."""
    a = np.asarray([x for x in v if x is not None], dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(np.median(a)) if len(a) else math.nan


def mean_of(v: list) -> float:
    """Mean of the values of ``v`` that are not None (a NaN makes it NaN); NaN if there are none."""
    a = np.asarray([x for x in v if x is not None], dtype=np.float64)
    return float(np.mean(a)) if len(a) else math.nan


def percentile_of(v: list, q: float) -> float:
    """``q``-th percentile (0-100) of the values of ``v`` that are not None; NaN if there are none."""
    a = np.asarray([x for x in v if x is not None], dtype=np.float64)
    return float(np.percentile(a, q)) if len(a) else math.nan
