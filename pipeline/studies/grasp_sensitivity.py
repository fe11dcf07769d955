"""How far a simulated grasp's outcome is reproducible: every scripted grasp of an evaluation simulated again at
its estimate, and again with the estimate or the target's restored position moved by a few micrometres.

A cheaper grasp simulation (fewer settling steps, fewer bodies, a branched state) may replace today's only if its
outcomes agree with today's on at least 99 % of 1,000 grasps (docs/experiments/grasp-simulation-speed.md). This
bench measures how much of that agreement the simulation itself grants: a shift a thousand times smaller than the
replay noise (0.5 mm) changes no physics a robot could feel, so the share of outcomes it flips is a floor on what
any other simulation flips too.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from pipeline.atomic import together, write_csv_rows, write_text
from pipeline.estimators.run_info import load_run
from pipeline.grasp import GraspParams, grasp_at
from pipeline.layout import partition
from pipeline.parallel import run_calls, single_threaded
from pipeline.schema.retrieval import read_retrieval

__all__ = ["SensitivityRow", "PERTURBED", "scripted_grasps", "sensitivity_rows", "summarise", "summary_markdown",
           "write_outputs"]

#: What a shift moves: the estimate the grasp is aimed at, or the target's position in the restored final state.
PERTURBED = ("estimate", "target")


@dataclass
class SensitivityRow:
    """One grasp simulated again with one shift (``shift_m`` 0: unshifted).

    ``table_success`` is the evaluation's verdict, ``success`` this simulation's; ``flipped`` compares it with the
    unshifted simulation's (not the table's, which it equals when the simulation is deterministic)."""

    scene: str
    seed: int
    method: str
    estimator: str
    perturbed: str
    shift_m: float
    table_success: bool
    success: bool
    flipped: bool
    outcome: str


def scripted_grasps(runs_from: str | Path) -> list[dict]:
    """The retrieval rows of an evaluation directory (``stucco evaluate --out``) whose grasp is the scripted one
    (a grasp verdict and no attempts: the active protocol's planned grasps are left out), in file order."""
    out = []
    for f in sorted((Path(runs_from) / "retrieval").glob("*.parquet")):
        if f.name.endswith(".candidates.parquet"):
            continue
        for r in read_retrieval(f).to_pylist():
            if r.get("grasp_success") is not None and r.get("grasp_attempts") is None:
                out.append(r)
    return out


def _one_run(path: Path, rows: Sequence[dict], shifts: Sequence[float], params: GraspParams) -> list[SensitivityRow]:
    """Every grasp of one run file: unshifted, then each shift of each of :data:`PERTURBED`, along +x."""
    with single_threaded():
        info = load_run(path)
        out = []
        for r in rows:
            est = np.array([r["x_m"], r["y_m"], r["yaw_rad"]], dtype=np.float64)
            base = None
            for what, shift in [("estimate", 0.0)] + [(w, s) for w in PERTURBED for s in shifts]:
                poses, aim = info.final_poses.copy(), est.copy()
                if what == "estimate":
                    aim[0] += shift
                else:
                    poses[info.target_id, 0] += shift
                g = grasp_at(info.scene, poses, info.final_ee, aim, params, info.final_tilted)
                base = bool(g.success) if base is None else base
                out.append(SensitivityRow(r["scene"], int(r["seed"]), r["method"], r["estimator"],
                                          what if shift else "none", float(shift), bool(r["grasp_success"]),
                                          bool(g.success), bool(g.success) != base, g.outcome))
        return out


def sensitivity_rows(runs_from: str | Path, shifts_m: Sequence[float], jobs: int = 1,
                     progress: Callable | None = None, params: GraspParams = GraspParams()) -> list[SensitivityRow]:
    """Every scripted grasp of the evaluation directory ``runs_from``, simulated unshifted and with each shift
    (metres, > 0) of the estimate and of the target; one job per run file; rows in the retrieval tables' order.
    ``progress`` wraps the iterable of finished runs (``progress(iterable, total=)``)."""
    if any(not (s > 0.0 and np.isfinite(s)) for s in shifts_m):
        raise ValueError(f"shifts {list(shifts_m)}: expected positive numbers of metres")
    by_run: dict[tuple[str, int], list[dict]] = {}
    for r in scripted_grasps(runs_from):
        by_run.setdefault((r["scene"], int(r["seed"])), []).append(r)
    if not by_run:
        raise ValueError(f"{Path(runs_from) / 'retrieval'}: no scripted grasp to simulate (run `stucco evaluate` "
                         "with the scripted policy first)")
    args = []
    for (scene, seed), rows in by_run.items():
        path = partition(Path(runs_from), "runs", scene, seed)
        if not path.is_file():
            raise ValueError(f"{path}: no run file for {scene} seed {seed}, whose grasps the retrieval tables hold")
        args.append((path, rows, tuple(float(s) for s in shifts_m), params))
    results = run_calls(_one_run, args, jobs)
    if progress is not None:
        results = progress(results, total=len(args))
    return [row for chunk in results for row in chunk]


def summarise(rows: Sequence[SensitivityRow]) -> list[dict]:
    """Per simulation (unshifted, then each perturbed quantity and shift): grasps, successes, outcomes that differ
    from the unshifted simulation's (from the evaluation's table, for the unshifted one) and the agreement, %."""
    keys = list(dict.fromkeys((r.perturbed, r.shift_m) for r in rows))
    out = []
    for what, shift in keys:
        sel = [r for r in rows if (r.perturbed, r.shift_m) == (what, shift)]
        differ = sum(r.success != r.table_success for r in sel) if what == "none" else sum(r.flipped for r in sel)
        out.append({"perturbed": what, "shift_um": round(shift * 1e6, 3), "grasps": len(sel),
                    "successes": sum(r.success for r in sel), "differ": differ,
                    "agreement_pct": round(100.0 * (1.0 - differ / len(sel)), 2) if sel else float("nan")})
    return out


def summary_markdown(summary: Sequence[dict]) -> str:
    """The summary as a markdown table."""
    lines = ["| simulation | grasps | successes | outcomes that differ | agreement % |", "|---|---|---|---|---|"]
    for s in summary:
        name = ("unshifted (against the evaluation's table)" if s["perturbed"] == "none"
                else f"{s['perturbed']} moved {s['shift_um']:g} um along x (against unshifted)")
        lines.append(f"| {name} | {s['grasps']} | {s['successes']} | {s['differ']} | {s['agreement_pct']:.2f} |")
    return "\n".join(lines) + "\n"


@together()  # its outputs appear all together or not at all
def write_outputs(rows: Sequence[SensitivityRow], out: str | Path) -> tuple[Path, Path]:
    """``sensitivity.csv`` (one row per simulated grasp) and ``sensitivity_summary.md`` into ``out``, atomically."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    fields = list(SensitivityRow.__dataclass_fields__)
    a = write_csv_rows(out / "sensitivity.csv", [asdict(r) for r in rows], fields)
    b = write_text(out / "sensitivity_summary.md", summary_markdown(summarise(rows)))
    return a, b
