"""The segments keep what they were tracked from (``params.tracking``: the tracker's parameters, its seed, its contacts
table), and the later stages check their other inputs against it instead of believing them: the method and robot
``retrieve`` is given, a run file of a run tracked without any contact, the diagnostics ``score`` takes its timings
from. Each refusal is one line naming the file."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from pipeline import schema
from stucco_cli.main import cli

REGRESSION = Path(__file__).resolve().parents[2] / "data" / "regression"
FAST = ["--robot", "disc:0.05", "--particles", "20"]


def _run(*args):
    return CliRunner().invoke(cli, ["-q", *[str(a) for a in args]])


def _ok(*args):
    r = _run(*args)
    assert r.exit_code == 0, r.output
    return r


def _fails(*args) -> str:
    r = _run(*args)
    assert r.exit_code != 0 and "Traceback" not in r.output, r.output
    return [line for line in r.output.splitlines() if line.strip()][-1]


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """FB/0 and TC/0 of the regression runs isolated, tracked (disc gripper, 20 particles, seed 0) and segmented."""
    d = tmp_path_factory.mktemp("provenance")
    (d / "runs").mkdir()
    for name in ("FB-000.parquet", "TC-000.parquet"):
        shutil.copy(REGRESSION / name, d / "runs" / name)
    _ok("isolate", "--in", d / "runs", "--out", d / "contacts.parquet")
    _ok("track", "--in", d / "contacts.parquet", "--out", d / "tracks.parquet", *FAST)
    _ok("segment", "--in", d / "tracks.parquet", "--out", d / "segments.parquet")
    return d


def test_retrieve_takes_the_robot_the_points_were_tracked_with_and_refuses_another(made, tmp_path):
    out = tmp_path / "r.parquet"
    _ok("retrieve", "--segments", made / "segments.parquet", "--runs", made / "runs", "--out", out, "--no-grasp")
    assert schema.read_metadata(out)["params"]["robot"] == "disc:0.05"
    last = _fails("retrieve", "--segments", made / "segments.parquet", "--runs", made / "runs", "--out",
                  tmp_path / "p.parquet", "--no-grasp", "--robot", "panda")
    assert "tracked with robot 'disc:0.05', not 'panda'" in last and "segments.parquet" in last
    assert not (tmp_path / "p.parquet").exists()
    # the same gripper spelled otherwise is the same gripper (its grid's digest)
    _ok("retrieve", "--segments", made / "segments.parquet", "--runs", made / "runs", "--out", tmp_path / "s.parquet",
        "--no-grasp", "--robot", "disc:0.050")


def test_retrieve_refuses_a_method_the_segments_were_not_tracked_by(made, tmp_path):
    last = _fails("retrieve", "--segments", made / "segments.parquet", "--runs", made / "runs", "--out",
                  tmp_path / "r.parquet", "--no-grasp", "--method", "kmeans")
    assert "tracked by method 'stucco', not 'kmeans'" in last


def test_segment_records_the_seed_of_its_tracks_not_its_own(made, tmp_path):
    _ok("--seed", 3, "track", "--in", made / "contacts.parquet", "--out", tmp_path / "t3.parquet", *FAST)
    _ok("segment", "--in", tmp_path / "t3.parquet", "--out", tmp_path / "s3.parquet")  # its own seed: 0
    assert schema.read_metadata(tmp_path / "s3.parquet")["seed"] == 3
    # ...so the runs collected with root seed 0 are not taken for these seed-3 tracks' runs
    last = _fails("retrieve", "--segments", tmp_path / "s3.parquet", "--runs", made / "runs", "--out",
                  tmp_path / "r.parquet", "--no-grasp")
    assert "root seed 0" in last and "seed 3" in last
    # and seed-0 tracks segmented under --seed 3 are still seed 0's: accepted
    _ok("--seed", 3, "segment", "--in", made / "tracks.parquet", "--out", tmp_path / "s0.parquet")
    assert schema.read_metadata(tmp_path / "s0.parquet")["seed"] == 0
    _ok("retrieve", "--segments", tmp_path / "s0.parquet", "--runs", made / "runs", "--out", tmp_path / "r0.parquet",
        "--no-grasp")


def test_score_refuses_diagnostics_of_another_tracking(made, tmp_path):
    retrieval = tmp_path / "r.parquet"
    _ok("retrieve", "--segments", made / "segments.parquet", "--runs", made / "runs", "--out", retrieval,
        "--no-grasp")
    _ok("score", "--retrieval", retrieval, "--segments", made / "segments.parquet", "--runs", made / "runs", "--out",
        tmp_path / "own.parquet", "--diagnostics", made / "tracks.diagnostics.parquet")
    _ok("track", "--in", made / "contacts.parquet", "--out", tmp_path / "t40.parquet", "--robot", "disc:0.05",
        "--particles", "40")
    last = _fails("score", "--retrieval", retrieval, "--segments", made / "segments.parquet", "--runs",
                  made / "runs", "--out", tmp_path / "s.parquet", "--diagnostics", tmp_path / "t40.diagnostics.parquet")
    assert "t40.diagnostics.parquet" in last and "not the tracking" in last and "params differs" in last
    assert not (tmp_path / "s.parquet").exists()


def test_a_run_tracked_without_contact_is_checked_against_its_recorded_run_file(tmp_path):
    # FB/0 cut to one action has no contact, so no segment row: its run file is still the one checked
    _ok("collect", "--scene", "FB", "--seeds", 0, "--max-actions", 1, "--out", tmp_path / "short")
    ok, bad = tmp_path / "ok", tmp_path / "bad"
    ok.mkdir()
    bad.mkdir()
    shutil.copy(tmp_path / "short" / "FB-000.parquet", ok / "FB-000.parquet")
    shutil.copy(REGRESSION / "FB-000.parquet", bad / "FB-000.parquet")  # the whole run, filed under the same name
    for d in (ok, bad):
        shutil.copy(REGRESSION / "TC-000.parquet", d / "TC-000.parquet")
    _ok("isolate", "--in", ok, "--out", tmp_path / "c.parquet")
    _ok("track", "--in", tmp_path / "c.parquet", "--out", tmp_path / "t.parquet", *FAST)
    _ok("segment", "--in", tmp_path / "t.parquet", "--out", tmp_path / "s.parquet")
    assert "FB/0" not in set(schema.read_segments(tmp_path / "s.parquet").column("run").to_pylist())
    _ok("retrieve", "--segments", tmp_path / "s.parquet", "--runs", ok, "--out", tmp_path / "r.parquet", "--no-grasp")
    last = _fails("retrieve", "--segments", tmp_path / "s.parquet", "--runs", bad, "--out", tmp_path / "x.parquet",
                  "--no-grasp")
    assert "FB-000.parquet" in last and "not the run FB/0" in last
    last = _fails("score", "--retrieval", tmp_path / "r.parquet", "--segments", tmp_path / "s.parquet", "--runs", bad,
                  "--out", tmp_path / "sc.parquet")
    assert "not the run FB/0" in last


def test_isolate_records_the_runs_root_seed_and_refuses_runs_of_two(tmp_path):
    _ok("--seed", 3, "collect", "--scene", "FB", "--seeds", 0, "--max-actions", 2, "--out", tmp_path / "s3")
    _ok("isolate", "--in", tmp_path / "s3", "--out", tmp_path / "c3.parquet")  # its own seed: 0, drawing nothing
    assert schema.read_metadata(tmp_path / "c3.parquet")["seed"] == 3
    (tmp_path / "mixed").mkdir()
    shutil.copy(tmp_path / "s3" / "FB-000.parquet", tmp_path / "mixed" / "FB-000.parquet")
    shutil.copy(REGRESSION / "TC-000.parquet", tmp_path / "mixed" / "TC-000.parquet")  # root seed 0
    last = _fails("isolate", "--in", tmp_path / "mixed", "--out", tmp_path / "cm.parquet")
    assert "root seeds 0, 3" in last and not (tmp_path / "cm.parquet").exists()
