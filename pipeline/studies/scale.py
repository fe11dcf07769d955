"""How the evaluation's wall time grows with the grid: `stucco bench scale` (docs/evaluation.md, "Scale").

Each point is one ``evaluate`` of one task from scratch (collection included, no figures) over the first ``n``
seeds, timed from the call to the written report. Beside the wall time it reports the work the jobs booked (the sum
of the scores' per-stage wall times, seconds in the workers), so the parallel efficiency is work / (wall x
workers). The other axis, the contacts of one run, is :mod:`pipeline.studies.scale_contacts`. Measured figures go
in docs/, never here.
"""
from __future__ import annotations

import os
import time
from collections.abc import Sequence
from pathlib import Path

from pipeline.atomic import save_figure, together, write_csv_rows
from pipeline.evaluate import EvalConfig, evaluate

__all__ = ["FIELDS", "scale_rows", "write_outputs"]

#: Columns of ``scale.csv``.
FIELDS = ("scene", "runs", "jobs", "workers", "backend", "wall_s", "work_s", "wall_per_run_s", "efficiency",
          "load_avg")

_STAGES = ("stage_collect_s", "stage_isolate_s", "stage_track_s", "stage_segment_s", "stage_retrieve_s",
           "stage_score_s")


def _work(scores) -> float:
    """Seconds the jobs booked: per job the stages' wall times, collection and isolation counted once per run (every
    job of a run carries them) and retrieval and scoring once per estimator row."""
    rows = scores.to_pylist()
    runs, jobs, total = set(), set(), 0.0
    for r in rows:
        run, job = (r["scene"], r["seed"]), (r["scene"], r["seed"], r["method"])
        if run not in runs:
            runs.add(run)
            total += (r["stage_collect_s"] or 0.0) + (r["stage_isolate_s"] or 0.0)
        if job not in jobs:
            jobs.add(job)
            total += (r["stage_track_s"] or 0.0) + (r["stage_segment_s"] or 0.0)
        total += (r["stage_retrieve_s"] or 0.0) + (r["stage_score_s"] or 0.0)
    return total


def scale_rows(out: str | Path, scene: str, run_counts: Sequence[int], methods: Sequence[str],
               estimators: Sequence[str], *, jobs: int = 2, root_seed: int = 0, max_actions: int | None = None,
               backend: str = "loky", scheduler: str | None = None, progress: bool | None = None) -> list[dict]:
    """Evaluate ``scene`` over seeds 0..n-1 for each n of ``run_counts``, each from scratch in ``out/<scene>-<n>``
    (an existing folder resumes, so its time would not be a measurement: a ValueError names it).

    Returns one dict per n with the columns of :data:`FIELDS` (wall and work in seconds; ``efficiency`` = work /
    (wall x workers); ``load_avg`` the 1-minute load average when the point finished)."""
    out = Path(out)
    rows = []
    for n in run_counts:
        dest = out / f"{scene}-{n}"
        if dest.exists():
            raise ValueError(f"{dest} exists: a resumed evaluation is not a measurement; remove it or choose --out")
        cfg = EvalConfig(root_seed=root_seed, max_actions=max_actions, estimators=tuple(estimators))
        t0 = time.perf_counter()
        ev = evaluate(dest, [scene], list(range(n)), methods, cfg, jobs=jobs, progress=progress, figures=False,
                      backend=backend, scheduler=scheduler)
        wall = time.perf_counter() - t0
        work = _work(ev.scores)
        workers = jobs if backend == "loky" else 0
        rows.append(dict(scene=scene, runs=n, jobs=n * len(methods), workers=workers, backend=backend,
                         wall_s=wall, work_s=work, wall_per_run_s=wall / n,
                         efficiency=work / (wall * workers) if workers else None, load_avg=os.getloadavg()[0]))
    return rows


@together()  # its outputs appear all together or not at all
def write_outputs(rows: list[dict], out: str | Path, png: str | Path | None = None) -> list[Path]:
    """``scale.csv`` and the PNG (wall time and booked work against runs, log-log; ``png`` or
    ``out/scale.png``), each written atomically."""
    import matplotlib  # imported here: only this output draws

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "scale.csv", Path(png or out / "scale.png")]
    write_csv_rows(paths[0], rows, FIELDS)
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    for (scene, backend) in dict.fromkeys((r["scene"], r["backend"]) for r in rows):
        sel = sorted((r for r in rows if r["scene"] == scene and r["backend"] == backend), key=lambda r: r["runs"])
        ax.plot([r["runs"] for r in sel], [r["wall_s"] for r in sel], marker="o", label=f"{scene} wall ({backend})")
        ax.plot([r["runs"] for r in sel], [r["work_s"] for r in sel], marker="x", ls="--",
                label=f"{scene} work in the workers ({backend})")
    ax.set_xscale("log")
    ax.set_yscale("log")
    from matplotlib.ticker import NullFormatter, ScalarFormatter

    ax.set_xticks(sorted({r["runs"] for r in rows}))
    for axis in (ax.xaxis, ax.yaxis):  # plain numbers, no labels on the minor ticks
        axis.set_major_formatter(ScalarFormatter())
        axis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("runs (seeds) of one task")
    ax.set_ylabel("seconds")
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title("stucco evaluate: time against grid size")
    fig.tight_layout()
    paths[1].parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, paths[1], dpi=120, image_format="png")
    return paths
