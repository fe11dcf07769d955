"""The Table II report: grasp success, FMI and contact error per method and scene, beside the paper's figures.

Input is a scores table (one row per scene, seed, method and pose estimator; see :mod:`pipeline.score`). Output
is a list of rows (one per scene, method and estimator) that render as CSV, and as Markdown with one line per
scene and method and the grasp success of every estimator side by side; :func:`claims` checks the paper's two
claims about STUCCO (grasp success of at least 65 % and the lowest contact error on every task).

Only the paper's tasks as shipped (``data/scenes/{FB,BC,IB,TC}.toml``) are compared with the paper: a scene is one
of them when the scores record its digest (``scene_sha256``) and it is the shipped file's, whatever its name, so a
user's own scene named ``FB`` gets neither the paper's figures nor its verdicts (:func:`paper_tasks`). Scores
written before they recorded the digest (no column, or nulls) are taken by their name.

Statistics: GS % = 100 x successes / runs with a grasp attempt; FMI and CE are the mean and the population
standard deviation (``numpy.std``, ddof 0) over runs with a value; null values (no labelled points, no points,
no grasp) are left out, never counted as zero.
"""
from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass

import numpy as np

from pipeline.registry import method_title, tracker_names
from pipeline.scenes.files import shipped_digest

#: The paper's Table II (20 runs per task in simulation): GS %, FMI mean (std), CE cm mean (std).
PAPER_TABLE_II = {
    "FB": {"stucco": (70, 0.69, 0.08, 0.72, 0.25), "birch": (5, 0.62, 0.07, 4.63, 0.53),
           "dbscan": (5, 0.66, 0.10, 3.52, 1.54), "kmeans": (45, 0.63, 0.05, 1.49, 0.40),
           "gmphd": (25, 0.56, 0.05, 3.90, 0.61)},
    "BC": {"stucco": (80, 0.92, 0.05, 1.33, 0.13), "birch": (0, 0.84, 0.09, 6.49, 0.36),
           "dbscan": (10, 0.89, 0.02, 6.56, 0.31), "kmeans": (5, 0.83, 0.04, 7.04, 0.41),
           "gmphd": (0, 0.57, 0.04, 7.33, 0.44)},
    "IB": {"stucco": (65, 0.78, 0.07, 1.04, 0.33), "birch": (0, 0.71, 0.05, 3.27, 0.36),
           "dbscan": (60, 0.75, 0.06, 2.31, 0.58), "kmeans": (10, 0.47, 0.23, 4.84, 1.81),
           "gmphd": (0, 0.46, 0.06, 5.62, 0.85)},
    "TC": {"stucco": (85, 1.00, 0.00, 0.31, 0.90), "birch": (0, 0.79, 0.07, 4.20, 0.22),
           "dbscan": (0, 1.00, 0.00, 4.14, 0.09), "kmeans": (25, 0.54, 0.17, 6.23, 0.72),
           "gmphd": (20, 0.54, 0.17, 8.09, 0.22)},
    # The real robot (§V-E): GS only, over 5 runs; our REAL scene is a simulated stand-in for it (data/scenes).
    "REAL": {"stucco": (100, None, None, None, None), "birch": (20, None, None, None, None),
             "dbscan": (0, None, None, None, None), "kmeans": (20, None, None, None, None),
             "gmphd": (0, None, None, None, None)},
}
#: Runs behind each paper row (Table II's caption): 20 per simulated task, 5 on the real robot.
PAPER_RUNS = {"FB": 20, "BC": 20, "IB": 20, "TC": 20, "REAL": 5}


