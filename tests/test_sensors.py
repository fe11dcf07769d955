"""Tactile fingertips and a noisy wrench (docs/simulation.md, "Tactile fingertips and a noisy wrench"): the scene
keys, what the simulator reports, isolation taking the pads first, and the settings a scene's robot was tuned with."""
from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from pipeline import schema
from pipeline.collect import collect_file, collect_run
from pipeline.detection import DetectionParams, scene_detection
from pipeline.isolate import isolate_file, isolate_runs
from pipeline.scenes import SceneError, load_scene, parse_scene
from pipeline.sim.effects import NO_CONTACT, summarize_pads, wrench_noise

SCENES = Path(__file__).resolve().parents[1] / "data" / "scenes"
ACTIONS = 60  # REAL's first 60 actions touch the kettle, the mustard and the box, with and without the pads


def _real_doc() -> dict:
    return tomllib.loads((SCENES / "REAL.toml").read_text())


def _parse(doc: dict):
    return parse_scene(doc, Path("X.toml"))


@pytest.fixture(scope="module")
def real_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("real")
    path = out / "REAL-000.parquet"
    collect_file(load_scene("REAL"), 0, path, max_actions=ACTIONS)
    return path


# ------------------------------------------------------------------------------------------- scene keys


def test_a_scene_without_sensors_asks_for_none_and_keeps_the_default_detector():
    fb = load_scene("FB")
    assert not fb.sensors.any and fb.hardware.detection == {} and fb.hardware.methods == {}
    assert scene_detection(fb) == DetectionParams()


def test_real_declares_the_papers_real_settings():
    real = load_scene("REAL")
    assert real.sensors.fingertips and real.sensors.pad_noise_mm == 2.0
    assert scene_detection(real).threshold == 5.0  # Table I's real residual threshold
    assert real.hardware.method_params("stucco") == {"length": 0.006, "tolerance": 0.010}  # Table I, real column
    assert real.hardware.method_params("dbscan") == {"eps": 0.1}
    assert real.hardware.method_params("birch") == {}
    assert real.action_scale == 0.02  # the real robot's 2 cm steps


@pytest.mark.parametrize("table, key, value, message", [
    ("sensors", "pad_noise_mm", -1.0, "sensors.pad_noise_mm"),
    ("sensors", "pad_threshold_n", 0.0, "sensors.pad_threshold_n"),
    ("sensors", "wrench_noise", [1.0, 2.0], "sensors.wrench_noise"),
    ("sensors", "wrench_noise", [1.0, -1.0, 0, 0, 0, 0], "sensors.wrench_noise"),
    ("sensors", "fingertip", True, "sensors.fingertip"),
    ("detection", "threshold", -5.0, "detection.threshold"),
    ("detection", "window", 3, "detection.window"),
    ("methods", "stucco", 0.006, "methods.stucco"),
])
def test_bad_sensor_keys_are_refused_naming_the_key(table, key, value, message):
    doc = _real_doc()
    doc[table][key] = value
    with pytest.raises(SceneError, match=message) as err:
        _parse(doc)
    assert "\n" not in str(err.value) and "X.toml" in str(err.value)


def test_a_methods_value_that_is_not_a_number_is_refused():
    doc = _real_doc()
    doc["methods"]["stucco"]["length"] = [0.006]
    with pytest.raises(SceneError, match="methods.stucco.length"):
        _parse(doc)


# ------------------------------------------------------------------------------------------- the pads


def test_summarize_pads_reports_the_last_firing_point_and_the_displacement_while_firing():
    s = 6
    readings = np.zeros((s, 2, 4))
    readings[:, :, 3] = NO_CONTACT
    readings[1:4, 0] = [3.0, 0.5, 0.1, 2]  # pad 0 pressed at steps 1-3 by object 2
    readings[3, 0, 1:3] = [0.52, 0.11]  # its last firing point
    readings[4, 1] = [1.5, 0.6, -0.1, 1]  # pad 1 only under the threshold 2 N
    start = np.array([0.0, 0.0])
    pos = np.cumsum(np.full((s, 2), [0.01, 0.0]), axis=0)  # 1 cm per sim step along x
    out = summarize_pads(readings, start, pos, 2.0, 0.0, np.random.default_rng(0))
    np.testing.assert_allclose(out["point"][0], [0.52, 0.11])
    np.testing.assert_allclose(out["dx"][0], [0.03, 0.0])  # three firing steps of 1 cm
    assert out["object"].tolist() == [2, NO_CONTACT]
    assert np.isnan(out["point"][1]).all() and np.isnan(out["dx"][1]).all()
    np.testing.assert_allclose(out["force"], [3.0, 1.5])


