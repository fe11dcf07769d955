"""isolate: detection kernels, isolation on known geometry, and the isolation error on a stored FB run."""
from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pipeline.geometry import gripper_yaw
from pipeline.isolate import (
    DetectionParams,
    contact_window,
    isolate_point,
    isolate_runs,
    residual,
    step_in_contact,
    window_in_contact,
)
from pipeline.schema import read_contacts, read_metadata, validate_contacts

REGRESSION = Path(__file__).resolve().parents[1] / "data" / "regression" / "FB-000.parquet"
# Measured on the stored run (FB seed 0, 54 actions, 40 in contact; docs/simulation.md): median 1.8 mm,
# p90 62 mm. The bounds leave a little room for changes of the surface points.
MEDIAN_BOUND_M = 0.0025
P90_BOUND_M = 0.070


# ------------------------------------------------------------------------------------------------ detection


def test_residual_weights_torques_by_fifty():
    w = np.array([[1.0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0.2], [0.6, 0.8, 0, 0.1, 0, 0]])
    np.testing.assert_allclose(residual(w), [1.0, 2.0, 1.5])


def test_step_in_contact_is_strictly_above_threshold_and_nan_is_free_space():
    w = np.array([[1.0, 0, 0, 0, 0, 0], [1.01, 0, 0, 0, 0, 0], [np.nan] * 6, [0.0] * 6])
    np.testing.assert_array_equal(step_in_contact(w), [False, True, False, False])


@pytest.mark.parametrize("flags, idx", [
    ([0, 0, 0, 0, 0], []),
    ([1, 1, 1, 1, 1], [1, 2, 3, 4]),          # at most 4 wrenches
    ([1, 1, 0, 1, 0], [3]),                   # latest contact, preceding run broken by a free step
    ([0, 1, 1, 0, 0], [1, 2]),
    ([1, 0, 0, 0, 0, 0], []),                 # contact only before the 5-step window
])
def test_contact_window(flags, idx):
    got = contact_window(np.array(flags, dtype=bool))
    assert got.tolist() == idx
    assert window_in_contact(np.array(flags, dtype=bool), DetectionParams().window) == bool(idx)


# ------------------------------------------------------------------------------------------------ isolation


def _square():
    """Candidate points on a 0.2 m square centred on the origin, 1 cm apart, with outward normals."""
    s = np.linspace(-0.09, 0.09, 19)
    pts, nrm = [], []
    for (nx, ny) in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        for t in s:
            pts.append((0.1 * nx + t * abs(ny), 0.1 * ny + t * abs(nx)))
            nrm.append((nx, ny))
    return np.array(pts), np.array(nrm, dtype=float)


def _wrench_at(point, force):
    return np.asarray(force, float), -point[1] * force[0] + point[0] * force[1]


def test_isolation_recovers_a_pure_normal_contact():
    pts, nrm = _square()
    for k in (0, 7, 25, 50, 70):
        f, tau = _wrench_at(pts[k], -2.0 * nrm[k])
        assert isolate_point(f[None], np.array([tau]), pts, nrm) == k


def test_isolation_with_friction_inside_the_cone_and_several_wrenches():
    pts, nrm = _square()
    k = 12  # on the +x face
    forces = np.array([[-3.0, 1.0], [-3.0, 2.0], [-2.0, -1.0]])  # all within 50 deg of -n = (-1, 0)
    taus = np.array([_wrench_at(pts[k], f)[1] for f in forces])
    assert isolate_point(forces, taus, pts, nrm) == k


def test_isolation_drops_the_oldest_wrench_when_nothing_explains_all():
    pts, nrm = _square()
    k = 40  # on the +y face
    new_f, new_tau = _wrench_at(pts[k], np.array([0.0, -2.0]))
    forces = np.array([[2.0, 0.0], new_f])  # the oldest pushes from -x: no point is valid for both
    assert isolate_point(forces, np.array([0.0, new_tau]), pts, nrm) == k


def test_isolation_without_any_valid_point_returns_none():
    pts = np.array([[0.1, 0.0]])
    nrm = np.array([[1.0, 0.0]])
    assert isolate_point(np.array([[1.0, 0.0]]), np.array([0.0]), pts, nrm) is None  # pulling, not pushing
    assert isolate_point(np.zeros((0, 2)), np.zeros(0), pts, nrm) is None