@dataclass(frozen=True)
class ReportRow:
    """Aggregates of one (scene, method, estimator) over its seeds ("" estimator: scores without the column); a row
    of ``report.csv`` (docs/evaluation.md, "report.csv").

    ``estimator_stream`` is the pose estimators' random stream the scores were made with (``stucco evaluate
    --estimator-stream``, 0 by default), so reports of several streams can be concatenated and told apart.
    """

    scene: str
    method: str
    estimator: str
    estimator_stream: int
    runs: int
    grasp_success_pct: float
    fmi_mean: float
    fmi_std: float
    ce_cm_mean: float
    ce_cm_std: float
    position_error_cm_median: float
    wall_s_mean: float
    track_s_mean: float
    paper_gs_pct: float | None
    paper_fmi_mean: float | None
    paper_fmi_std: float | None
    paper_ce_cm_mean: float | None
    paper_ce_cm_std: float | None


def _ordered(values, order):
    rank = {v: i for i, v in enumerate(order)}
    return sorted(set(values), key=lambda v: (rank.get(v, len(rank)), v))


def paper_tasks(scores) -> set[str]:
    """The scenes of a scores table that are the paper's tasks as shipped: named in :data:`PAPER_TABLE_II`, and
    every digest the table records for them (``scene_sha256``) is the shipped scene file's. Rows without a digest
    (tables written before scores recorded it) do not disqualify a scene."""
    scene = scores.column("scene").to_pylist()
    digests = (scores.column("scene_sha256").to_pylist() if "scene_sha256" in scores.column_names
               else [None] * len(scene))
    seen: dict[str, set] = {}
    for sc, d in zip(scene, digests):
        seen.setdefault(sc, set())
        if d is not None:
            seen[sc].add(d)
    return {sc for sc, ds in seen.items() if sc in PAPER_TABLE_II and ds <= {shipped_digest(sc)}}


def table_ii(scores, estimator_stream: int = 0) -> list[ReportRow]:
    """Aggregate a scores table (pyarrow) into one row per (scene, method, estimator), scenes and methods in paper
    order, estimators in order of first appearance; ``estimator_stream`` (the stream the scores were made with) is
    copied into every row. The paper's figures fill the ``paper_*`` fields of the :func:`paper_tasks` only."""
    # Nulls (a run with no tracked points, or scored without a grasp) are "not measured": floats become NaN and
    # drop out of the statistics, and grasp success counts only runs where a grasp was attempted.
    col = {name: np.array([math.nan if v is None else v for v in scores.column(name).to_pylist()], dtype=float)
           for name in ("fmi", "contact_error_cm", "position_error_cm", "wall_s", "track_s")}
    col["grasp_success"] = np.array([math.nan if v is None else float(v)
                                     for v in scores.column("grasp_success").to_pylist()])
    for name in ("scene", "method"):
        col[name] = np.array(scores.column(name).to_pylist(), dtype=object)
    scene = col["scene"].astype(str)
    method = col["method"].astype(str)
    estimator = (np.array(scores.column("estimator").to_pylist(), dtype=object).astype(str)
                 if "estimator" in scores.column_names else np.full(scores.num_rows, "", dtype=object))
    est_order = tuple(dict.fromkeys(estimator))
    shipped = paper_tasks(scores)
    rows = []
    for sc, m, e in ((sc, m, e) for sc in _ordered(scene, tuple(PAPER_TABLE_II))
                     for m in _ordered(method[scene == sc], tracker_names())
                     for e in _ordered(estimator[(scene == sc) & (method == m)], est_order)):
        sel = (scene == sc) & (method == m) & (estimator == e)

        def stat(name, fn):
            v = col[name][sel].astype(float)
            v = v[np.isfinite(v)]
            return float(fn(v)) if v.size else math.nan

        paper = PAPER_TABLE_II[sc].get(m) if sc in shipped else None
        rows.append(ReportRow(
            scene=sc, method=m, estimator=e, estimator_stream=int(estimator_stream), runs=int(sel.sum()),
            grasp_success_pct=100.0 * stat("grasp_success", np.mean),
            fmi_mean=stat("fmi", np.mean), fmi_std=stat("fmi", np.std),
            ce_cm_mean=stat("contact_error_cm", np.mean), ce_cm_std=stat("contact_error_cm", np.std),
            position_error_cm_median=stat("position_error_cm", np.median), wall_s_mean=stat("wall_s", np.mean),
            track_s_mean=stat("track_s", np.mean),
            paper_gs_pct=None if paper is None else float(paper[0]),
            paper_fmi_mean=None if paper is None else paper[1], paper_fmi_std=None if paper is None else paper[2],
            paper_ce_cm_mean=None if paper is None else paper[3], paper_ce_cm_std=None if paper is None else paper[4],
        ))
    return rows


