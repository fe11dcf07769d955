"""The tracking methods: one list of their names, in report order, and their titles (paper §V-A).

STUCCO (:mod:`pipeline.track.soft`) and the baselines (:mod:`pipeline.track.cluster`, :mod:`pipeline.track.gmphd`)
are built by :func:`pipeline.track.stage.make_tracker`; every command, the evaluation and the report take the
names from here. To add a tracker, see docs/architecture.md.
"""
from __future__ import annotations

__all__ = ["METHOD_ORDER", "BASELINES", "METHOD_TITLE"]

#: Every method, in the order of the paper's Table II (ours first).
METHOD_ORDER: tuple[str, ...] = ("stucco", "birch", "dbscan", "kmeans", "gmphd")
#: The baselines of the paper's §V-A.
BASELINES: tuple[str, ...] = METHOD_ORDER[1:]
#: Row titles of the report.
METHOD_TITLE: dict[str, str] = {"stucco": "ours (STUCCO)", "birch": "BIRCH", "dbscan": "DBSCAN", "kmeans": "k-means",
                                "gmphd": "GM-PHD"}
