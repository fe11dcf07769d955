"""Retrieval from a robot's log (pipeline/retrieve/log_route.py, pipeline/estimators/log_run.py): a simulated
run's contacts with every ground-truth column dropped, tracked, segmented and retrieved with the target given by
its shape, give exactly the estimate the simulated route gives (docs/retrieval.md, "Retrieval from a robot's
log"); CSV logs and 0/1 booleans are read; bad specs and mismatched files are one line."""
from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pcsv
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from pipeline import schema
from pipeline.estimators.log_run import parse_target
from pipeline.schema import read_metadata, write_table
from stucco_cli.main import cli

REGRESSION = Path(__file__).resolve().parents[1] / "data" / "regression"


def _ok(*args):
    r = CliRunner().invoke(cli, ["-q", "--seed", "0", *map(str, args)])
    assert r.exit_code == 0, r.output
    return r


def _fails(*args) -> str:
    r = CliRunner().invoke(cli, ["-q", "--seed", "0", *map(str, args)])
    assert r.exit_code != 0 and "Traceback" not in r.output, r.output
    lines = [line for line in r.output.splitlines() if line.strip()]
    return lines[-1]


def _untracked_copy(src, dst):
    """A copy of a segments file that does not record its tracking (as made before it did, or by another tool):
    the log's own checks must still catch a log that does not fit it."""
    meta = read_metadata(src)
    params = {k: v for k, v in meta["params"].items() if k != "tracking"}
    write_table(schema.read_segments(src), dst, stage="segment", params=params, seed=meta["seed"], kind="segments")
    return dst


@pytest.fixture(scope="module")
def routes(tmp_path_factory):
    """The simulated route and the log route of FB seed 0, tracked with every step (for the paper estimator)."""
    d = tmp_path_factory.mktemp("routes")
    runs = d / "runs"
    runs.mkdir()
    shutil.copy(REGRESSION / "FB-000.parquet", runs / "FB-000.parquet")
    _ok("isolate", "--in", runs, "--out", d / "contacts.parquet")
    sim = pq.read_table(d / "contacts.parquet")
    log = sim.drop_columns(["object_id"])  # the ground truth a robot does not have
    pq.write_table(log, d / "log.parquet")
    for name, contacts in (("sim", d / "contacts.parquet"), ("log", d / "log.parquet")):
        _ok("track", "--in", contacts, "--out", d / f"{name}-tracks.parquet", "--every-step")
        _ok("segment", "--in", d / f"{name}-tracks.parquet", "--out", d / f"{name}-segments.parquet")
    return d


@pytest.mark.parametrize("estimator", ["plausible", "pushtrack", "paper"])
def test_the_log_route_is_the_simulation_route(routes, estimator):
    d = routes
    _ok("retrieve", "--segments", d / "sim-segments.parquet", "--runs", d / "runs", "--no-grasp",
        "--estimator", estimator, "--out", d / f"sim-{estimator}.parquet")
    _ok("retrieve", "--segments", d / "log-segments.parquet", "--contacts", d / "log.parquet",
        "--target", "FB:cracker_box", "--estimator", estimator, "--out", d / f"log-{estimator}.parquet")
    sim = pq.read_table(d / f"sim-{estimator}.parquet").to_pylist()[0]
    log = pq.read_table(d / f"log-{estimator}.parquet").to_pylist()[0]
    for k in ("x_m", "y_m", "yaw_rad", "segment", "n_points", "notes"):
        assert log[k] == sim[k], k
    assert log["run"] == sim["run"] == "FB/0"
    assert log["true_x_m"] is None and log["position_error_m"] is None and log["grasp_success"] is None
    cand_sim = pq.read_table(d / f"sim-{estimator}.candidates.parquet")
    cand_log = pq.read_table(d / f"log-{estimator}.candidates.parquet")
    assert cand_log.equals(cand_sim)