def _ms(mean, std, fmt):
    return "n/a" if mean is None or (isinstance(mean, float) and math.isnan(mean)) else f"{mean:{fmt}} ({std:{fmt}})"


def _num(v: float, fmt: str) -> str:
    return "n/a" if v is None or math.isnan(v) else f"{v:{fmt}}"


def to_markdown(rows: list[ReportRow]) -> str:
    """Table II layout: one line per scene and method, ours beside the paper's (the paper's columns only when a
    row is one of the paper's tasks as shipped).

    GS % (one column per pose estimator when there are several, the first one's estimator listed first), FMI
    mean (std), CE cm mean (std) and the paper's; median position error of the first estimator's target
    estimate (cm); mean tracking time (the tracker's updates) and mean wall time per run (every stage, collect
    and isolate included) in seconds.
    """
    estimators = list(dict.fromkeys(r.estimator for r in rows))
    gs_head = " | ".join(f"GS % {e}" for e in estimators) if len(estimators) > 1 else "GS %"
    # The paper's columns only beside the paper's tasks: a grid of other scenes (generated ones) has none.
    paper = any(r.paper_gs_pct is not None for r in rows)
    cols = ["task", "method", "runs", gs_head] + (["paper GS %"] if paper else []) + ["FMI"] + \
        (["paper FMI"] if paper else []) + ["CE cm"] + (["paper CE cm"] if paper else []) + \
        ["median pos. err. cm", "track s/run", "s/run"]
    n_cols = len(cols) + max(1, len(estimators)) - 1
    head = "| " + " | ".join(cols) + " |\n|" + "---|" * n_cols
    lines = [head]
    by = {(r.scene, r.method, r.estimator): r for r in rows}
    for r in rows:
        if r.estimator != next(e for e in estimators if (r.scene, r.method, e) in by):
            continue  # one line per (scene, method): the first estimator's row carries the line
        gs = " | ".join(_num(by[(r.scene, r.method, e)].grasp_success_pct, '.0f') if (r.scene, r.method, e) in by
                        else "" for e in estimators)
        cells = [r.scene, method_title(r.method), str(r.runs), gs]
        runs = PAPER_RUNS.get(r.scene, 20)
        paper_gs = "" if r.paper_gs_pct is None else f"{r.paper_gs_pct:.0f}" + (f" ({runs} runs)" if runs != 20 else "")
        cells += [paper_gs] if paper else []
        cells += [_ms(r.fmi_mean, r.fmi_std, ".2f")]
        cells += [_ms(r.paper_fmi_mean, r.paper_fmi_std, ".2f")] if paper else []
        cells += [_ms(r.ce_cm_mean, r.ce_cm_std, '.2f')]
        cells += [_ms(r.paper_ce_cm_mean, r.paper_ce_cm_std, '.2f')] if paper else []
        cells += [_num(r.position_error_cm_median, '.1f'), _num(r.track_s_mean, '.2f'), _num(r.wall_s_mean, '.1f')]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


#: The paper's claims about STUCCO in simulation (Table II).
MIN_GS_PCT = 65.0


def _gs_claim(r: ReportRow, several: bool) -> str:
    tag = f" ({r.estimator} estimator)" if several else ""
    if math.isnan(r.grasp_success_pct):
        return f"GS{tag} not measured"
    if r.grasp_success_pct >= MIN_GS_PCT:
        return f"GS {r.grasp_success_pct:.0f} %{tag} >= {MIN_GS_PCT:.0f} %: holds"
    return (f"GS {r.grasp_success_pct:.0f} %{tag} < {MIN_GS_PCT:.0f} %: short by "
            f"{MIN_GS_PCT - r.grasp_success_pct:.0f} points")


