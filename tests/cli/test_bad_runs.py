"""Collected run files are validated on read (issue 12, classes 4 and 7): the ``sim_run`` spec.

A run file that is empty, truncated, hand-edited, in millimetres or carries an infinite wrench is refused by
``stucco isolate`` and ``stucco retrieve`` with a non-zero exit and one line naming the run file and the column,
no traceback, no output written, and every input byte-identical afterwards (docs/tables.md#sim_run).
"""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from pipeline import schema
from stucco_cli.main import cli

DATA = Path(__file__).resolve().parents[2] / "data" / "regression"
RUN = DATA / "FB-000.parquet"
SEGMENTS = DATA / "expected" / "segments.parquet"


def _set(t: pa.Table, name: str, array) -> pa.Table:
    return t.set_column(t.column_names.index(name), name, array)


def _nested(values: np.ndarray) -> pa.Array:
    """numpy (rows, a, b) or (rows, a) -> nested fixed-size lists."""
    arr = pa.array(values.reshape(-1))
    for size in reversed(values.shape[1:]):
        arr = pa.FixedSizeListArray.from_arrays(arr, size)
    return arr


def _floats(t: pa.Table, name: str) -> np.ndarray:
    return np.array(t.column(name).to_numpy(zero_copy_only=False), dtype=np.float64)


def _wrench(t: pa.Table) -> np.ndarray:
    col = t.column("win_wrench").combine_chunks().flatten().flatten()
    return np.array(col.to_numpy(zero_copy_only=False)).reshape(t.num_rows, 8, 6)


def _with(t: pa.Table, name: str, row: int, value) -> pa.Table:
    v = _floats(t, name)
    v[row] = value
    return _set(t, name, pa.array(v))


def _in_contact_row(t: pa.Table) -> int:
    return int(np.flatnonzero(t.column("in_contact").to_numpy(zero_copy_only=False))[0])


def _free_row(t: pa.Table) -> int:
    return int(np.flatnonzero(~t.column("in_contact").to_numpy(zero_copy_only=False))[0])


def _inf_wrench(t):
    w = _wrench(t)
    w[_in_contact_row(t), 7, 0] = np.inf
    return _set(t, "win_wrench", _nested(w))


def _short_wrench(t):
    return _set(t, "win_wrench", _nested(_wrench(t)[:, :, :5].copy()))


def _nan_wrench_in_contact(t):
    w = _wrench(t)
    w[_in_contact_row(t)] = np.nan
    return _set(t, "win_wrench", _nested(w))


def _swapped_steps(t):
    s = np.array(t.column("step").to_numpy())
    s[[3, 4]] = s[[4, 3]]
    return _set(t, "step", pa.array(s))


def _millimetres(t):
    for c in ("ee_start_x_m", "ee_start_y_m", "ee_x_m", "ee_y_m", "ee_z_m"):
        t = _set(t, c, pa.array(_floats(t, c) * 1000.0))
    return t


def _two_runs(t):
    runs = t.column("run").to_pylist()
    runs[-1] = "FB/999"
    return _set(t, "run", pa.array(runs))


def _displacement_in_free_space(t):
    return _with(t, "contact_dx_m", _free_row(t), 0.01)


#: (case id, table edit, column the message must name).
TABLE_CASES = [
    ("no rows", lambda t: t.slice(0, 0), "no actions"),
    ("nan position", lambda t: _with(t, "ee_x_m", 3, np.nan), "'ee_x_m', row 3"),
    ("inf position", lambda t: _with(t, "ee_y_m", 5, np.inf), "'ee_y_m', row 5"),
    ("swapped steps", _swapped_steps, "'step'"),
    ("millimetres", _millimetres, "'ee_start_x_m'"),
    ("inf wrench", _inf_wrench, "'win_wrench'"),
    ("nan wrench in contact", _nan_wrench_in_contact, "'win_wrench'"),
    ("wrench of 5 components", _short_wrench, "'win_wrench'"),
    ("two runs", _two_runs, "'run'"),
    ("displacement in free space", _displacement_in_free_space, "'contact_dx_m'"),
    ("missing column", lambda t: t.drop_columns(["win_pose"]), "'win_pose'"),
    ("string seed", lambda t: _set(t, "seed", pa.array([str(s) for s in t.column("seed").to_pylist()])), "'seed'"),
    ("label below -1", lambda t: _set(t, "object_id", pa.array(np.full(t.num_rows, -5))), "'object_id'"),
    ("command outside [-1, 1]", lambda t: _with(t, "cmd_ux", 0, 2.0), "'cmd_ux'"),
]


def _stucco_segments(path: Path) -> Path:
    """The stored STUCCO segments of run FB/0 as a segments file (the regression snapshot holds all methods)."""
    t = pq.read_table(SEGMENTS)
    keep = np.array([m == "stucco" and r == "FB/0" for m, r in zip(t.column("method").to_pylist(),
                                                                     t.column("run").to_pylist())])
    pq.write_table(t.filter(pa.array(keep)).drop_columns(["method"]), path)
    return path


