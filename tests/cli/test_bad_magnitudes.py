"""Finite but absurd values in an input table (1e300 m in a segments table, 1e308 ms in diagnostics) are refused on
read, in one line naming the input file and column (issue 17, bad-input probe), not by an internal table whose
sums overflowed (``<table>: column 'wall_s'``)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from stucco_cli.main import cli
from tests.cli.test_bad_runs import RUN, _set, _stucco_segments


@pytest.fixture(scope="module")
def retrieved(tmp_path_factory):
    """FB/0's runs folder, STUCCO segments, a diagnostics table of its steps and the retrieval made from them."""
    tmp = tmp_path_factory.mktemp("retrieved")
    runs = tmp / "runs"
    runs.mkdir()
    (runs / "FB-000.parquet").write_bytes(RUN.read_bytes())
    segments = _stucco_segments(tmp / "segments.parquet")
    steps = sorted(set(pq.read_table(segments).column("step").to_pylist()))
    n = len(steps)
    pq.write_table(pa.table({"run": ["FB/0"] * n, "step": steps, "in_contact": [True] * n, "n_contacts": [1] * n,
                             "ess": [1.0] * n, "resampled": [False] * n, "n_replaced": [0] * n,
                             "update_ms": [1.0] * n}), tmp / "diagnostics.parquet")
    retrieval = tmp / "retrieval.parquet"
    r = CliRunner().invoke(cli, ["-q", "retrieve", "--segments", str(segments), "--runs", str(runs),
                                 "--out", str(retrieval), "--no-grasp", "--method", "stucco"])
    assert r.exit_code == 0, r.output
    return tmp, runs, segments, tmp / "diagnostics.parquet", retrieval


def _huge(src: Path, dst: Path, column: str, value: float) -> Path:
    t = pq.read_table(src)
    v = np.array(t.column(column).to_numpy(zero_copy_only=False), dtype=np.float64)
    v[0] = value
    pq.write_table(_set(t, column, pa.array(v)).replace_schema_metadata(t.schema.metadata), dst)
    return dst


def _names(r, path: Path, column: str) -> None:
    assert r.exit_code not in (0, None) and isinstance(r.exception, SystemExit), r.output
    lines = [ln for ln in r.output.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and "<table>" not in r.output, r.output
    assert path.name in lines[0] and f"'{column}'" in lines[0], r.output


@pytest.mark.parametrize("column", ["x_m", "y_m"])
def test_retrieve_names_a_segments_coordinate_of_1e300(retrieved, tmp_path, column):
    _, runs, segments, _, _ = retrieved
    bad = _huge(segments, tmp_path / "segments.parquet", column, 1e300)
    out = tmp_path / "r.parquet"
    r = CliRunner().invoke(cli, ["-q", "retrieve", "--segments", str(bad), "--runs", str(runs), "--out", str(out),
                                 "--no-grasp", "--method", "stucco"])
    _names(r, bad, column)
    assert not out.exists()


@pytest.mark.parametrize("value", [1e308, -1.0], ids=["1e308", "negative"])
def test_score_names_diagnostics_times_out_of_range(retrieved, tmp_path, value):
    _, runs, segments, diagnostics, retrieval = retrieved
    bad = _huge(diagnostics, tmp_path / "diagnostics.parquet", "update_ms", value)
    out = tmp_path / "scores.parquet"
    r = CliRunner().invoke(cli, ["-q", "score", "--retrieval", str(retrieval), "--segments", str(segments),
                                 "--runs", str(runs), "--diagnostics", str(bad), "--out", str(out)])
    _names(r, bad, "update_ms")
    assert not out.exists()


@pytest.mark.parametrize("column", ["icp_s", "grasp_s"])
def test_score_names_a_retrieval_time_of_1e308(retrieved, tmp_path, column):
    _, runs, segments, diagnostics, retrieval = retrieved
    bad = _huge(retrieval, tmp_path / "retrieval.parquet", column, 1e308)
    out = tmp_path / "scores.parquet"
    r = CliRunner().invoke(cli, ["-q", "score", "--retrieval", str(bad), "--segments", str(segments),
                                 "--runs", str(runs), "--diagnostics", str(diagnostics), "--out", str(out)])
    _names(r, bad, column)
    assert not out.exists()
