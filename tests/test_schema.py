"""Tables of pipeline.schema: known-good tables round-trip, every broken table fails with a pinned one-line message
naming file, column and first bad row, writes are atomic and reproducible."""
from __future__ import annotations

import pickle
import re
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import pipeline
from pipeline import schema as S
from pipeline.environment import environment
from pipeline.schema import SchemaError

N = None
DOCS = Path(__file__).resolve().parents[1] / "docs" / "tables.md"


def base_columns() -> dict[str, list]:
    """Two interleaved runs; run 'a' step 1 has two simultaneous contacts (rows 1, 2)."""
    return {
        "run":         ["a",   "a",   "a",   "b",  "a",   "b"],
        "step":        [0,     1,     1,     0,    2,     3],
        "ee_x_m":      [0.15,  0.16,  0.16,  0.5,  0.17,  0.5],
        "ee_y_m":      [0.20,  0.20,  0.20,  0.5,  0.20,  0.52],
        "in_contact":  [False, True,  True,  False, True, True],
        "contact_x_m": [N,     0.30,  0.31,  N,    0.30,  0.6],
        "contact_y_m": [N,     0.25,  0.22,  N,    0.25,  0.55],
        "dx_m":        [N,     0.01,  0.01,  N,    0.01,  0.0],
        "dy_m":        [N,     0.0,   0.0,   N,    0.0,   0.02],
        "object_id":   [-1,    0,     1,     -1,   0,     2],
        "note":        ["s0",  "s1a", "s1b", "t0", "s2",  "t3"],
    }


def make(cols: dict[str, list] | None = None, types: dict[str, pa.DataType] | None = None) -> pa.Table:
    cols = base_columns() if cols is None else cols
    types = types or {}
    return pa.table({k: pa.array(v, types.get(k)) for k, v in cols.items()})


def write_raw(tmp_path: Path, table: pa.Table, name: str = "contacts.parquet") -> Path:
    path = tmp_path / name
    pq.write_table(table, path)
    return path


def where(path: Path, column: str, row: int | None = None) -> str:
    """Regex for the start of a message: file, column and (optionally) row."""
    loc = f"column '{column}'" + ("" if row is None else f", row {row}")
    return "^" + re.escape(f"{path}: {loc}: ")


# ---------------------------------------------------------------------------------------------------------
# contacts: valid tables


def test_valid_contacts_round_trip_canonical_types_and_extra_column(tmp_path):
    cols = base_columns()
    cols["ee_x_m"] = [0, 1, 1, 2, 3, 4]  # integers are accepted for float columns
    table = make(cols, {"step": pa.int16(), "ee_x_m": pa.int32()})
    table = table.set_column(0, "run", table.column("run").dictionary_encode())
    # extra column first in the file: it must come back after the described columns, unchanged
    table = table.select(["note"] + [c for c in table.column_names if c != "note"])
    path = write_raw(tmp_path, table)

    out = S.read_contacts(path)

    given = [c for c in S.CONTACTS_COLUMNS if c.name in table.column_names]  # optional columns absent stay absent
    assert out.column_names == [c.name for c in given] + ["note"]
    assert [out.schema.field(c.name).type for c in given] == [c.type for c in given]
    assert out.column("ee_x_m").to_pylist() == [0.0, 1.0, 1.0, 2.0, 3.0, 4.0]
    assert out.column("step").to_pylist() == [0, 1, 1, 0, 2, 3]
    assert out.column("run").to_pylist() == ["a", "a", "a", "b", "a", "b"]
    assert out.column("note").equals(table.column("note"))
    assert out.column("contact_x_m").null_count == 2


def test_object_id_is_optional():
    cols = base_columns()
    del cols["object_id"]
    out = S.validate_contacts(make(cols))
    assert "object_id" not in out.column_names


