"""Every folder of an evaluation opens with the usual tools and no extra arguments, and one evaluation at a time
writes a folder (issue 12, items 4 and 5; docs/evaluation.md, "The output directory")."""
from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import duckdb
import pandas as pd
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from pipeline import registry
from pipeline.atomic import exclusive
from pipeline.layout import CONFIG, FLAT, KINDS, LOCK, PER_ESTIMATOR, SHARED
from stucco_cli.main import cli

REGRESSION = Path(__file__).resolve().parents[1] / "data" / "regression"
ARGS = ["-q", "evaluate", "--from-runs", str(REGRESSION), "--scenes", "FB,TC", "--seeds", "0", "--methods",
        "stucco,birch", "--estimators", "plausible,paper", "--no-figures"]


@pytest.fixture(scope="module")
def evaluation(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("open") / "ev"
    r = CliRunner().invoke(cli, [*ARGS, "--out", str(out)])
    assert r.exit_code == 0, r.output
    return out


def _rows_in_files(folder: Path) -> int:
    return sum(pq.ParquetFile(f).metadata.num_rows for f in folder.rglob("*.parquet"))


@pytest.mark.parametrize("kind", KINDS)
def test_every_kind_opens_with_pyarrow_pandas_and_duckdb(evaluation, kind):
    folder = evaluation / kind
    n = _rows_in_files(folder)
    assert n > 0
    keys = {"scene", "seed"} | ({"method"} if kind not in ("runs", "contacts") else set())

    t = pq.read_table(folder)
    assert t.num_rows == n and keys <= set(t.column_names)
    d = ds.dataset(folder, partitioning="hive").to_table()
    assert d.num_rows == n and keys <= set(d.column_names)
    assert sorted(d.column("scene").to_pylist()) == sorted(str(s) for s in t.column("scene").to_pylist())
    df = pd.read_parquet(folder)
    assert len(df) == n and keys <= set(df.columns)
    con = duckdb.connect()
    got = con.execute(f"SELECT count(*), count(DISTINCT scene) FROM '{folder}/**/*.parquet'").fetchone()
    assert got == (n, 2)


def _keys(kind: str) -> list[str]:
    return ["scene", "seed"] + (["method"] if kind not in SHARED else []) + (["estimator"] if kind in PER_ESTIMATOR
                                                                           else [])


def test_every_table_of_an_evaluation_opens_with_one_pattern(evaluation):
    # Every folder of the evaluation holding Parquet is a table, and each opens with the same DuckDB call and the
    # same pyarrow call, its keys as columns with the same values either way (issue: one layout for every table).
    tables = sorted({p.relative_to(evaluation).parts[0] for p in evaluation.rglob("*.parquet")})
    assert tables == sorted(KINDS)
    # A policy's side file beside a run (the active protocol's times) must not stop either reader.
    registry.side_path(evaluation / "runs" / "FB-000.parquet", ".probe_s.json").write_text('{"decision_s": []}')
    con = duckdb.connect()
    for table in tables:
        keys = _keys(table)
        q = (f"SELECT {', '.join(keys)}, count(*) FROM read_parquet('{evaluation}/{table}/**/*.parquet', "
             f"hive_partitioning=true) GROUP BY ALL ORDER BY ALL")
        by_duckdb = con.execute(q).fetchall()
        t = ds.dataset(evaluation / table, partitioning="hive").to_table(columns=keys)
        by_pyarrow = sorted(Counter(tuple(r[k] for k in keys) for r in t.to_pylist()).items())
        assert [(*k, n) for k, n in by_pyarrow] == by_duckdb, table
        assert sum(n for *_, n in by_duckdb) == _rows_in_files(evaluation / table), table
        assert {r[0] for r in by_duckdb} == {"FB", "TC"} and {r[1] for r in by_duckdb} == {0}, table


def test_flat_kinds_hold_their_keys_and_runs_is_a_run_directory(evaluation):
    for kind in FLAT:
        files = sorted((evaluation / kind).glob("*.parquet"))
        assert files and all(not f.is_dir() for f in (evaluation / kind).iterdir() if f.suffix == ".parquet")
    names = sorted(f.name for f in (evaluation / "runs").glob("*.parquet"))
    assert names == ["FB-000.parquet", "TC-000.parquet"]  # as `stucco collect --out` names them
    scores = pq.read_table(evaluation / "scores")
    assert scores.schema.field("seed").type == "int64" and scores.schema.field("scene").type == "string"
    assert scores.num_rows == 2 * 2 * 2  # scenes x methods x estimators


def test_a_second_evaluation_on_the_folder_is_refused_in_one_line(evaluation):
    config = (evaluation / CONFIG).read_bytes()
    with exclusive(evaluation, LOCK):  # as if another `stucco evaluate` were writing there
        r = CliRunner().invoke(cli, [*ARGS, "--seeds", "0", "--methods", "kmeans", "--out", str(evaluation)])
    assert r.exit_code == 1 and isinstance(r.exception, SystemExit), r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and str(evaluation) in lines[0] and "another process" in lines[0], r.output
    assert (evaluation / CONFIG).read_bytes() == config
    assert not list((evaluation / "tracks").rglob("method=kmeans"))


def test_a_folder_of_the_older_layout_is_refused_not_mixed(evaluation, tmp_path):
    out = tmp_path / "old"
    out.mkdir()
    # The configuration the same ARGS write (the module's evaluation made it; it names no output path), less the
    # layout key that folders of the older layout lack.
    old = json.loads((evaluation / CONFIG).read_text())
    del old["layout"]
    (out / CONFIG).write_text(json.dumps(old))
    r = CliRunner().invoke(cli, [*ARGS, "--out", str(out)])
    assert r.exit_code == 1 and "another layout" in r.output, r.output
    assert sorted(p.name for p in out.iterdir()) == sorted([CONFIG, LOCK])