def _write_like_collect(table: pa.Table, path: Path) -> None:
    # keep the writer's provenance so only the edited content is at fault
    pq.write_table(table.replace_schema_metadata(pq.read_schema(RUN).metadata), path)


def _assert_refused(r, path: Path, culprit: str, before: dict[Path, bytes], out: Path) -> None:
    assert r.exit_code not in (0, None), r.output
    assert "Traceback" not in r.output and isinstance(r.exception, SystemExit), r.output
    lines = [ln for ln in r.output.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, r.output
    assert str(path) in lines[0] or path.name in lines[0], r.output
    assert culprit in lines[0], r.output
    assert not out.exists()
    assert {p: p.read_bytes() for p in before} == before


@pytest.mark.parametrize("edit, culprit", [c[1:] for c in TABLE_CASES], ids=[c[0] for c in TABLE_CASES])
def test_isolate_refuses_a_bad_run_file(tmp_path, edit, culprit):
    bad = tmp_path / "FB-000.parquet"
    _write_like_collect(edit(pq.read_table(RUN)), bad)
    out = tmp_path / "contacts.parquet"
    before = {bad: bad.read_bytes()}
    r = CliRunner().invoke(cli, ["-q", "isolate", "--in", str(bad), "--out", str(out)])
    _assert_refused(r, bad, culprit, before, out)


@pytest.mark.parametrize("edit, culprit", [c[1:] for c in TABLE_CASES[:6]], ids=[c[0] for c in TABLE_CASES[:6]])
def test_retrieve_refuses_a_bad_run_file(tmp_path, edit, culprit):
    runs = tmp_path / "runs"
    runs.mkdir()
    bad = runs / "FB-000.parquet"
    _write_like_collect(edit(pq.read_table(RUN)), bad)
    segments = _stucco_segments(tmp_path / "segments.parquet")
    out = tmp_path / "retrieval.parquet"
    before = {bad: bad.read_bytes(), segments: segments.read_bytes()}
    r = CliRunner().invoke(cli, ["-q", "retrieve", "--segments", str(segments), "--runs", str(runs),
                                 "--out", str(out), "--method", "stucco"])
    _assert_refused(r, bad, culprit, before, out)


@pytest.mark.parametrize("content", [RUN.read_bytes()[: len(RUN.read_bytes()) // 2], b"\x00\x01binary\xff" * 50],
                         ids=["truncated", "not parquet"])
@pytest.mark.parametrize("command", ["isolate", "retrieve"])
def test_an_unreadable_run_file_is_named_not_skipped(tmp_path, content, command):
    runs = tmp_path / "runs"
    runs.mkdir()
    shutil.copyfile(RUN, runs / "BC-000.parquet")
    bad = runs / "FB-000.parquet"
    bad.write_bytes(content)
    segments = _stucco_segments(tmp_path / "segments.parquet")
    out = tmp_path / "out.parquet"
    before = {p: p.read_bytes() for p in [*runs.iterdir(), segments]}
    args = (["isolate", "--in", str(runs), "--out", str(out)] if command == "isolate" else
            ["retrieve", "--segments", str(segments), "--runs", str(runs), "--out", str(out)])
    r = CliRunner().invoke(cli, ["-q", *args])
    _assert_refused(r, bad, "Parquet", before, out)


def test_collected_runs_pass_their_spec():
    for name in ("FB-000", "BC-000", "IB-001", "TC-000"):
        t = schema.read_run(DATA / f"{name}.parquet")
        assert t.num_rows > 0 and tuple(t.column_names) == schema.SIM_RUN.required_names


def test_list_columns_report_the_element():
    t = _inf_wrench(pq.read_table(RUN))
    with pytest.raises(schema.SchemaError, match=r"has inf at \[7, 0\]"):
        schema.validate_table(t, "sim_run", "x.parquet")


# ------------------------------------------------------------------------------ a table of the wrong kind

def _segments_with_provenance(path: Path) -> Path:
    t = pq.read_table(_stucco_segments(path))
    schema.write_table(t, path, stage="segment", params={}, seed=0, kind="segments")
    return path


@pytest.mark.parametrize("case", ["segments to segment", "segments without provenance to segment",
                                  "run file to track", "run file to segment", "segments to track"])
def test_a_table_of_another_kind_is_named_as_the_input(tmp_path, case):
    segments = (_segments_with_provenance(tmp_path / "segments.parquet") if "without" not in case
                else _stucco_segments(tmp_path / "segments.parquet"))
    run = tmp_path / "FB-000.parquet"
    shutil.copyfile(RUN, run)
    given = run if case.startswith("run file") else segments
    command = case.rsplit(" ", 1)[-1]
    out = tmp_path / "out.parquet"
    extra = ["--robot", "disc:0.05"] if command == "track" else []
    before = {p: p.read_bytes() for p in (run, segments)}
    r = CliRunner().invoke(cli, ["-q", command, "--in", str(given), "--out", str(out), *extra])
    culprit = ("segments table" if given == segments and command == "segment" else
               "is a sim_run table" if given == run else "is a segments table")
    _assert_refused(r, given, culprit, before, out)
