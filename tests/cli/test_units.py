"""One length unit per scores table: the position error in cm beside the contact error in cm (yaw in rad)."""
from __future__ import annotations

import pyarrow.parquet as pq

from pipeline import schema
from pipeline.report import table_ii
from pipeline.schema.results import SCORES_COLUMNS

REGRESSION = __import__("pathlib").Path(__file__).resolve().parents[2] / "data" / "regression" / "expected"


def test_the_scores_spec_has_one_length_unit():
    units = {c.unit for c in SCORES_COLUMNS}
    assert "m" not in units and "cm" in units
    assert [c.name for c in SCORES_COLUMNS if c.unit == "cm"] == ["contact_error_cm", "position_error_cm"]


def test_scores_carry_the_retrieval_position_error_in_cm(stages):
    d, _ = stages
    retrieval = schema.read_table(d / "retrieval.parquet", "retrieval").to_pylist()
    scores = schema.read_table(d / "scores.parquet", "scores").to_pylist()
    assert [s["position_error_cm"] for s in scores] == [r["position_error_m"] * 100.0 for r in retrieval]
    assert "position_error_m" not in scores[0]


def test_the_report_reads_cm(stages):
    d, _ = stages
    scores = schema.read_table(d / "scores.parquet", "scores")
    (row,) = table_ii(scores)
    assert row.position_error_cm_median == scores.column("position_error_cm")[0].as_py()  # not x 100 again


def test_regression_scores_renamed_not_recomputed():
    t = pq.read_table(REGRESSION / "scores.parquet")
    assert "position_error_cm" in t.column_names and "position_error_m" not in t.column_names
