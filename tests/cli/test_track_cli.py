"""`stucco track` and `stucco segment` through click's CliRunner: outputs, metadata, determinism, one-line errors."""
from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from pipeline import schema
from pipeline.studies.anchors import load_stream, stream_path, stream_to_contacts
from stucco_cli.main import cli

FAST = ["--robot", "disc:0.05", "--particles", "20"]


@pytest.fixture(scope="module")
def contacts_table():
    """The first 70 steps of the T=50 anchor stream: 13 contacts on two objects (steps 32-38 and 61-67)."""
    return stream_to_contacts(load_stream(stream_path(50)), "r").slice(0, 70)


@pytest.fixture
def contacts_file(tmp_path, contacts_table):
    path = tmp_path / "contacts.parquet"
    pq.write_table(contacts_table, path)
    return path


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def track(contacts, out, *extra, seed=None):
    pre = [] if seed is None else ["--seed", seed]
    return invoke(*pre, "track", "--in", contacts, "--out", out, *extra)


def ok(res):
    assert res.exit_code == 0, (res.exit_code, res.stderr, res.exception)
    return res


def assert_one_line_error(res, *needles):
    """Non-zero exit, one line on stderr naming what is wrong, no traceback (a ClickException, not a crash)."""
    assert res.exit_code != 0
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
    assert "Traceback" not in res.stderr and res.stdout == ""
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), res.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def assert_usage_error(res, *needles):
    """Bad option values: click's usage error (exit code 2), whose single error line names the option."""
    assert res.exit_code == 2, (res.exit_code, res.stderr, res.exception)
    assert "Traceback" not in res.stderr
    errors = [line for line in res.stderr.splitlines() if line.startswith("Error: ")]
    assert len(errors) == 1, res.stderr
    for needle in needles:
        assert needle in errors[0], (needle, errors[0])


def only_input_left(tmp_path, *inputs):
    """No output (nor a temporary file) was written next to the inputs."""
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in inputs)


# ------------------------------------------------------------------------------------------------ track
def test_track_writes_tracks_and_diagnostics_with_metadata(tmp_path, contacts_file, contacts_table):
    out = tmp_path / "tracks.parquet"
    res = ok(track(contacts_file, out, *FAST, "--length", "0.03", seed=7))
    assert res.stdout == "" and "tracked 1 run(s), 13 point rows" in res.stderr
    tracks = schema.read_tracks(out)
    diag = schema.read_diagnostics(tmp_path / "tracks.diagnostics.parquet")
    assert tracks.num_rows == 13 and diag.num_rows == 70
    inc = contacts_table.filter(pc.field("in_contact"))
    np.testing.assert_array_equal(tracks.column("step").to_numpy(), inc.column("step").to_numpy())
    np.testing.assert_array_equal(tracks.column("object_id").to_numpy(), inc.column("object_id").to_numpy())
    for path, kind in ((out, "tracks"), (tmp_path / "tracks.diagnostics.parquet", "diagnostics")):
        meta = schema.read_metadata(path)
        assert meta["stage"] == "track" and meta["schema"] == kind and meta["seed"] == 7
        p = meta["params"]
        assert p["method"] == "stucco" and p["robot"] == "disc:0.05" and p["every_step"] is False
        assert p["length"] == 0.03 and p["n_particles"] == 20
        assert p["penetration_length"] == 0.002 and p["alpha"] == 0.4  # defaults filled in
        assert meta["inputs"]["contacts"]["file"] == "contacts.parquet"
        assert meta["inputs"]["contacts"]["sha256"] == schema.file_digest(contacts_file)


def test_track_quiet_and_explicit_diagnostics_path(tmp_path, contacts_file):
    diag = tmp_path / "sub" / "diag.parquet"
    res = ok(invoke("-q", "track", "--in", contacts_file, "--out", tmp_path / "t.parquet", "--diagnostics", diag,
                    *FAST))
    assert res.stderr == "" and res.stdout == ""
    assert schema.read_diagnostics(diag).num_rows == 70
    assert not (tmp_path / "t.diagnostics.parquet").exists()


def test_track_options_reach_the_tracker(tmp_path, contacts_file):
    out = tmp_path / "t.parquet"
    ok(track(contacts_file, out, *FAST, "--weighting", "paper", "--replace", "never", "--ess-threshold", "0.5",
             "--tolerance", "0.001", "--penetration-length", "0.01", "--alpha", "0.3", "--set", "weight_floor=0"))
    p = schema.read_metadata(out)["params"]
    assert (p["weighting"], p["replace"], p["ess_threshold"], p["tolerance"], p["penetration_length"], p["alpha"],
            p["weight_floor"]) == ("paper", "never", 0.5, 0.001, 0.01, 0.3, 0)
    diag = schema.read_diagnostics(tmp_path / "t.diagnostics.parquet")
    assert sum(diag.column("n_replaced").to_pylist()) == 0