def claims(rows: list[ReportRow], method: str = "stucco") -> list[str]:
    """The paper's two claims checked per scene: ``method`` reaches at least 65 % GS (with each pose estimator),
    and has the lowest mean CE.

    One line per scene where ``method`` was evaluated (nothing when it was not), saying "holds" or by how much it
    falls short; for a scene that is not one of the paper's tasks as shipped (its rows carry no paper figures,
    :func:`table_ii`), a line saying there is nothing to compare, never a verdict.
    """
    out = []
    several = len({r.estimator for r in rows}) > 1
    for sc in dict.fromkeys(r.scene for r in rows):
        here: dict[str, ReportRow] = {}
        for r in rows:
            if r.scene == sc:
                here.setdefault(r.method, r)  # CE does not depend on the estimator: the first row of each method
        ours = here.get(method)
        if ours is None:
            continue
        name = method_title(method)
        if ours.paper_gs_pct is None:
            out.append(f"{sc}: not one of the paper's tasks as shipped (data/scenes/{{FB,BC,IB,TC,REAL}}.toml): no "
                       f"paper figures, no verdict")
            continue
        if ours.paper_fmi_mean is None:  # the real robot's row: GS only, against the baselines (§V-E)
            out.append(f"{sc}: {_above_baselines(rows, sc, method)}; {_ce_claim(here, method)}")
            continue
        gs = "; ".join(_gs_claim(r, several) for r in rows if r.scene == sc and r.method == method)
        out.append(f"{sc}: {name} {gs}; {_ce_claim(here, method)}")
    return out


def _ce_claim(here: dict[str, ReportRow], method: str) -> str:
    """Whether ``method`` has the lowest mean CE among the rows ``here`` (one per method of a scene)."""
    ours = here[method]
    others = {m: r.ce_cm_mean for m, r in here.items() if m != method and not math.isnan(r.ce_cm_mean)}
    if math.isnan(ours.ce_cm_mean) or not others:
        return "lowest CE: not measurable"
    best = min(others, key=others.get)
    if ours.ce_cm_mean < others[best]:
        return f"lowest CE ({ours.ce_cm_mean:.2f} cm, next {method_title(best)} {others[best]:.2f}): holds"
    return (f"lowest CE: no, {ours.ce_cm_mean:.2f} cm vs {method_title(best)} {others[best]:.2f} cm "
            f"(+{ours.ce_cm_mean - others[best]:.2f} cm)")


def _above_baselines(rows: list[ReportRow], scene: str, method: str) -> str:
    """The real row's GS claim (§V-E: ours 100 %, every baseline at most 20 %): ``method``'s best GS over the
    estimators against each baseline's best."""
    best: dict[str, float] = {}
    for r in rows:
        if r.scene == scene and not math.isnan(r.grasp_success_pct):
            best[r.method] = max(best.get(r.method, -1.0), r.grasp_success_pct)
    if method not in best:
        return f"{method_title(method)} GS not measured"
    others = {m: v for m, v in best.items() if m != method}
    gs = f"{method_title(method)} best GS {best[method]:.0f} % (paper 100 %)"
    if others:
        rival = max(others, key=others.get)
        gs += (f", best baseline {method_title(rival)} {others[rival]:.0f} % (paper at most 20 %): above every "
               f"baseline: {'holds' if best[method] > others[rival] else 'no'}")
    return gs


def to_csv(rows: list[ReportRow]) -> str:
    buf = io.StringIO()
    fields = list(ReportRow.__dataclass_fields__)
    w = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if getattr(r, k) is None else getattr(r, k)) for k in fields})
    return buf.getvalue()