def test_pad_noise_is_drawn_once_per_action_whatever_fired():
    """The draws do not depend on the contacts: a run's later draws are the same whatever its pads felt."""
    quiet = np.zeros((3, 2, 4))
    quiet[:, :, 3] = NO_CONTACT
    pressed = quiet.copy()
    pressed[:, 0] = [5.0, 0.1, 0.2, 0]
    a, b = np.random.default_rng(5), np.random.default_rng(5)
    summarize_pads(quiet, np.zeros(2), np.zeros((3, 2)), 1.0, 0.002, a)
    out = summarize_pads(pressed, np.zeros(2), np.zeros((3, 2)), 1.0, 0.002, b)
    assert a.random() == b.random()
    assert np.all(np.abs(out["point"][0] - [0.1, 0.2]) < 0.01) and not np.array_equal(out["point"][0], [0.1, 0.2])


def test_wrench_noise_has_the_asked_spread_and_nothing_where_sigma_is_zero():
    sigma = (1.0, 2.0, 0.0, 0.3, 0.3, 0.0)
    n = wrench_noise(np.random.default_rng(0), 20000, sigma)
    assert n.shape == (20000, 6)
    np.testing.assert_allclose(n.std(axis=0), sigma, atol=0.03)
    assert np.all(n[:, [2, 5]] == 0.0)


def test_a_run_with_fingertips_is_deterministic_and_logs_every_pad(real_run, tmp_path):
    again = tmp_path / "REAL-000.parquet"
    collect_file(load_scene("REAL"), 0, again, max_actions=ACTIONS)
    assert real_run.read_bytes() == again.read_bytes()
    t = schema.read_run(real_run)
    point = np.asarray(t.column("pad_contact_m").to_pylist(), dtype=float)
    obj = np.asarray(t.column("pad_object").to_pylist())
    assert point.shape == (ACTIONS, 2, 2)
    fired = np.isfinite(point[:, :, 0])
    assert fired.any(), "the rummage's first pass presses the pads on the box"
    assert np.all(obj[fired] >= 0) and np.all(obj[~fired] == NO_CONTACT)
    meta = schema.read_metadata(real_run)["params"]
    assert meta["detection"]["threshold"] == 5.0 and meta["sensors"]["fingertips"] is True


def test_a_scene_without_sensors_logs_no_pad_column_and_draws_nothing_more():
    fb = load_scene("FB")
    table, params, _ = collect_run(fb, 0, max_actions=5)
    assert not any(c.startswith("pad_") for c in table.column_names) and "sensors" not in params
    # the noise draws of the replay (first stream) are those of a run collected before the sensors existed:
    # the stored regression run's commands are these commands
    stored = pq.read_table(Path(__file__).resolve().parents[1] / "data" / "regression" / "FB-000.parquet")
    np.testing.assert_array_equal(table.column("cmd_ux").to_numpy(), stored.column("cmd_ux").to_numpy()[:5])


def test_wrench_noise_leaves_the_trajectory_unchanged():
    """The noise is sensing: the gripper and the objects move the same with and without it."""
    real = load_scene("REAL")
    quiet = dataclasses.replace(real, sensors=dataclasses.replace(real.sensors, wrench_noise=(0.0,) * 6))
    a, _, _ = collect_run(real, 0, max_actions=12)
    b, _, _ = collect_run(quiet, 0, max_actions=12)
    np.testing.assert_array_equal(a.column("ee_x_m").to_numpy(), b.column("ee_x_m").to_numpy())
    wa = np.asarray(a.column("win_wrench").to_pylist(), dtype=float)
    wb = np.asarray(b.column("win_wrench").to_pylist(), dtype=float)
    assert not np.array_equal(wa, wb)