@pytest.mark.parametrize("yaw", [0.0, 0.3, -1.2])
def test_gripper_yaw_reads_the_in_plane_rotation(yaw):
    import pybullet as p

    q = p.getQuaternionFromEuler((0.0, math.pi / 2, 0.0))
    rz = p.getQuaternionFromEuler((0.0, 0.0, yaw))
    _, qq = p.multiplyTransforms((0, 0, 0), rz, (0, 0, 0), q)
    assert gripper_yaw(np.array(qq)) == pytest.approx(yaw, abs=1e-6)  # pybullet quaternions: ~1e-7


# ------------------------------------------------------------------------------------------------ stored run


@pytest.fixture(scope="module")
def stored():
    assert REGRESSION.is_file() and REGRESSION.stat().st_size < 200_000
    return isolate_runs([REGRESSION])


def test_stored_run_isolation_error_stays_below_the_measured_figure(stored):
    s = stored.error_summary()
    assert s["n"] >= 35
    assert s["median_m"] < MEDIAN_BOUND_M
    assert s["p90_m"] < P90_BOUND_M


def test_isolated_contacts_pass_the_contacts_schema(stored):
    import pyarrow.parquet as pq

    t = validate_contacts(stored.table, "isolated")
    run = pq.read_table(REGRESSION)
    assert t.num_rows == run.num_rows
    assert t.column("object_id").to_pylist() == run.column("object_id").to_pylist()
    assert t.column("run").to_pylist() == ["FB/0"] * run.num_rows
    inc = t.column("in_contact").to_numpy(zero_copy_only=False)
    assert inc.sum() == stored.n_contact > 0
    # contact points are within a gripper's reach of the end effector
    d = np.hypot(np.asarray(t.column("contact_x_m").to_pylist(), dtype=float)[inc] - t.column("ee_x_m").to_numpy()[inc],
                 np.asarray(t.column("contact_y_m").to_pylist(), dtype=float)[inc] - t.column("ee_y_m").to_numpy()[inc])
    assert np.all(d < 0.13)


def _cli():
    import stucco_cli.sim  # noqa: F401
    from stucco_cli.main import cli

    return cli


def test_cli_isolate_writes_contacts_with_error_metadata_and_reports(tmp_path):
    runs = tmp_path / "runs"
    runs.mkdir()
    shutil.copy(REGRESSION, runs / REGRESSION.name)
    out = tmp_path / "contacts.parquet"
    res = CliRunner().invoke(_cli(), ["isolate", "--in", str(runs), "--out", str(out), "--report"])
    assert res.exit_code == 0, res.output
    assert "median" in res.stdout and "p90" in res.stdout
    read_contacts(out)
    meta = read_metadata(out)
    assert meta["stage"] == "isolate" and meta["schema"] == "contacts"
    err = meta["params"]["isolation_error"]
    assert err["median_m"] < MEDIAN_BOUND_M and err["p90_m"] < P90_BOUND_M
    res = CliRunner().invoke(_cli(), ["isolate", "--in", str(runs), "--out", str(out)])
    assert res.exit_code == 1 and "exists (--out); pass --force-overwrite" in res.stderr


def test_cli_isolate_empty_or_missing_input_is_a_one_line_error(tmp_path):
    res = CliRunner().invoke(_cli(), ["isolate", "--in", str(tmp_path), "--out", str(tmp_path / "c.parquet")])
    assert res.exit_code == 1 and "no *.parquet run files" in res.stderr
    res = CliRunner().invoke(_cli(), ["isolate", "--in", str(tmp_path / "nope"), "--out", str(tmp_path / "c.parquet")])
    assert res.exit_code == 1 and "does not exist" in res.stderr


def test_cli_isolate_rejects_a_file_that_is_not_a_run(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    bad = tmp_path / "x.parquet"
    pq.write_table(pa.table({"run": ["a"], "step": [0]}), bad)
    res = CliRunner().invoke(_cli(), ["isolate", "--in", str(bad), "--out", str(tmp_path / "c.parquet")])
    assert res.exit_code == 1 and "x.parquet: column 'scene': missing" in res.stderr
