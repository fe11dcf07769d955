"""How each stage's time grows with the contacts of one run: ``stucco bench scale --contacts`` (docs/evaluation.md,
"Scale").

Each size is one run of one task collected with the ``rummage`` policy (:class:`pipeline.policies.RummagePolicy`)
until that many actions have ended in contact, then isolated, tracked, segmented, retrieved and scored, one stage
after the other in this process (the evaluation's own stage functions, single-threaded as its workers are), each
timed in wall seconds and CPU seconds of this process. A first, small run (the warm-up) pays the imports and
numba's compilation and loading; its row is kept apart. Measured figures go in docs/, never here.
"""
from __future__ import annotations

import math
import os
import time
from collections.abc import Sequence
from pathlib import Path

import pyarrow.compute as pc
import pyarrow.parquet as pq

from pipeline.atomic import save_figure, together, write_csv_rows
from pipeline.collect import collect_file
from pipeline.evaluate import EvalConfig, Job, single_threaded
from pipeline.evaluate.stages import run_isolate, run_retrieve, run_score, run_segment, run_track
from pipeline.layout import STAGES, job_paths
from pipeline.policies import RummageParams
from pipeline.safe_open import regular_file

__all__ = ["CONTACT_FIELDS", "WARMUP_CONTACTS", "contact_rows", "growth", "write_contact_outputs"]

#: Columns of ``scale_contacts.csv``: one row per (run, stage[, estimator]); ``requested`` is the rummage's
#: target, ``contacts`` the isolated contacts of the run's contacts table (what the tracker gets), ``actions`` the
#: run's actions.
CONTACT_FIELDS = ("scene", "seed", "requested", "actions", "contacts", "warmup", "stage", "estimator", "wall_s",
                  "cpu_s", "load_avg")
#: Contacts of the warm-up run (the imports and numba's compilation, timed but kept apart).
WARMUP_CONTACTS = 5


def _timed(fn, *args) -> tuple[float, float]:
    """(wall s, CPU s of this process) of ``fn(*args)``."""
    w0, c0 = time.perf_counter(), time.process_time()
    fn(*args)
    return time.perf_counter() - w0, time.process_time() - c0


def _one_run(dest: Path, scene: str, seed: int, contacts: int, method: str, estimators: Sequence[str],
             cfg: EvalConfig, warmup: bool) -> list[dict]:
    job = Job(scene, seed, method)
    p = job_paths(dest, job, estimators)
    sc = cfg.scene(scene)

    def collect() -> None:
        collect_file(sc, seed, p["runs"], root_seed=cfg.root_seed, policy="rummage",
                     policy_params=RummageParams(contacts=contacts))

    times: list[tuple[str, str, float, float]] = []
    with single_threaded():
        times.append(("collect", "", *_timed(collect)))
        times.append(("isolate", "", *_timed(run_isolate, p, cfg)))
        times.append(("track", "", *_timed(run_track, p, method, cfg)))
        times.append(("segment", "", *_timed(run_segment, p, cfg)))
        for est in estimators:
            times.append(("retrieve", est, *_timed(run_retrieve, p, method, cfg, est)))
        walls = {(s, e): wall for s, e, wall, _ in times}  # what each estimator's scores record
        for est in estimators:
            earlier = {s: walls[(s, "")] for s in ("collect", "isolate", "track", "segment")}
            earlier["retrieve"] = walls[("retrieve", est)]
            times.append(("score", est, *_timed(run_score, p, cfg, est, earlier)))
    load = os.getloadavg()[0]
    actions = pq.read_metadata(regular_file(p["runs"], "the run file")).num_rows
    xs = pq.read_table(regular_file(p["contacts"], "the contacts file"), columns=["contact_x_m"]).column(0)
    n_contacts = len(xs) - xs.null_count - int(pc.sum(pc.is_nan(xs)).as_py() or 0)
    return [dict(scene=scene, seed=seed, requested=contacts, actions=actions, contacts=n_contacts, warmup=warmup,
                 stage=stage, estimator=est, wall_s=wall, cpu_s=cpu, load_avg=load)
            for stage, est, wall, cpu in times]