def test_track_every_step(tmp_path, contacts_file, contacts_table):
    out = tmp_path / "t.parquet"
    ok(track(contacts_file, out, *FAST, "--every-step"))
    tracks = schema.read_tracks(out)
    assert schema.read_metadata(out)["params"]["every_step"] is True
    est = tracks.column("estimate_step").to_numpy()
    first = int(np.flatnonzero(contacts_table.column("in_contact").to_numpy(zero_copy_only=False))[0])
    # one estimate after every step from the first contact on, holding every contact observed so far
    np.testing.assert_array_equal(np.unique(est), np.arange(first, 70))
    inc = contacts_table.column("in_contact").to_numpy(zero_copy_only=False)
    np.testing.assert_array_equal([np.sum(est == s) for s in range(first, 70)], np.cumsum(inc)[first:70])
    final = tracks.filter(pc.equal(tracks["estimate_step"], 69))
    ok(track(contacts_file, tmp_path / "last.parquet", *FAST))
    assert final.equals(schema.read_tracks(tmp_path / "last.parquet"))
    # segment records it, for the estimators that read every in-contact step (retrieve --estimator paper)
    ok(invoke("segment", "--in", out, "--out", tmp_path / "s.parquet"))
    assert schema.read_metadata(tmp_path / "s.parquet")["params"]["every_step"] is True


def test_track_dbscan_end_to_end(tmp_path, contacts_file):
    out = tmp_path / "t.parquet"
    ok(track(contacts_file, out, "--method", "dbscan", "--robot", "disc:0.05", "--set", "eps=0.05"))
    tracks = schema.read_tracks(out)
    assert tracks.num_rows == 13
    p = schema.read_metadata(out)["params"]
    assert p["method"] == "dbscan" and p["eps"] == 0.05 and "n_particles" not in p
    seg = tmp_path / "s.parquet"
    ok(invoke("segment", "--in", out, "--out", seg))
    meta = schema.read_metadata(seg)
    assert meta["params"]["method"] == "dbscan" and meta["params"]["by"] == "tracker" and "length" not in meta["params"]
    segs = schema.read_segments(seg)
    # auto: the baseline's own clusters are its segmentation
    from pipeline.segment import canonical_labels

    np.testing.assert_array_equal(segs.column("segment").to_numpy(),
                                  canonical_labels(segs.column("tracker_label").to_numpy()))


def test_same_seed_gives_byte_identical_tracks_and_segments(tmp_path, contacts_file):
    # same file names in two directories: the metadata records input file names, so they must match too
    outs = []
    for d in ("a", "b"):
        (tmp_path / d).mkdir()
        ok(track(contacts_file, tmp_path / d / "tracks.parquet", *FAST, seed=3))
        ok(invoke("--seed", "3", "segment", "--in", tmp_path / d / "tracks.parquet", "--out",
                  tmp_path / d / "segments.parquet"))
        outs.append(tmp_path / d)
    a, b = outs
    assert (a / "tracks.parquet").read_bytes() == (b / "tracks.parquet").read_bytes()
    assert (a / "segments.parquet").read_bytes() == (b / "segments.parquet").read_bytes()
    # (the diagnostics hold wall times and are not expected to be identical)


def test_jobs_do_not_change_the_tracks(tmp_path, contacts_table):
    two = pa.concat_tables([contacts_table,
                            contacts_table.set_column(0, "run", pa.array(["s"] * contacts_table.num_rows))])
    pq.write_table(two, tmp_path / "two.parquet")
    ok(invoke("--seed", "2", "--jobs", "2", "track", "--in", tmp_path / "two.parquet", "--out", tmp_path / "j2.parquet",
              *FAST))
    ok(invoke("--seed", "2", "track", "--in", tmp_path / "two.parquet", "--out", tmp_path / "j1.parquet", *FAST))
    assert (tmp_path / "j1.parquet").read_bytes() == (tmp_path / "j2.parquet").read_bytes()