# ------------------------------------------------------------------------------------------- isolation


def test_isolation_takes_the_pads_first_and_the_wrench_only_where_none_fired(real_run):
    res = isolate_runs([real_run])
    c = res.table.to_pydict()
    assert res.detection.threshold == 5.0  # the detector the run was collected with
    t = schema.read_run(real_run)
    point = np.asarray(t.column("pad_contact_m").to_pylist(), dtype=float)
    fired = np.isfinite(point[:, :, 0])
    step = np.asarray(c["step"])
    sensor = c["sensor"]
    for s in range(ACTIONS):
        rows = np.flatnonzero(step == s)
        if fired[s].any():
            assert [sensor[r] for r in rows] == np.flatnonzero(fired[s]).tolist()
            for r, j in zip(rows, np.flatnonzero(fired[s])):
                assert (c["contact_x_m"][r], c["contact_y_m"][r]) == tuple(point[s, j])
                assert c["in_contact"][r]
        else:
            assert len(rows) == 1 and sensor[rows[0]] in (-1, None)
            assert (sensor[rows[0]] == -1) == bool(c["in_contact"][rows[0]])
    assert (np.bincount(step) == 2).any(), "some action had both pads pressed"
    schema.validate_contacts(res.table)
    assert res.n_contact == len({s for s, inc in zip(c["step"], c["in_contact"]) if inc})


def test_isolate_file_records_the_runs_detector(real_run, tmp_path):
    out = tmp_path / "contacts.parquet"
    isolate_file([real_run], out, seed=0)
    assert schema.read_metadata(out)["params"]["detection"]["threshold"] == 5.0
    assert "sensor" in pq.read_schema(out).names


def test_a_table_of_runs_with_and_without_pads_marks_the_wrench_rows(real_run, tmp_path):
    fb = tmp_path / "FB-000.parquet"
    collect_file(load_scene("FB"), 0, fb, max_actions=8)
    res = isolate_runs([real_run, fb])
    d = res.table.to_pydict()
    fb_rows = [i for i, r in enumerate(d["run"]) if r == "FB/0"]
    assert all(d["sensor"][i] == (-1 if d["in_contact"][i] else None) for i in fb_rows)
    assert res.detection is None  # two detectors: recorded as "per run"


def test_a_run_without_pads_isolates_as_before():
    stored = Path(__file__).resolve().parents[1] / "data" / "regression" / "FB-000.parquet"
    res = isolate_runs([stored])
    assert "sensor" not in res.table.column_names and res.detection == DetectionParams()


# ------------------------------------------------------------------------------------------- evaluate and report


def test_evaluate_tracks_with_the_scenes_settings_and_reports_the_real_row(tmp_path):
    from click.testing import CliRunner

    from pipeline.layout import partition
    from stucco_cli.main import cli

    out = tmp_path / "ev"
    res = CliRunner().invoke(cli, ["-q", "evaluate", "--scenes", "REAL", "--seeds", "0", "--methods", "stucco,dbscan",
                                   "--estimators", "plausible", "--max-actions", str(ACTIONS), "--no-figures",
                                   "--jobs", "1", "--out", str(out)])
    assert res.exit_code == 0, res.output
    tracked = schema.read_metadata(partition(out, "tracks", "REAL", 0, "stucco"))["params"]
    assert tracked["length"] == 0.006 and tracked["tolerance"] == 0.010
    assert schema.read_metadata(partition(out, "tracks", "REAL", 0, "dbscan"))["params"]["eps"] == 0.1
    contacts = schema.read_contacts(partition(out, "contacts", "REAL", 0))
    assert "sensor" in contacts.column_names
    report = (out / "report.md").read_text()
    assert "100 (5 runs)" in report  # the paper's real row, beside ours
    assert "best baseline" in report and "short by" not in report  # the real row's claim, not the 65 % one
    # the stage alone, told the scene, tracks exactly as the evaluation did
    alone = tmp_path / "alone.parquet"
    res = CliRunner().invoke(cli, ["-q", "track", "--in", str(partition(out, "contacts", "REAL", 0)), "--out",
                                   str(alone), "--scene", "REAL"])
    assert res.exit_code == 0, res.output
    assert schema.read_tracks(alone).equals(schema.read_tracks(partition(out, "tracks", "REAL", 0, "stucco")))