def contact_rows(out: str | Path, scene: str, contact_counts: Sequence[int], method: str,
                 estimators: Sequence[str], *, root_seed: int = 0, seed: int = 0,
                 progress=None) -> list[dict]:
    """Time every stage on one run of ``scene`` (run seed ``seed``) per size of ``contact_counts``, after a warm-up
    run of :data:`WARMUP_CONTACTS` contacts; each in ``out/<scene>-c<N>`` (``out/<scene>-warmup``), made from
    scratch (an existing folder raises ValueError naming it).

    Returns
    -------
    list of dict
        The rows of :data:`CONTACT_FIELDS` (seconds), the warm-up's first; ``progress(text)`` is called before
        each run when given.
    """
    out = Path(out)
    sizes = [("warmup", WARMUP_CONTACTS)] + [(f"c{n}", n) for n in contact_counts]
    for tag, _ in sizes:
        if (out / f"{scene}-{tag}").exists():
            raise ValueError(f"{out / f'{scene}-{tag}'} exists: a rerun stage is not a measurement; remove it or "
                             "choose --out")
    cfg = EvalConfig(root_seed=root_seed, estimators=tuple(estimators))
    rows: list[dict] = []
    for tag, n in sizes:
        if progress is not None:
            progress(f"{scene} seed {seed}: {n} contacts")
        rows += _one_run(out / f"{scene}-{tag}", scene, seed, n, method, estimators, cfg, warmup=tag == "warmup")
    return rows


def _label(r: dict) -> str:
    return r["stage"] + (f" ({r['estimator']})" if r["estimator"] else "")


def growth(rows: list[dict]) -> dict[str, float | None]:
    """Stage label -> the exponent b of CPU s ~ contacts^b, a least-squares line through the log-log points of the
    measured (not warm-up) runs; None with fewer than two sizes or a zero time."""
    out: dict[str, float | None] = {}
    for label in dict.fromkeys(_label(r) for r in rows if not r["warmup"]):
        pts = [(r["contacts"], r["cpu_s"]) for r in rows if not r["warmup"] and _label(r) == label]
        if len({x for x, _ in pts}) < 2 or any(x <= 0 or y <= 0 for x, y in pts):
            out[label] = None
            continue
        xs, ys = [math.log(x) for x, _ in pts], [math.log(y) for _, y in pts]
        mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
        out[label] = sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)
    return out


@together()  # its outputs appear all together or not at all
def write_contact_outputs(rows: list[dict], out: str | Path, png: str | Path | None = None) -> list[Path]:
    """``scale_contacts.csv`` and the PNG (CPU seconds of each stage against the run's contacts, log-log, with the
    total's wall time; ``png`` or ``out/scale_contacts.png``), each written atomically."""
    import matplotlib  # imported here: only this output draws

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, NullFormatter, ScalarFormatter

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "scale_contacts.csv", Path(png or out / "scale_contacts.png")]
    write_csv_rows(paths[0], rows, CONTACT_FIELDS)
    measured = [r for r in rows if not r["warmup"]]
    fig, ax = plt.subplots(figsize=(6.0, 4.0))
    order = {s: i for i, s in enumerate(STAGES)}
    for label in sorted(dict.fromkeys(_label(r) for r in measured), key=lambda s: (order[s.split()[0]], s)):
        sel = sorted((r for r in measured if _label(r) == label), key=lambda r: r["contacts"])
        ax.plot([r["contacts"] for r in sel], [max(r["cpu_s"], 1e-3) for r in sel], marker="o", label=label)
    totals: dict[int, float] = {}
    for r in measured:
        totals[r["contacts"]] = totals.get(r["contacts"], 0.0) + r["wall_s"]
    xs = sorted(totals)
    ax.plot(xs, [totals[x] for x in xs], color="black", ls="--", marker="x", label="all stages, wall")
    if len(xs) > 1:  # guides through the top total: what linear and quadratic growth would look like
        top = totals[xs[-1]]
        for power, style in ((1, ":"), (2, "-.")):
            ax.plot([xs[0], xs[-1]], [top * (xs[0] / xs[-1]) ** power, top], color="grey", ls=style, lw=0.8,
                    label=f"~ contacts^{power}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xticks(xs)
    ax.xaxis.set_major_formatter(ScalarFormatter())
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))  # 0.01, not ScalarFormatter's 0.0
    for axis in (ax.xaxis, ax.yaxis):  # no labels on the minor ticks
        axis.set_minor_formatter(NullFormatter())
    scene = measured[0]["scene"] if measured else ""
    ax.set_xlabel(f"contacts in the run ({scene}, one run per size)")
    ax.set_ylabel("seconds (stages: CPU; total: wall)")
    ax.legend(loc="upper left", fontsize=7)
    ax.set_title("stucco: stage time against contacts per run")
    fig.tight_layout()
    paths[1].parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, paths[1], dpi=120, image_format="png")
    return paths
