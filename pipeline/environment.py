"""The software environment a result was computed in: Python and the versions of the libraries that compute.

Recorded in every table's provenance (``stucco.environment``, :mod:`pipeline.schema.io`) and at the foot of
``report.md``, so that two results can be compared knowing whether they came from the same locked environment
(``requirements.lock``, docs/evaluation.md "Same numbers on every machine").
"""
from __future__ import annotations

import platform
from functools import lru_cache
from importlib.metadata import PackageNotFoundError, version

__all__ = ["COMPUTING_DISTRIBUTIONS", "environment", "environment_line"]

#: The distributions whose code computes a number of some table (the rest of the lock only serves them).
COMPUTING_DISTRIBUTIONS: tuple[str, ...] = ("numpy", "scipy", "scikit-learn", "numba", "llvmlite", "open3d-cpu",
                                            "pybullet", "pyarrow")


@lru_cache(maxsize=1)
def environment() -> dict[str, str]:
    """``{"python": "3.11.7", "numpy": "2.4.6", ...}``: Python's version and each of
    :data:`COMPUTING_DISTRIBUTIONS` ("not installed" when absent, e.g. open3d installed as ``open3d``)."""
    out = {"python": platform.python_version()}
    for name in COMPUTING_DISTRIBUTIONS:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "not installed"
    return out


def environment_line() -> str:
    """One line for a report: ``python 3.11.7, numpy 2.4.6, ...``."""
    return ", ".join(f"{k} {v}" for k, v in environment().items())
