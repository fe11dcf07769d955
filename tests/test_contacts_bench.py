"""`stucco bench contacts`: the K-contact streams it builds, and the command end to end (figures in docs, never
asserted here)."""
from __future__ import annotations

import json

import numpy as np
from click.testing import CliRunner

from pipeline.studies.anchors import load_contacts_stream
from pipeline.studies.multi_contact import ANGLE_RAD, with_contacts_per_step
from stucco_cli.main import cli


def test_added_contacts_lie_on_the_robot_as_far_from_its_centre_and_move_alike():
    stream = load_contacts_stream(50)
    c = stream["in_contact"].astype(bool)
    p, dx = with_contacts_per_step(stream, 3)
    assert p.shape == (len(c), 3, 2) and dx.shape == (len(c), 3, 2)
    np.testing.assert_array_equal(p[c, 0], stream["p"][c])  # the stream's own contact first
    r = np.linalg.norm(p[c] - stream["x"][c][:, None, :], axis=2)
    np.testing.assert_allclose(r, r[:, :1].repeat(3, axis=1), atol=1e-12)
    a = [np.arctan2(*(p[c, j] - stream["x"][c])[:, ::-1].T) - np.arctan2(*(p[c, 0] - stream["x"][c])[:, ::-1].T)
         for j in (1, 2)]
    np.testing.assert_allclose(np.angle(np.exp(1j * a[0])), ANGLE_RAD, atol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * a[1])), -ANGLE_RAD, atol=1e-9)
    np.testing.assert_array_equal(dx[c, 1], dx[c, 0])


def test_bench_contacts_runs_end_to_end_and_writes_its_figures(tmp_path):
    out = tmp_path / "contacts.json"
    res = CliRunner().invoke(cli, ["bench", "contacts", "--T", "50", "--K", "1,2", "--N", "16", "--repeats", "1",
                                   "--methods", "stucco,dbscan", "--json", str(out)])
    assert res.exit_code == 0, res.output
    rows = json.loads(out.read_text())
    assert [(r["method"], r["K"], r["points"]) for r in rows] == [("stucco", 1, 50), ("stucco", 2, 100),
                                                                  ("dbscan", 1, 50), ("dbscan", 2, 100)]
    assert all(r["cpu_s"] >= 0 and np.isfinite(r["ratio_same_steps"]) for r in rows)
    assert rows[1]["ratio_same_points"] is not None  # the T=100 stream exists


def test_bench_contacts_refuses_a_bad_count_in_one_line():
    res = CliRunner().invoke(cli, ["bench", "contacts", "--K", "0"])
    assert res.exit_code == 2 and "--K" in res.output and "Traceback" not in res.output
