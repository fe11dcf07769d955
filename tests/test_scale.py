"""`stucco bench scale`: one evaluation per grid size from scratch, the table, CSV and figure; a folder that would
resume is refused (its time would not be a measurement)."""
import csv

from click.testing import CliRunner

from stucco_cli.main import cli


def test_scale_times_each_grid_from_scratch_and_refuses_to_resume(tmp_path):
    out = tmp_path / "scale"
    args = ["--seed", "0", "-j", "1", "bench", "scale", "--scene", "TC", "--runs", "1,2", "--methods", "stucco",
            "--estimators", "plausible", "--max-actions", "3", "--out", str(out), "--png", str(tmp_path / "s.png")]
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(open(out / "scale.csv")))
    assert [int(x["runs"]) for x in rows] == [1, 2] and [int(x["jobs"]) for x in rows] == [1, 2]
    for x in rows:
        assert float(x["wall_s"]) > 0 and float(x["work_s"]) > 0 and x["backend"] == "loky"
    assert (out / "TC-1" / "report.csv").is_file() and (out / "TC-2" / "report.csv").is_file()
    assert (tmp_path / "s.png").stat().st_size > 0 and "| TC | 2 | 2 |" in r.output
    again = CliRunner().invoke(cli, args)
    assert again.exit_code != 0 and "exists: a resumed evaluation is not a measurement" in again.output
    assert "Traceback" not in again.output


def test_scale_refuses_dask_without_a_scheduler_and_two_tasks(tmp_path):
    base = ["bench", "scale", "--out", str(tmp_path / "o"), "--runs", "1"]
    r = CliRunner().invoke(cli, base + ["--backend", "dask"])
    assert r.exit_code != 0 and "--scheduler" in r.output
    r = CliRunner().invoke(cli, base + ["--scene", "FB,TC"])
    assert r.exit_code != 0 and "expected one task" in r.output