def test_a_csv_log_with_0_1_booleans_gives_the_same_pose(routes, tmp_path):
    d = routes
    log = pq.read_table(d / "log.parquet")
    as_int = log.set_column(log.column_names.index("in_contact"), "in_contact",
                            pa.array(np.asarray(log.column("in_contact").to_numpy(zero_copy_only=False), dtype=int)))
    pcsv.write_csv(as_int, tmp_path / "log.csv")
    _ok("track", "--in", tmp_path / "log.csv", "--out", tmp_path / "tracks.parquet")
    _ok("segment", "--in", tmp_path / "tracks.parquet", "--out", tmp_path / "segments.parquet")
    _ok("retrieve", "--segments", tmp_path / "segments.parquet", "--contacts", tmp_path / "log.csv",
        "--target", "box:0.0616x0.1575@10", "--out", tmp_path / "r.parquet", "--print")
    _ok("retrieve", "--segments", d / "log-segments.parquet", "--contacts", d / "log.parquet",
        "--target", "box:0.0616x0.1575@10", "--out", tmp_path / "p.parquet")
    a, b = pq.read_table(tmp_path / "r.parquet").to_pylist()[0], pq.read_table(tmp_path / "p.parquet").to_pylist()[0]
    assert (a["x_m"], a["y_m"], a["yaw_rad"]) == (b["x_m"], b["y_m"], b["yaw_rad"])


@pytest.mark.parametrize("spec, kind, half, mass", [
    ("box:0.0616x0.1575", "box", (0.0308, 0.07875), math.nan),
    ("box:0.05x0.1@2.5", "box", (0.025, 0.05), 2.5),
    ("cylinder:0.039", "cylinder", (0.039,), math.nan),
    ("TC:tomato_can", "cylinder", (0.039,), 2.0),
])
def test_target_specs(spec, kind, half, mass):
    prim, m, _ = parse_target(spec)
    assert prim.kind == kind and prim.half == pytest.approx(half)
    assert (math.isnan(m) and math.isnan(mass)) or m == pytest.approx(mass)


@pytest.mark.parametrize("spec, culprit", [
    ("box:-1x2", "expected box:WxL or cylinder:R"),
    ("sphere:1", "expected box:WxL or cylinder:R"),
    ("box:0.2x0.1", "is the short side"),
    ("box:61.6x157.5", "must be in (0, 2.0]"),
    ("FB:kettle", "has no object 'kettle'"),
    ("NOPE:thing", "NOPE"),
])
def test_a_bad_target_is_one_line(routes, spec, culprit):
    d = routes
    last = _fails("retrieve", "--segments", d / "log-segments.parquet", "--contacts", d / "log.parquet",
                  "--target", spec, "--out", d / "bad.parquet")
    assert culprit in last and "--target" in last


def test_a_log_needs_its_target_and_segments_of_its_own_runs(routes, tmp_path):
    d = routes
    assert "needs --target" in _fails("retrieve", "--segments", d / "log-segments.parquet", "--contacts",
                                      d / "log.parquet", "--out", tmp_path / "r.parquet")
    assert "not both" in _fails("retrieve", "--segments", d / "log-segments.parquet", "--contacts", d / "log.parquet",
                                "--runs", d / "runs", "--target", "FB:cracker_box", "--out", tmp_path / "r.parquet")
    other = pq.read_table(d / "log.parquet")
    other = other.set_column(0, "run", pa.array(["lab-1"] * other.num_rows))
    pq.write_table(other, tmp_path / "other.parquet")
    last = _fails("retrieve", "--segments", d / "log-segments.parquet", "--contacts", tmp_path / "other.parquet",
                  "--target", "FB:cracker_box", "--out", tmp_path / "r.parquet")
    assert "not the contacts table" in last and "was tracked from" in last
    bare = _untracked_copy(d / "log-segments.parquet", tmp_path / "bare-segments.parquet")
    last = _fails("retrieve", "--segments", bare, "--contacts", tmp_path / "other.parquet",
                  "--target", "FB:cracker_box", "--out", tmp_path / "r.parquet")
    assert "run 'FB/0' is not in the contacts table" in last
    assert not (tmp_path / "r.parquet").exists()


def test_a_csv_missing_a_column_or_with_a_bad_boolean_is_one_line(routes, tmp_path):
    log = pq.read_table(routes / "log.parquet")
    pcsv.write_csv(log.drop_columns(["ee_y_m"]), tmp_path / "a.csv")
    assert "ee_y_m" in _fails("track", "--in", tmp_path / "a.csv", "--out", tmp_path / "t.parquet")
    ints = np.asarray(log.column("in_contact").to_numpy(zero_copy_only=False), dtype=int)
    ints[3] = 2
    bad = log.set_column(log.column_names.index("in_contact"), "in_contact", pa.array(ints))
    pq.write_table(bad, tmp_path / "b.parquet")
    last = _fails("track", "--in", tmp_path / "b.parquet", "--out", tmp_path / "t.parquet")
    assert "in_contact" in last and "row 3" in last and "1/0" in last


