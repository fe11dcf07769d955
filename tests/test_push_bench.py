"""`stucco bench pushes`: the pushing models and pybullet replays against the recorded pushes
(pipeline/studies/pushes.py)."""
import csv
import math

import numpy as np
import pytest
from click.testing import CliRunner

from pipeline.collect import collect_file
from pipeline.estimators.pushtrack.params import MOTIONS
from pipeline.estimators.run_info import load_run
from pipeline.layout import partition
from pipeline.scenes import load_scene
from pipeline.studies.pushes import MIN_PUSH, push_cases, push_rows, summarise, summary_markdown
from stucco_cli.main import cli


@pytest.fixture(scope="module")
def evaluation(tmp_path_factory):
    """An evaluation directory with one short FB run (its first 13 scripted actions push the box)."""
    root = tmp_path_factory.mktemp("pushes")
    path = partition(root, "runs", "FB", 0)
    path.parent.mkdir(parents=True, exist_ok=True)
    collect_file(load_scene("FB"), 0, path, max_actions=13)
    return root


def test_the_cases_are_the_targets_pushes(evaluation):
    path = partition(evaluation, "runs", "FB", 0)
    info = load_run(path)
    cases = push_cases(path, info.target_id)
    assert len(cases) >= 2
    for c in cases:
        assert math.hypot(*c.push) >= MIN_PUSH
        assert c.before.shape == c.after.shape == (len(info.scene.body_names), 3)
        assert np.all(np.isfinite(c.contact)) and np.all(np.isfinite(c.command))


def test_the_replay_reproduces_the_recording_and_static_moves_nothing(evaluation):
    rows = push_rows(evaluation, [("FB", 0)], replay=True)
    assert rows and {r["scene"] for r in rows} == {"FB"}
    for r in rows:
        # "static" leaves the pose: its yaw error is the true turn itself
        assert r["static_yaw_error_rad"] == pytest.approx(abs(r["true_turn_rad"]), abs=1e-12)
        assert r["static_turn_rad"] == 0.0
        for m in MOTIONS:
            assert math.isfinite(r[f"{m}_yaw_error_rad"]) and math.isfinite(r[f"{m}_position_error_m"])
    # pybullet from the recorded poses moves the box the recorded way (not to the bit: the state's velocities and
    # contact caches are not recorded, and a push through the clutter can go another way), far closer than not
    # moving it at all
    for replay in ("replay_scene", "replay_alone"):
        err = [r[f"{replay}_position_error_m"] for r in rows]
        assert np.all(np.isfinite(err))
        assert np.median(err) < 0.5 * np.median([r["static_position_error_m"] for r in rows])
    summary = summarise(rows)
    assert [s["model"] for s in summary] == list(MOTIONS) + ["replay_scene", "replay_alone"]
    assert all(s["pushes"] == len(rows) for s in summary)
    assert summary_markdown(summary).count("\n") == len(summary) + 2


def test_bench_pushes_cli_writes_its_tables_and_figure(evaluation, tmp_path):
    out = tmp_path / "bench"
    res = CliRunner().invoke(cli, ["-q", "bench", "pushes", "--runs-from", str(evaluation), "--scenes", "FB",
                                   "--seeds", "0", "--no-replay", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "| FB | sweep |" in res.output and "replay" not in res.output.split("->")[0]
    rows = list(csv.DictReader(open(out / "pushes.csv")))
    assert rows and {"step", "true_turn_rad", "sweep_yaw_error_rad"} <= set(rows[0])
    assert (out / "pushes_summary.csv").is_file() and (out / "pushes.png").stat().st_size > 0


def test_bench_pushes_refuses_a_directory_without_runs(tmp_path):
    res = CliRunner().invoke(cli, ["bench", "pushes", "--runs-from", str(tmp_path), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "--runs-from" in res.output and "not an evaluation directory" in res.output
    (tmp_path / "runs").mkdir()
    res = CliRunner().invoke(cli, ["bench", "pushes", "--runs-from", str(tmp_path), "--scenes", "FB", "--seeds", "3",
                                   "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "no collected run for FB seed 3" in res.output