def test_the_grasp_keeps_its_3_cm_steps_whatever_step_the_rummage_takes():
    """REAL rummages in 2 cm steps; the grasp script is the same grasp (GRASP_STEP_M), so a scene's action scale
    changes nothing of it."""
    from pipeline.grasp import grasp_at

    stored = pq.read_table(Path(__file__).resolve().parents[1] / "data" / "regression" / "FB-000.parquet")
    last = stored.num_rows - 1
    poses = np.asarray(stored.column("obj_pose")[last].as_py(), dtype=float)
    ee = np.array([stored.column("ee_x_m")[last].as_py(), stored.column("ee_y_m")[last].as_py()])
    fb = load_scene("FB")
    a = grasp_at(fb, poses, ee, poses[0])
    b = grasp_at(dataclasses.replace(fb, action_scale=0.02), poses, ee, poses[0])
    assert a.success and (a.success, a.outcome) == (b.success, b.outcome)
    np.testing.assert_array_equal(a.target_pose, b.target_pose)


def test_the_active_protocol_senses_with_the_scenes_robot_and_takes_every_contact(tmp_path):
    from pipeline.probe.belief import Sensing

    real = load_scene("REAL")
    sensing = Sensing("REAL/0", 0, np.zeros(2), 10, scene=real)
    assert sensing.detection.threshold == 5.0 and sensing.tracker.params.length == 0.006
    assert sensing.region == real.target_region
    table, params, result = collect_run(real, 0, policy="scripted+probe", max_actions=ACTIONS)
    assert table.column("probe").to_pylist()[:ACTIONS] == [False] * ACTIONS
    assert params["probe"]["probes"] >= 0 and result.n_actions == table.num_rows


def test_a_force_floor_leaves_the_weak_wrench_contacts_unisolated(real_run):
    shipped = isolate_runs([real_run])
    assert shipped.detection.min_force_n == 5.0  # REAL's own detector places no weak wrench contact
    plain = isolate_runs([real_run], dataclasses.replace(shipped.detection, min_force_n=0.0))
    det = dataclasses.replace(plain.detection, min_force_n=5.0)
    floored = isolate_runs([real_run], det)
    assert floored.table.equals(shipped.table)
    a, b = plain.table.to_pydict(), floored.table.to_pydict()
    weak = [i for i, s in enumerate(a["sensor"]) if s == -1 and a["force_n"][i] < 5.0]
    assert weak, "the noisy wrench detects weak contacts"
    assert floored.n_unisolated == plain.n_unisolated + len(weak)
    kept = [(s, st) for s, st, f in zip(a["sensor"], a["step"], a["force_n"]) if s is not None and not
            (s == -1 and f < 5.0)]
    assert [(s, st) for s, st in zip(b["sensor"], b["step"]) if s is not None] == kept  # the pads untouched
    assert all(f >= 5.0 for s, f in zip(b["sensor"], b["force_n"]) if s == -1)


def test_without_contact_truth_the_pads_record_no_object():
    real = load_scene("REAL")
    table, _, _ = collect_run(real.with_effects(contact_truth=False), 0, max_actions=ACTIONS)
    point = np.asarray(table.column("pad_contact_m").to_pylist(), dtype=float)
    assert np.isfinite(point).any()  # the pads still sense
    assert set(np.asarray(table.column("pad_object").to_pylist()).ravel().tolist()) == {NO_CONTACT}


def test_bench_sim_times_the_sensors_only_for_a_scene_that_has_them():
    from pipeline.studies.sim_effects import effect_costs

    names = [r["variant"] for r in effect_costs(load_scene("REAL"), n_actions=2, repeat=1)]
    assert "no sensors" in names
    assert "no sensors" not in [r["variant"] for r in effect_costs(load_scene("TC"), n_actions=2, repeat=1)]
