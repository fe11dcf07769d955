"""`stucco bench grasp-sensitivity`: every scripted grasp simulated again, unshifted and shifted; the CLI's errors."""
from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from pipeline.estimators.run_info import load_run
from pipeline.grasp import grasp_at
from pipeline.retrieve import retrieval_table
from pipeline.schema import SchemaError, write_table
from pipeline.studies.grasp_sensitivity import scripted_grasps, sensitivity_rows, summarise, write_outputs
from stucco_cli.main import cli

REGRESSION = Path(__file__).resolve().parents[1] / "data" / "regression"


@pytest.fixture(scope="module")
def evaluation(tmp_path_factory) -> Path:
    """An evaluation directory of one run (FB-000): two scripted grasps (at the true pose, and 2 cm off along x)
    with the verdicts the simulation gives, and one active-protocol row, which the bench leaves out."""
    out = tmp_path_factory.mktemp("evaluation")
    (out / "runs").mkdir()
    (out / "retrieval").mkdir()
    shutil.copy(REGRESSION / "FB-000.parquet", out / "runs" / "FB-000.parquet")
    info = load_run(out / "runs" / "FB-000.parquet")
    rows = []
    for estimator, shift in (("plausible", 0.0), ("paper", 0.02)):
        pose = np.asarray(info.true_pose, dtype=np.float64) + [shift, 0.0, 0.0]
        g = grasp_at(info.scene, info.final_poses, info.final_ee, pose, tilted=info.final_tilted)
        rows.append(dict(run="FB/0", scene="FB", seed=0, method="stucco", estimator=estimator, target="cracker_box",
                         x_m=float(pose[0]), y_m=float(pose[1]), yaw_rad=float(pose[2]), segment=0, n_points=3,
                         n_segments=1, position_var_m2=None, icp_rmse_m=None, penetration_m=0.0, low_confidence=False,
                         notes="", true_x_m=None, true_y_m=None, true_yaw_rad=None, position_error_m=None,
                         yaw_error_rad=None, grasp_success=bool(g.success), grasp_outcome=g.outcome,
                         grasp_attempts=None, grasp_success_any=None, icp_s=0.0, grasp_s=None))
    rows.append(dict(rows[0], estimator="pushtrack", grasp_attempts=2))  # the active protocol's planned grasp
    for r in rows:
        write_table(retrieval_table([r]), out / "retrieval" / f"FB-000-stucco-{r['estimator']}.parquet",
                    stage="retrieve", params={}, seed=0, kind="retrieval")
    return out


def test_only_scripted_grasps_are_taken(evaluation):
    rows = scripted_grasps(evaluation)
    assert sorted(r["estimator"] for r in rows) == ["paper", "plausible"]


def test_every_grasp_is_simulated_unshifted_and_with_each_shift(evaluation, tmp_path):
    rows = sensitivity_rows(evaluation, [1e-6])
    assert len(rows) == 2 * 3  # two grasps: unshifted, the estimate moved, the target moved
    assert {(r.perturbed, r.shift_m) for r in rows} == {("none", 0.0), ("estimate", 1e-6), ("target", 1e-6)}
    summary = {s["perturbed"]: s for s in summarise(rows)}
    # the simulation is deterministic: unshifted, it gives the evaluation's verdicts
    assert summary["none"]["differ"] == 0 and summary["none"]["agreement_pct"] == 100.0
    for r in rows:
        base = next(b for b in rows if b.estimator == r.estimator and b.perturbed == "none")
        assert r.flipped == (r.success != base.success)
    csv_path, md_path = write_outputs(rows, tmp_path / "out")
    with open(csv_path, newline="") as f:
        assert len(list(csv.DictReader(f))) == len(rows)
    assert "agreement %" in md_path.read_text()


def test_bad_shifts_and_missing_runs_are_refused(evaluation, tmp_path):
    with pytest.raises(ValueError, match="positive"):
        sensitivity_rows(evaluation, [0.0])
    empty = tmp_path / "empty"
    (empty / "retrieval").mkdir(parents=True)
    with pytest.raises(ValueError, match="no scripted grasp"):
        sensitivity_rows(empty, [1e-6])
    odd = tmp_path / "odd"
    (odd / "retrieval").mkdir(parents=True)
    pq.write_table(pa.table({"scene": ["FB"], "seed": [0]}), odd / "retrieval" / "FB-000-stucco-plausible.parquet")
    with pytest.raises(SchemaError, match="FB-000-stucco-plausible.parquet: column 'run': missing"):
        sensitivity_rows(odd, [1e-6])
    orphan = tmp_path / "orphan"
    shutil.copytree(evaluation / "retrieval", orphan / "retrieval")
    with pytest.raises(ValueError, match="no run file for FB seed 0"):
        sensitivity_rows(orphan, [1e-6])


def test_cli_errors_are_one_line(evaluation, tmp_path):
    runner = CliRunner()
    r = runner.invoke(cli, ["bench", "grasp-sensitivity", "--runs-from", str(tmp_path), "--out", str(tmp_path / "o")])
    assert r.exit_code != 0 and "not an evaluation directory" in r.output and "Traceback" not in r.output
    r = runner.invoke(cli, ["bench", "grasp-sensitivity", "--runs-from", str(evaluation), "--shifts-um", "-1",
                            "--out", str(tmp_path / "o")])
    assert r.exit_code != 0 and "--shifts-um" in r.output and "Traceback" not in r.output
