"""stucco pipeline: the stages (collect, isolate, track, segment, retrieve, score, evaluate) and their algorithms.

Each stage reads and writes Parquet tables described in :mod:`pipeline.schema`; the click CLI in
:mod:`stucco_cli` only parses options, calls these functions and reports.
"""
from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _version

try:
    __version__ = _version("stucco")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0+unknown"