# ------------------------------------------------------------------------------------------------ segment
def test_segment_writes_segment_column_and_prints_a_summary(tmp_path, contacts_file):
    tracks = tmp_path / "t.parquet"
    ok(track(contacts_file, tracks, *FAST))
    seg, png = tmp_path / "s.parquet", tmp_path / "s.png"
    res = ok(invoke("segment", "--in", tracks, "--out", seg, "--print", "--plot", png))
    segs = schema.read_segments(seg)
    assert segs.column_names[-1] == "segment" and segs.num_rows == 13
    assert segs.drop_columns(["segment"]).equals(schema.read_tracks(tracks))
    meta = schema.read_metadata(seg)
    tracking = meta["params"].pop("tracking")
    assert meta["stage"] == "segment" and meta["params"] == dict(length=0.02, alpha=0.4, by="components",
                                                                 method="stucco", every_step=False)
    # what the segments keep of the tracking behind them: its parameters, seed and contacts
    tmeta = schema.read_metadata(tracks)
    assert tracking == {"params": tmeta["params"], "seed": tmeta["seed"],
                        "contacts_sha256": tmeta["inputs"]["contacts"]["sha256"]}
    assert meta["seed"] == tmeta["seed"]
    lines = res.stdout.strip().splitlines()
    assert lines[0].split() == ["run", "segment", "points", "centroid_x_m", "centroid_y_m", "run_FMI"]
    n_seg = len(set(segs.column("segment").to_pylist()))
    assert len(lines) == 1 + n_seg
    assert sum(int(line.split()[2]) for line in lines[1:]) == 13
    assert all(line.split()[0] == "r" and 0.0 <= float(line.split()[-1]) <= 1.0 for line in lines[1:])
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert "segmented 1 run(s), 13 rows" in res.stderr


def test_segment_options_override_the_tracks_metadata(tmp_path, contacts_file):
    tracks = tmp_path / "t.parquet"
    ok(track(contacts_file, tracks, *FAST, "--length", "0.05"))
    ok(invoke("segment", "--in", tracks, "--out", tmp_path / "meta.parquet"))
    assert schema.read_metadata(tmp_path / "meta.parquet")["params"]["length"] == 0.05
    ok(invoke("segment", "--in", tracks, "--out", tmp_path / "one.parquet", "--alpha", "1e-300", "--by", "components"))
    assert set(schema.read_segments(tmp_path / "one.parquet").column("segment").to_pylist()) == {0}
    ok(invoke("segment", "--in", tracks, "--out", tmp_path / "many.parquet", "--alpha", "0.9999999999999999"))
    many = schema.read_segments(tmp_path / "many.parquet")
    seg = many.column("segment").to_numpy()
    xy = np.c_[many.column("x_m").to_numpy(), many.column("y_m").to_numpy()]
    # alpha just below 1: the connection radius is nanometres, so only coincident points share a segment
    assert len(np.unique(seg)) == len(np.unique(np.round(xy, 8), axis=0)) > 1
    assert all(np.ptp(xy[seg == k], axis=0).max() < 1e-8 for k in np.unique(seg))


def test_segment_missing_input_is_one_line(tmp_path):
    res = invoke("segment", "--in", tmp_path / "nope.parquet", "--out", tmp_path / "s.parquet")
    assert_one_line_error(res, "nope.parquet", "file not found")
    only_input_left(tmp_path)


def test_segment_refuses_a_contacts_file(tmp_path, contacts_file):
    res = invoke("segment", "--in", contacts_file, "--out", tmp_path / "s.parquet")
    assert_one_line_error(res, "contacts.parquet", "column 'contact_index'")
    only_input_left(tmp_path, contacts_file)


# ------------------------------------------------------------------------------------------------ track errors
def _null_at(col: pa.ChunkedArray, row: int) -> pa.Array:
    values = col.to_pylist()
    values[row] = None
    return pa.array(values, col.type)


def _set_at(col: pa.ChunkedArray, row: int, value) -> pa.Array:
    values = col.to_pylist()
    values[row] = value
    return pa.array(values, col.type)


BAD_TABLES = {
    "missing column": (lambda t: t.drop_columns(["dy_m"]), "column 'dy_m'", "missing"),
    "NaN in ee_x_m": (lambda t: t.set_column(2, "ee_x_m", _set_at(t["ee_x_m"], 5, float("nan"))),
                      "column 'ee_x_m', row 5", "finite"),
    "contact without displacement": (lambda t: t.set_column(7, "dx_m", _null_at(t["dx_m"], 33)),
                                     "column 'dx_m', row 33", "contact without displacement"),
    "decreasing step": (lambda t: t.set_column(1, "step", _set_at(t["step"], 10, 3)),
                        "column 'step', row 10", "step 3 follows step 9"),
}


@pytest.mark.parametrize("case", list(BAD_TABLES))
def test_track_bad_table_is_one_line_naming_file_and_column(tmp_path, contacts_table, case):
    edit, column, what = BAD_TABLES[case]
    assert contacts_table.column_names[1:3] == ["step", "ee_x_m"] and contacts_table.column_names[7] == "dx_m"
    bad = tmp_path / "bad.parquet"
    pq.write_table(edit(contacts_table), bad)
    res = track(bad, tmp_path / "t.parquet", *FAST)
    assert_one_line_error(res, str(bad), column, what)
    only_input_left(tmp_path, bad)


def test_track_missing_input_file(tmp_path):
    res = track(tmp_path / "absent.parquet", tmp_path / "t.parquet", *FAST)
    assert_one_line_error(res, "absent.parquet", "file not found")
    only_input_left(tmp_path)


