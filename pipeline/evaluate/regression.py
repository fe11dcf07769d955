"""The regression snapshot: what ``tests/test_regression.py`` compares against ``data/regression/expected``.

docs/evaluation.md, "CI regression on stored runs", says what is compared exactly and what within a tolerance.
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pyarrow as pa

from pipeline import registry, schema
from pipeline.atomic import together
from pipeline.evaluate.config import EvalConfig, Job
from pipeline.evaluate.results import gather_scores
from pipeline.layout import partition
from pipeline.segment import final_estimates

__all__ = ["SNAPSHOT_SCORE_COLUMNS", "snapshot", "write_snapshot"]

#: Score columns compared by the regression test (the others are wall times).
SNAPSHOT_SCORE_COLUMNS = ("scene", "seed", "method", "estimator", "run", "grasp_success", "fmi", "contact_error_cm",
                          "position_error_cm", "yaw_error_rad", "low_confidence", "n_points", "n_segments")


def snapshot(out: str | Path, job_list: Sequence[Job], estimators: Sequence[str] | None = None
             ) -> dict[str, pa.Table]:
    """What the regression test compares, as one table per kind, rows in grid order.

    ``contacts``: the isolate output of every (scene, seed); ``segments``: the track + segment output of every
    job (its final estimate: the estimates after every step, written for the online estimator, are checked
    through its scores), with a leading ``method`` column; ``scores``: :data:`SNAPSHOT_SCORE_COLUMNS` (no wall times).
    """
    out = Path(out)
    jobs_ = sorted(job_list)
    pairs = list(dict.fromkeys((j.scene, j.seed) for j in jobs_))
    contacts = pa.concat_tables([schema.read_contacts(partition(out, "contacts", sc, s)) for sc, s in pairs])
    segs = []
    for j in jobs_:
        t = final_estimates(schema.read_segments(partition(out, "segments", j.scene, j.seed, j.method)))
        segs.append(t.add_column(0, "method", pa.array([j.method] * t.num_rows, pa.string())))
    segments = pa.concat_tables(segs)
    scores = gather_scores(out, jobs_, registry.estimator_names() if estimators is None else estimators).select(
        list(SNAPSHOT_SCORE_COLUMNS))
    return {"contacts": contacts, "segments": segments, "scores": scores}


@together()  # its outputs appear all together or not at all
def write_snapshot(out: str | Path, job_list: Sequence[Job], dest: str | Path, cfg: EvalConfig) -> list[Path]:
    """Write :func:`snapshot` to ``dest/<kind>.parquet`` (the expected results of ``data/regression``)."""
    dest = Path(dest)
    written = []
    for kind, table in snapshot(out, job_list, cfg.estimators).items():
        path = dest / f"{kind}.parquet"
        schema.write_table(table, path, stage="evaluate", params=dict(cfg.to_dict(), snapshot=kind),
                           seed=cfg.root_seed, kind=f"regression-{kind}")
        written.append(path)
    return written
