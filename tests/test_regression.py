"""CI regression on stored runs: replay isolate -> track -> segment -> retrieve -> score on ``data/regression``.

The stored runs (one collected run per Table II task: FB-000, BC-000, IB-001, TC-000, root seed 0) are replayed
for every method and estimator with root seed 0, as ``stucco --seed 0 evaluate --from-runs data/regression`` does,
and compared **exactly** with ``data/regression/expected/{contacts,segments,scores}.parquet``: the contacts, the
segments (tracked points, the tracker's labels, segments), and every score but the wall times (FMI, contact error,
pose errors, grasp success, the low-confidence flag). The pipeline computes the same bits on every x86-64 CPU
(no BLAS/LAPACK in any stage, transcendentals through :mod:`pipeline.portable`, near-ties broken by index:
docs/evaluation.md, "Same numbers on every machine"), so any difference is a change of behaviour; the failure
names the first stage (table) and column that differ.

Regenerate the expected files after an intended change (then review the diff of the report it prints)::

    rm -rf out/regression && .venv/bin/stucco --seed 0 evaluate --from-runs data/regression --methods all \\
        --jobs 2 --no-figures --out out/regression --snapshot data/regression/expected
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline.evaluate import METHODS, EvalConfig, evaluate, snapshot

REGRESSION = Path(__file__).resolve().parents[1] / "data" / "regression"
EXPECTED = REGRESSION / "expected"


@pytest.fixture(scope="module")
def replayed(tmp_path_factory) -> dict[str, pa.Table]:
    out = tmp_path_factory.mktemp("regression") / "ev"
    ev = evaluate(out, None, None, METHODS, EvalConfig(root_seed=0, source=str(REGRESSION)), jobs=2,
                  progress=True, figures=False)
    return snapshot(out, ev.jobs)


def _expected(kind: str) -> pa.Table:
    return pq.read_table(EXPECTED / f"{kind}.parquet").replace_schema_metadata(None)


def _first_difference(stage: str, actual: pa.Table, expected: pa.Table) -> str | None:
    """'<stage>: column c, row r (run, method): got x, expected y' for the first difference, or None."""
    if actual.num_rows != expected.num_rows:
        return f"{stage}: {actual.num_rows} rows, expected {expected.num_rows}"
    for c in expected.column_names:
        if c not in actual.column_names:
            return f"{stage}: column {c!r} missing"
        a, e = actual.column(c).to_pylist(), expected.column(c).to_pylist()
        for i, (x, y) in enumerate(zip(a, e)):
            if x != y and not (isinstance(x, float) and isinstance(y, float) and np.isnan(x) and np.isnan(y)):
                key = actual.column("run")[i].as_py() if "run" in actual.column_names else i
                m = f", {actual.column('method')[i].as_py()}" if "method" in actual.column_names else ""
                est = f", {actual.column('estimator')[i].as_py()}" if "estimator" in actual.column_names else ""
                return f"{stage}: column {c!r}, row {i} ({key}{m}{est}): got {x!r}, expected {y!r}"
    return None


def test_stored_runs_cover_every_task_and_stay_small():
    assert sorted(p.name for p in REGRESSION.glob("*.parquet")) == ["BC-000.parquet", "FB-000.parquet",
                                                                     "IB-001.parquet", "TC-000.parquet"]
    assert sum(p.stat().st_size for p in REGRESSION.rglob("*") if p.is_file()) < 1_000_000


def test_isolation_is_exactly_reproduced(replayed):
    assert _first_difference("isolate (contacts)", replayed["contacts"], _expected("contacts")) is None


def test_tracking_and_segmentation_are_exactly_reproduced(replayed):
    exp = _expected("segments")
    assert sorted(set(exp.column("method").to_pylist())) == sorted(METHODS)
    assert _first_difference("track + segment (segments)", replayed["segments"], exp) is None


def test_retrieval_and_scores_are_exactly_reproduced(replayed):
    assert _first_difference("retrieve + score (scores)", replayed["scores"], _expected("scores")) is None


def test_expected_scores_keep_successes_and_failures():
    # A regression set where every grasp fails (or succeeds) could not see a change of the grasp or of the pose.
    gs = _expected("scores").column("grasp_success").to_pylist()
    assert 0 < sum(gs) < len(gs)