def test_the_readme_route_with_a_disc_gripper(routes, tmp_path):
    """README's "Your own robot log": CSV log -> track -> segment -> retrieve with the gripper a 5 cm disc."""
    pcsv.write_csv(pq.read_table(routes / "log.parquet"), tmp_path / "mylog.csv")
    _ok("track", "--in", tmp_path / "mylog.csv", "--out", tmp_path / "t.parquet", "--robot", "disc:0.05")
    _ok("segment", "--in", tmp_path / "t.parquet", "--out", tmp_path / "s.parquet")
    _ok("retrieve", "--segments", tmp_path / "s.parquet", "--contacts", tmp_path / "mylog.csv", "--target",
        "box:0.0616x0.1575@10", "--robot", "disc:0.05", "--out", tmp_path / "pose.parquet")
    row = pq.read_table(tmp_path / "pose.parquet").to_pylist()[0]
    assert all(np.isfinite([row["x_m"], row["y_m"], row["yaw_rad"]])) and row["scene"] == "log"
    assert (tmp_path / "pose.candidates.parquet").is_file()
    meta = pq.read_schema(tmp_path / "pose.parquet").metadata
    assert b"disc:0.05" in meta[b"stucco.params"] and b"box:0.0616x0.1575@10" in meta[b"stucco.params"]


def test_a_log_with_an_unlogged_move_is_refused(routes, tmp_path):
    log = pq.read_table(routes / "log.parquet")
    xs = np.array(log.column("ee_start_x_m").to_numpy(zero_copy_only=False), dtype=float)
    xs[5] += 0.05  # step 5 starts 5 cm from where step 4 ended
    pq.write_table(log.set_column(log.column_names.index("ee_start_x_m"), "ee_start_x_m", pa.array(xs)),
                   tmp_path / "gap.parquet")
    bare = _untracked_copy(routes / "log-segments.parquet", tmp_path / "bare-segments.parquet")
    last = _fails("retrieve", "--segments", bare, "--contacts", tmp_path / "gap.parquet",
                  "--target", "FB:cracker_box", "--out", tmp_path / "r.parquet")
    assert "step 5: starts 50.0 mm from where step 4 ended" in last and "contiguous" in last


def test_an_object_that_is_not_the_scenes_target_takes_the_plan_of_its_shape():
    assert parse_target("FB:tomato_can")[2].name == "TC"
    assert parse_target("TC:tomato_can")[2].name == "TC"
    assert parse_target("FB:cracker_box")[2].name == "FB"


def test_a_shape_spec_takes_the_plan_any_scene_of_its_own_gets():
    from pipeline.grasp import DEEP_BOX, PLANS, plan_for

    box = plan_for(parse_target("box:0.0616x0.1575")[2])
    assert (box.offset, box.yaw_range, box.guarded_steps) == (DEEP_BOX.offset, DEEP_BOX.yaw_range, 5)
    assert plan_for(parse_target("cylinder:0.04")[2]) is PLANS["TC"]
    mustard = plan_for(parse_target("REAL:mustard")[2])  # a box that is not REAL's target: REAL's plan, its box's
    assert (mustard.offset, mustard.yaw_range, mustard.guarded_steps) == (DEEP_BOX.offset, DEEP_BOX.yaw_range, 5)


def test_grasp_is_refused_for_a_log(routes, tmp_path):
    last = _fails("retrieve", "--segments", routes / "log-segments.parquet", "--contacts", routes / "log.parquet",
                  "--target", "FB:cracker_box", "--grasp", "--out", tmp_path / "r.parquet")
    assert "--grasp needs a simulated run" in last


def test_a_pose_from_a_log_is_drawn_without_a_scene(routes, tmp_path):
    # the README's log route ends with a picture: the trail from the log, the segments, the estimated outline
    d = routes
    pose = tmp_path / "pose.parquet"
    _ok("retrieve", "--segments", d / "log-segments.parquet", "--contacts", d / "log.parquet",
        "--target", "box:0.0616x0.1575@10", "--out", pose)
    shutil.copy(d / "log.parquet", tmp_path / "log.parquet")
    shutil.copy(d / "log-segments.parquet", tmp_path / "log-segments.parquet")
    _ok("plot", "--in", pose, "--out", tmp_path / "pose.png")
    assert (tmp_path / "pose.png").stat().st_size > 10_000
    from pipeline.figures.tables import _log_of

    log = _log_of(pose, pq.read_table(pose).column("run")[0].as_py())
    assert log["spec"] == "box:0.0616x0.1575@10" and log["target"].kind == "box" and len(log["ee"]) > 0