def test_several_contacts_per_step_accepted():
    cols = {k: [v[1]] * 4 for k, v in base_columns().items()}
    cols["contact_x_m"] = [0.1, 0.2, 0.3, 0.4]
    out = S.validate_contacts(make(cols))
    assert out.num_rows == 4


def test_all_free_space_with_null_typed_contact_columns():
    cols = {k: [v[0], v[0]] for k, v in base_columns().items()}
    cols["step"] = [0, 1]
    table = make(cols)  # contact_* and dx columns are all None -> pyarrow type null
    assert table.schema.field("dx_m").type == pa.null()
    out = S.validate_contacts(table)
    assert out.schema.field("dx_m").type == pa.float64()


def test_empty_contacts_table_is_valid():
    table = make().slice(0, 0)
    assert S.validate_contacts(table).num_rows == 0
    assert S.contacts_by_run(table) == []


# ---------------------------------------------------------------------------------------------------------
# contacts: each broken table names file, column and first bad row


def _set(column, row, value):
    def mutate(cols):
        cols[column][row] = value
    return mutate


def _drop(column):
    return lambda cols: cols.pop(column)


def _replace(column, values):
    def mutate(cols):
        cols[column] = values
    return mutate


def _chain(*fs):
    def mutate(cols):
        for f in fs:
            f(cols)
    return mutate


CASES = [
    # id, mutate, column, row, rest of the message (regex)
    ("missing_column", _drop("dx_m"), "dx_m", None, r"missing; expected float64 in m"),
    ("string_ee", _replace("ee_x_m", ["0.15"] * 6), "ee_x_m", None,
     r"has type string; expected float64 \(any float or integer type"),
    ("bool_ee", _replace("ee_y_m", [True] * 6), "ee_y_m", None, r"has type bool; expected float64"),
    ("int_in_contact", _replace("in_contact", [0, 1, 2, 0, 1, 1]), "in_contact", 2,
     r"is 2; expected a boolean \(true/false, or 1/0\)$"),
    ("float_step", _replace("step", [0.0, 1.0, 1.0, 0.0, 2.0, 3.0]), "step", None,
     r"has type double; expected int64 \(any integer type"),
    ("nan_ee", _set("ee_x_m", 4, float("nan")), "ee_x_m", 4, r"is nan; expected a finite value$"),
    ("inf_ee", _set("ee_y_m", 3, float("inf")), "ee_y_m", 3, r"is inf; expected a finite value$"),
    ("null_ee", _set("ee_x_m", 5, None), "ee_x_m", 5, r"is null; expected a value"),
    ("null_step", _set("step", 2, None), "step", 2, r"is null"),
    ("contact_without_displacement", _set("dx_m", 2, None), "dx_m", 2,
     r"is null while in_contact is true: contact without displacement"),
    ("contact_without_point", _set("contact_y_m", 4, None), "contact_y_m", 4,
     r"is null while in_contact is true; expected the contact point in metres"),
    ("nan_while_in_contact", _set("contact_x_m", 1, float("nan")), "contact_x_m", 1,
     r"is nan while in_contact is true; expected a finite value"),
    ("nan_where_null_expected", _set("contact_x_m", 3, float("nan")), "contact_x_m", 3,
     r"is NaN while in_contact is false; use null \(not NaN\)"),
    ("value_where_null_expected", _set("dy_m", 0, 0.0), "dy_m", 0,
     r"is 0\.0 while in_contact is false; expected null"),
    ("decreasing_step", _set("step", 4, 0), "step", 4,
     r"step 0 follows step 1 \(row 2\) in run 'a'; steps must be non-decreasing within a run"),
    ("mixed_free_and_contact_step",
     _chain(_set("in_contact", 2, False), _set("contact_x_m", 2, None), _set("contact_y_m", 2, None),
            _set("dx_m", 2, None), _set("dy_m", 2, None)),
     "in_contact", 2, r"is false but step 1 of run 'a' has several rows; a free-space step is exactly one row"),
    ("ee_differs_within_step", _set("ee_y_m", 2, 0.21), "ee_y_m", 2,
     r"is 0\.21 but row 1 of the same step 1 \(run 'a'\) has 0\.2; all rows of one step must share"),
    ("ee_in_millimetres", lambda c: c.update(ee_x_m=[v * 1000 for v in c["ee_x_m"]]), "ee_x_m", 0,
     r"is 150\.0, which looks like the wrong unit \(positions beyond 5 m\); metres are expected"),
    ("contact_in_millimetres", _set("contact_y_m", 5, 550.0), "contact_y_m", 5,
     r"is 550\.0, which looks like the wrong unit"),
    ("displacement_in_millimetres", _set("dx_m", 1, 10.0), "dx_m", 1,
     r"is 10\.0, which looks like the wrong unit \(displacements per step beyond 1 m\); metres are expected"),
    ("null_object_id", _set("object_id", 1, None), "object_id", 1, r"is null"),
    ("object_id_below_minus_one", _set("object_id", 3, -2), "object_id", 3, r"is -2; expected at least -1"),
]


