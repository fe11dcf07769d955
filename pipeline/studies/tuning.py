"""``stucco study tune``: one parameter per method swept on the training set, chosen by :func:`choose_setting`.

docs/studies.md, ``stucco study tune``; the defaults (Table I, §V-B) are not changed by the command.
"""
from __future__ import annotations

import json
import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from pipeline import registry
from pipeline.constraints import plain
from pipeline.studies.tables import median_of, write_csv
from pipeline.studies.training import TRAINING_SCENES, TRAINING_SEEDS, load_training, score_methods

__all__ = ["choose_setting", "tune", "dataclass_dict"]


def choose_setting(stats: Sequence[dict[str, float]], fmi_tolerance: float = 0.01) -> int:
    """Index of the chosen setting: highest median FMI; among those within ``fmi_tolerance`` of it, the lowest
    median CE (the paper maximised median FMI and minimised median CE; FMI first, CE breaks near-ties)."""
    f = np.array([s["fmi"] for s in stats], dtype=float)
    c = np.array([s["ce_cm"] for s in stats], dtype=float)
    ok = np.isfinite(f)
    if not ok.any():
        raise ValueError("no setting has a finite median FMI")
    near = np.flatnonzero(ok & (f >= np.nanmax(f) - fmi_tolerance))
    cc = np.where(np.isfinite(c[near]), c[near], np.inf)
    return int(near[np.argmin(cc)])


def tune(out: str | Path, grid: dict[str, tuple[str, Sequence[float]]] | None = None,
         scenes: Sequence[str] = TRAINING_SCENES, seeds: Sequence[int] = TRAINING_SEEDS, *, root_seed: int = 0,
         jobs: int = 1, progress: bool | None = None, max_actions: int | None = None) -> dict[str, Any]:
    """Sweep one parameter per method on the training set (collected if needed, as
    :func:`pipeline.studies.training_study`); ``out/tune.csv`` holds the medians of every value; returns the chosen
    value per method (:func:`choose_setting`). The default grid is every tracker's ``tune`` entry in
    :mod:`pipeline.registry` (Table I / §V-B values included: STUCCO l = 0.02, BIRCH 0.08, DBSCAN 0.05, k-means
    inertia ratio and GM-PHD detection at their defaults)."""
    t0 = time.perf_counter()
    out = Path(out)
    grid = dict(grid or registry.tune_grid())
    _, contacts, truths = load_training(out, scenes, seeds, root_seed, jobs, progress, max_actions)
    settings = [(m, {p: v}) for m, (p, vals) in grid.items() for v in vals]
    rows = score_methods(contacts, truths, settings, root_seed, jobs, progress)
    summary, chosen = [], {}
    for m, (p, vals) in grid.items():
        stats = []
        for v in vals:
            sub = [r for r in rows if r["method"] == m and json.loads(r["params"]) == {p: v}]
            stats.append(dict(method=m, parameter=p, value=v, runs=len(sub), fmi=median_of([r["fmi"] for r in sub]),
                              ce_cm=median_of([r["contact_error_cm"] for r in sub])))
        i = choose_setting(stats)
        default = dataclass_dict(registry.build_params(registry.tracker(m)))[p]
        for j, s in enumerate(stats):
            s["chosen"] = j == i
            s["default"] = math.isclose(s["value"], float(default))
        summary.extend(stats)
        chosen[m] = dict(parameter=p, value=stats[i]["value"], default=default, fmi=stats[i]["fmi"],
                         ce_cm=stats[i]["ce_cm"])
    write_csv(pa.Table.from_pylist(summary), out / "tune.csv")
    return dict(chosen=chosen, table=summary, runs=len(truths), wall_s=time.perf_counter() - t0)


def dataclass_dict(obj) -> dict[str, Any]:
    """A baseline's parameters as a dict (:func:`pipeline.constraints.plain`)."""
    return plain(obj)