def test_track_not_a_parquet_file(tmp_path):
    junk = tmp_path / "junk.parquet"
    junk.write_text("run,step\n")
    res = track(junk, tmp_path / "t.parquet", *FAST)
    assert_one_line_error(res, "junk.parquet", "not a Parquet file")
    only_input_left(tmp_path, junk)


@pytest.mark.parametrize("args, needles", [
    (["--robot", "cube"], ["unknown robot 'cube'", "disc:RADIUS"]),
    (["--robot", "disc:-1"], ["radius must be positive"]),
    (["--method", "nope", "--robot", "disc:0.05"], ["unknown method 'nope'", "stucco"]),
    (["--method", "dbscan", "--robot", "disc:0.05", "--set", "bogus=1"], ["unknown parameter(s) 'bogus'"]),
])
def test_track_bad_values_are_one_line(tmp_path, contacts_file, args, needles):
    res = track(contacts_file, tmp_path / "t.parquet", *args)
    assert_one_line_error(res, *needles)
    only_input_left(tmp_path, contacts_file)


@pytest.mark.parametrize("args, needles", [
    (["--weighting", "raw"], ["--weighting", "'raw'"]),
    (["--replace", "always"], ["--replace"]),
    (["--method", "dbscan", "--length", "0.1"], ["--length applies to --method stucco only"]),
    (["--method", "kmeans", "--weighting", "paper"], ["--weighting applies to --method stucco only"]),
    (["--set", "novalue"], ["KEY=VALUE"]),
])
def test_track_bad_options_are_usage_errors(tmp_path, contacts_file, args, needles):
    res = track(contacts_file, tmp_path / "t.parquet", "--robot", "disc:0.05", *args)
    assert_usage_error(res, *needles)
    only_input_left(tmp_path, contacts_file)


def test_track_unknown_stucco_parameter_is_one_line(tmp_path, contacts_file):
    res = track(contacts_file, tmp_path / "t.parquet", "--robot", "disc:0.05", "--set", "bogus=1")
    assert_one_line_error(res, "bogus")


def test_track_nan_alpha_is_one_line(tmp_path, contacts_file):
    res = track(contacts_file, tmp_path / "t.parquet", "--robot", "disc:0.05", "--alpha", "nan")
    assert_usage_error(res, "--alpha", "not a finite number")  # more cases: tests/cli/test_bad_values.py


def test_track_particles_with_a_baseline_names_the_real_option(tmp_path, contacts_file):
    res = track(contacts_file, tmp_path / "t.parquet", "--robot", "disc:0.05", "--method", "kmeans",
                "--particles", "5")
    assert_usage_error(res, "--particles applies to --method stucco only")


# ------------------------------------------------------------------------------------------- outputs vs inputs


@pytest.mark.parametrize("command, clash", [
    ("track", "out=in"), ("track", "diagnostics=in"), ("track", "diagnostics=out"),
    ("segment", "out=in"), ("segment", "plot=in"),
    ("retrieve", "out=segments"), ("retrieve", "candidates=segments"), ("retrieve", "candidates=out"),
    ("score", "out=retrieval"), ("score", "out=segments"), ("score", "out=diagnostics"),
])
def test_no_command_overwrites_its_input_or_writes_two_outputs_to_one_file(tmp_path, command, clash):
    """Refused in one line before any work; every file is byte-identical afterwards."""
    from stucco_cli.main import cli

    files = {name: tmp_path / f"{name}.parquet" for name in ("in", "out", "segments", "retrieval", "diagnostics",
                                                             "candidates", "plot")}
    for f in files.values():
        f.write_bytes(b"precious " + f.name.encode())
    before = {f: f.read_bytes() for f in files.values()}
    a, b = clash.split("=")
    files[a] = files[b]
    runs = tmp_path / "runs"
    runs.mkdir()
    args = {
        "track": ["track", "--in", files["in"], "--out", files["out"], "--diagnostics", files["diagnostics"]],
        "segment": ["segment", "--in", files["in"], "--out", files["out"], "--plot", files["plot"]],
        "retrieve": ["retrieve", "--segments", files["segments"], "--runs", runs, "--out", files["out"],
                     "--candidates", files["candidates"]],
        "score": ["score", "--retrieval", files["retrieval"], "--segments", files["segments"], "--runs", runs,
                  "--diagnostics", files["diagnostics"], "--out", files["out"]],
    }[command]
    r = CliRunner().invoke(cli, [str(x) for x in args])
    assert r.exit_code == 2, r.output
    last = [ln for ln in r.output.splitlines() if ln.strip()][-1]
    assert last.startswith("Error: --") and ("never overwrites its own input" in last or "cannot share" in last), last
    assert "Traceback" not in r.output
    assert {f: f.read_bytes() for f in before} == before