@pytest.mark.parametrize("mutate, column, row, what", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_broken_contacts_file_names_file_column_and_first_bad_row(tmp_path, mutate, column, row, what):
    cols = base_columns()
    mutate(cols)
    path = write_raw(tmp_path, make(cols))

    with pytest.raises(SchemaError, match=where(path, column, row) + what) as info:
        S.read_contacts(path)

    err = info.value
    assert (err.path, err.column, err.row) == (str(path), column, row)
    assert "\n" not in str(err)


def test_first_bad_row_is_reported_when_several_are_bad():
    cols = base_columns()
    cols["ee_x_m"][5] = float("nan")
    cols["ee_x_m"][2] = float("nan")
    with pytest.raises(SchemaError, match=r"^<table>: column 'ee_x_m', row 2: "):
        S.validate_contacts(make(cols))


def test_decreasing_step_in_interleaved_run_names_first_bad_row_in_file_order():
    cols = base_columns()
    cols["step"] = [5, 6, 6, 9, 7, 1]  # run b goes 9 -> 1 at row 5; run a is fine
    with pytest.raises(SchemaError, match=r"row 5: step 1 follows step 9 \(row 3\) in run 'b'"):
        S.validate_contacts(make(cols), "x.parquet")


def test_uint64_step_beyond_int64_is_an_error():
    cols = base_columns()
    cols["step"] = [0, 1, 1, 0, 2, 2**63]
    with pytest.raises(SchemaError, match=r"column 'step', row 5: 9223372036854775808 does not fit in int64"):
        S.validate_contacts(make(cols, {"step": pa.uint64()}))


def test_repeated_extra_column_is_carried():
    table = make().append_column("note", pa.array(range(6)))
    out = S.validate_contacts(table)
    assert out.column_names[-2:] == ["note", "note"] and out.column(out.num_columns - 1).to_pylist() == [*range(6)]


def test_duplicate_column_is_an_error():
    table = make()
    table = table.append_column("step", table.column("step"))
    with pytest.raises(SchemaError, match=r"^<table>: column 'step': appears 2 times"):
        S.validate_contacts(table)


def test_missing_file(tmp_path):
    path = tmp_path / "nope.parquet"
    with pytest.raises(SchemaError, match="^" + re.escape(f"{path}: file not found") + "$") as info:
        S.read_contacts(path)
    assert info.value.column is None and info.value.row is None


def test_not_a_parquet_file(tmp_path):
    path = tmp_path / "contacts.parquet"
    path.write_text("run,step\na,0\n")
    with pytest.raises(SchemaError, match="^" + re.escape(f"{path}: not a Parquet file")) as info:
        S.read_contacts(path)
    assert "\n" not in str(info.value)


def test_schema_error_pickles_with_its_attributes():
    err = SchemaError("f.parquet", "dx_m", 3, "is null")
    back = pickle.loads(pickle.dumps(err))
    assert (str(back), back.path, back.column, back.row) == (str(err), "f.parquet", "dx_m", 3)


# ---------------------------------------------------------------------------------------------------------
# tracks, segments, diagnostics


def tracks_columns() -> dict[str, list]:
    # estimates after steps 1 and 2 of run 'a' (step 1 had two contacts)
    return {
        "run": ["a", "a", "a", "a", "a"],
        "step": [1, 1, 1, 1, 2],
        "contact_index": [0, 1, 0, 1, 0],
        "estimate_step": [1, 1, 2, 2, 2],
        "x_m": [0.30, 0.31, 0.30, 0.31, 0.30],
        "y_m": [0.25, 0.22, 0.25, 0.22, 0.25],
        "tracker_label": [0, 1, 0, 1, 0],
        "object_id": [0, 1, 0, 1, 0],
    }


def test_valid_tracks_and_segments(tmp_path):
    tracks = make(tracks_columns(), {"contact_index": pa.int8()})
    path = write_raw(tmp_path, tracks, "tracks.parquet")
    out = S.read_tracks(path)
    assert out.column_names == [c.name for c in S.TRACKS_COLUMNS]
    assert out.schema.field("contact_index").type == pa.int64()

    seg = tracks.append_column("segment", pa.array([0, 1, 0, 1, 0]))
    path = write_raw(tmp_path, seg, "segments.parquet")
    assert S.read_segments(path).column_names[-1] == "segment"
    with pytest.raises(SchemaError, match=r"column 'segment': missing"):
        S.validate_segments(tracks)


@pytest.mark.parametrize("mutate, column, row, what", [
    (_set("estimate_step", 4, 1), "estimate_step", 4, r"is 1, before the contact was observed \(step 2\)"),
    (_set("contact_index", 3, 0), "contact_index", 3, r"is 0 for step 1, estimate_step 2, run 'a'.*0\.\.K-1"),
    (_set("contact_index", 4, 1), "contact_index", 4, r"is 1 for step 2"),
    (_set("x_m", 2, float("nan")), "x_m", 2, r"is nan; expected a finite value"),
    (_set("tracker_label", 0, -1), "tracker_label", 0, r"is -1; expected at least 0"),
], ids=["estimate_before_observation", "repeated_contact_index", "gap_in_contact_index", "nan_x", "neg_label"])
def test_broken_tracks(mutate, column, row, what):
    cols = tracks_columns()
    mutate(cols)
    with pytest.raises(SchemaError, match=where(Path("t.parquet"), column, row) + what):
        S.validate_tracks(make(cols), "t.parquet")


def diagnostics_columns() -> dict[str, list]:
    return {
        "run": ["a", "a", "a"],
        "step": [0, 1, 2],
        "in_contact": [False, True, True],
        "n_contacts": [0, 2, 1],
        "ess": [1.0, 0.4, 0.9],
        "resampled": [False, True, False],
        "n_replaced": [0, 3, 0],
        "update_ms": [0.1, 2.5, 1.0],
    }


def test_valid_diagnostics():
    out = S.validate_diagnostics(make(diagnostics_columns()))
    assert out.column_names == [c.name for c in S.DIAGNOSTICS_COLUMNS]


@pytest.mark.parametrize("mutate, column, row, what", [
    (_set("ess", 1, 0.0), "ess", 1, r"is 0\.0; expected greater than 0"),
    (_set("ess", 2, 1.5), "ess", 2, r"is 1\.5; expected at most 1"),
    (_set("n_contacts", 2, 0), "n_contacts", 2, r"is 0 while in_contact is true; expected at least 1"),
    (_set("n_contacts", 0, 1), "n_contacts", 0, r"is 1 while in_contact is false; expected 0"),
    (_set("step", 2, 1), "step", 2, r"step 1 follows step 1 \(row 1\) in run 'a'; diagnostics have one row"),
    (_set("n_replaced", 1, -1), "n_replaced", 1, r"is -1; expected at least 0"),
    (_set("update_ms", 0, float("inf")), "update_ms", 0, r"is inf; expected a finite value"),
], ids=["ess_zero", "ess_above_one", "contact_without_points", "free_with_points", "repeated_step",
        "negative_replaced", "inf_time"])
def test_broken_diagnostics(mutate, column, row, what):
    cols = diagnostics_columns()
    mutate(cols)
    with pytest.raises(SchemaError, match=where(Path("<table>"), column, row) + what):
        S.validate_diagnostics(make(cols))


# ---------------------------------------------------------------------------------------------------------
# write_table: provenance, atomicity, reproducibility


def _write(table, path, **kw):
    kw = {"stage": "track", "params": {"length": 0.02, "n_particles": np.int64(100)}, "seed": 7} | kw
    return S.write_table(table, path, **kw)


def test_write_table_metadata_round_trip(tmp_path):
    src = write_raw(tmp_path, make(), "in.parquet")
    out = _write(S.read_contacts(src), tmp_path / "deep" / "dir" / "out.parquet", inputs={"contacts": src})

    assert out == tmp_path / "deep" / "dir" / "out.parquet"
    assert S.read_metadata(out) == {
        "stage": "track",
        "version": pipeline.__version__,
        "params": {"length": 0.02, "n_particles": 100},
        "seed": 7,
        "inputs": {"contacts": {"file": "in.parquet", "sha256": S.file_digest(src)}},
        "environment": environment(),
        "schema": "contacts",
    }
    assert set(environment()) >= {"python", "numpy", "scipy", "numba", "open3d-cpu", "pybullet"}
    assert pq.read_schema(out).metadata[b"stucco.params"] == b'{"length":0.02,"n_particles":100}'
    assert S.read_contacts(out).equals(S.read_contacts(src))


def test_read_metadata_of_foreign_file_is_empty(tmp_path):
    assert S.read_metadata(write_raw(tmp_path, make())) == {}


def test_write_table_seed_none_and_explicit_kind(tmp_path):
    table = pa.table({"run": ["a"], "ce_cm": [1.5]})  # a kind of its own (not in TABLES) is written as given
    path = _write(table, tmp_path / "summary.parquet", seed=None, kind="summary", stage="bench")
    meta = S.read_metadata(path)
    assert meta["seed"] is None and meta["schema"] == "summary" and meta["inputs"] == {}


def test_every_stage_table_kind_is_in_tables():
    assert set(S.TABLES) == {"sim_run", "contacts", "tracks", "diagnostics", "segments", "retrieval", "candidates",
                             "scores"}


def test_result_tables_are_validated_on_write(tmp_path):
    with pytest.raises(S.SchemaError, match=r"column 'scene': missing"):
        _write(pa.table({"run": ["a"], "ce_cm": [1.5]}), tmp_path / "scores.parquet", kind="scores", stage="score")
    assert list(tmp_path.iterdir()) == []


def test_write_table_unknown_kind_needs_kind(tmp_path):
    with pytest.raises(ValueError, match="cannot tell the table kind"):
        _write(pa.table({"a": [1]}), tmp_path / "x.parquet")
    assert list(tmp_path.iterdir()) == []


def test_write_table_is_byte_identical_on_rewrite(tmp_path):
    table = S.validate_contacts(make())
    rechunked = pa.concat_tables([table.slice(0, 2), table.slice(2)])  # chunking must not matter
    a = _write(table, tmp_path / "a.parquet").read_bytes()
    b = _write(rechunked, tmp_path / "b.parquet").read_bytes()
    c = _write(table, tmp_path / "a.parquet").read_bytes()
    assert a == b == c


def test_write_table_validates_and_leaves_nothing_on_invalid_table(tmp_path):
    cols = base_columns()
    cols["dx_m"][1] = None
    target = tmp_path / "out.parquet"
    with pytest.raises(SchemaError, match=where(target, "dx_m", 1)):
        _write(make(cols), target)
    assert list(tmp_path.iterdir()) == []


def _fail_midway(table, sink):
    sink.write(b"PAR1 partial bytes")
    raise RuntimeError("disk full")


def test_write_table_failure_leaves_no_target_and_no_temp_file(tmp_path, monkeypatch):
    monkeypatch.setattr(S.io, "_write_parquet", _fail_midway)
    target = tmp_path / "out" / "tracks.parquet"
    with pytest.raises(RuntimeError, match="disk full"):
        _write(make(), target)
    assert not target.exists()
    assert list(target.parent.iterdir()) == []


def test_write_table_failure_keeps_existing_target_intact(tmp_path, monkeypatch):
    target = _write(make(), tmp_path / "contacts.parquet")
    before = target.read_bytes()
    monkeypatch.setattr(S.io, "_write_parquet", _fail_midway)
    with pytest.raises(RuntimeError):
        _write(make(), target, seed=8)
    assert target.read_bytes() == before
    assert list(tmp_path.iterdir()) == [target]


def test_file_digest(tmp_path):
    p = tmp_path / "f"
    p.write_bytes(b"abc")
    assert S.file_digest(p) == "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"


# ---------------------------------------------------------------------------------------------------------
# contacts_by_run


def test_contacts_by_run_groups_runs_in_first_appearance_and_steps():
    runs = S.contacts_by_run(make())

    assert [name for name, _ in runs] == ["a", "b"]
    a, b = runs[0][1], runs[1][1]
    assert a.run == "a" and a.n_steps == 3 and a.n_rows == 4
    np.testing.assert_array_equal(a.step, [0, 1, 2])
    np.testing.assert_array_equal(a.ee, [[0.15, 0.20], [0.16, 0.20], [0.17, 0.20]])
    np.testing.assert_array_equal(a.in_contact, [False, True, True])
    np.testing.assert_array_equal(a.row_start, [0, 1, 3])
    np.testing.assert_array_equal(a.row_count, [1, 2, 1])
    np.testing.assert_array_equal(a.row_index, [0, 1, 2, 4])
    np.testing.assert_array_equal(a.contact, [[np.nan, np.nan], [0.30, 0.25], [0.31, 0.22], [0.30, 0.25]])
    np.testing.assert_array_equal(a.dx, [[np.nan, np.nan], [0.01, 0.0], [0.01, 0.0], [0.01, 0.0]])
    np.testing.assert_array_equal(a.object_id, [-1, 0, 1, 0])
    assert a.rows(1) == slice(1, 3)

    x, dx, p = a.observation(1)
    np.testing.assert_array_equal(x, [0.16, 0.20])
    np.testing.assert_array_equal(dx, [[0.01, 0.0], [0.01, 0.0]])
    np.testing.assert_array_equal(p, [[0.30, 0.25], [0.31, 0.22]])
    x, dx, p = a.observation(0)
    assert dx is None and p is None

    np.testing.assert_array_equal(b.step, [0, 3])
    np.testing.assert_array_equal(b.row_index, [3, 5])
    with pytest.raises(ValueError):
        b.ee[0, 0] = 1.0  # read-only views: a tracker cannot corrupt the input


def test_contacts_by_run_validates():
    cols = base_columns()
    cols["step"][4] = 0
    with pytest.raises(SchemaError, match="column 'step', row 4"):
        S.contacts_by_run(make(cols))


# ---------------------------------------------------------------------------------------------------------
# property: any valid generated contacts table validates and round-trips

coord = st.floats(-5.0, 5.0, allow_nan=False)
disp = st.floats(-0.05, 0.05, allow_nan=False)


@st.composite
def contacts_tables(draw):
    names = draw(st.lists(st.text(max_size=4), min_size=1, max_size=3, unique=True))
    per_run = []
    for name in names:
        rows = []
        step = draw(st.integers(-3, 3))
        for _ in range(draw(st.integers(1, 5))):
            step += draw(st.integers(1, 3))
            ee = (draw(coord), draw(coord))
            k = draw(st.integers(0, 3))
            if k == 0:
                rows.append((name, step, *ee, False, N, N, N, N))
            for _ in range(k):
                rows.append((name, step, *ee, True, draw(coord), draw(coord), draw(disp), draw(disp)))
        per_run.append(rows)
    # interleave runs while keeping each run's rows in order
    labels = draw(st.permutations([i for i, rows in enumerate(per_run) for _ in rows]))
    cursors = [iter(rows) for rows in per_run]
    rows = [next(cursors[i]) for i in labels]

    names_ = [c.name for c in S.CONTACTS_COLUMNS[:9]]
    cols = {n: [r[j] for r in rows] for j, n in enumerate(names_)}
    run_type = draw(st.sampled_from(["string", "large_string", "dictionary"]))
    types = {
        "run": pa.large_string() if run_type == "large_string" else pa.string(),
        "step": draw(st.sampled_from([pa.int16(), pa.int32(), pa.int64()])),
        "ee_x_m": draw(st.sampled_from([pa.float32(), pa.float64()])),
    }
    table = make(cols, types)
    if run_type == "dictionary":
        table = table.set_column(0, "run", table.column("run").dictionary_encode())
    if draw(st.booleans()):
        table = table.append_column("object_id", pa.array(draw(
            st.lists(st.integers(-1, 3), min_size=len(rows), max_size=len(rows))), pa.int32()))
    table = table.append_column("extra", pa.array(range(len(rows)), pa.int16()))
    return table


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(table=contacts_tables())
def test_any_valid_contacts_table_validates_and_round_trips(tmp_path, table):
    canonical = S.validate_contacts(table)
    path = _write(table, tmp_path / "c.parquet")
    back = S.read_contacts(path)
    assert back.equals(canonical)
    assert back.column("extra").equals(table.column("extra"))
    assert back.column("ee_x_m").to_pylist() == table.column("ee_x_m").cast(pa.float64()).to_pylist()

    runs = S.contacts_by_run(back)
    assert [r for r, _ in runs] == list(dict.fromkeys(back.column("run").to_pylist()))
    row_index = np.concatenate([rc.row_index for _, rc in runs])
    np.testing.assert_array_equal(np.sort(row_index), np.arange(back.num_rows))
    d = back.to_pydict()
    for run, rc in runs:
        assert np.all(np.diff(rc.step) > 0)
        assert rc.row_count.sum() == rc.n_rows and rc.row_start[0] == 0
        for s in range(rc.n_steps):
            for j in range(rc.row_start[s], rc.row_start[s] + rc.row_count[s]):
                i = rc.row_index[j]
                assert (d["run"][i], d["step"][i], d["in_contact"][i]) == (run, rc.step[s], rc.in_contact[s])
                assert (d["ee_x_m"][i], d["ee_y_m"][i]) == tuple(rc.ee[s])
                if rc.in_contact[s]:
                    assert (d["contact_x_m"][i], d["dy_m"][i]) == (rc.contact[j, 0], rc.dx[j, 1])
                else:
                    assert rc.row_count[s] == 1 and np.isnan(rc.contact[j]).all()


# ---------------------------------------------------------------------------------------------------------
# docs agree with the descriptions


@pytest.mark.parametrize("kind", sorted(S.TABLES))
def test_docs_show_the_generated_column_tables_and_rules(kind):
    text = DOCS.read_text(encoding="utf-8")
    assert S.table_markdown(kind) in text
    for key, _ in S.METADATA_KEYS:
        assert f"`{key}`" in text
