"""`stucco bench scale`: one evaluation per grid size from scratch, the table, CSV and figure; a folder that would
resume is refused (its time would not be a measurement)."""
import csv

import numpy as np
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


# ------------------------------------------------------------------------------------------------ the contacts axis
def _in_contact(path):
    import pyarrow.parquet as pq

    return sum(pq.read_table(path, columns=["in_contact"]).column(0).to_pylist())


def test_rummage_stops_at_the_requested_contacts_past_the_script_and_gives_the_same_bytes_twice(tmp_path):
    """TC's 40 scripted actions end fewer than 15 in contact, so 15 needs a second play of the script, from the
    scene's starting state again."""
    import pyarrow.parquet as pq

    from pipeline.collect import collect_file
    from pipeline.scenes import load_scene
    from pipeline.schema import read_metadata

    sc = load_scene("TC")
    a, b = tmp_path / "a.parquet", tmp_path / "b.parquet"
    for path in (a, b):
        res = collect_file(sc, 3, path, policy="rummage", policy_params={"contacts": 15})
    assert a.read_bytes() == b.read_bytes()
    assert _in_contact(a) == 15 == res.n_contact and res.n_actions > len(sc.actions)
    params = read_metadata(a)["params"]
    assert params["policy"] == "rummage" and params["policy_params"]["contacts"] == 15
    # every action is the script's (plus replay noise of at most 0.5 mm on a 30 mm scale), the noise drawn anew
    t = pq.read_table(a).to_pandas()
    n = len(sc.actions)
    cmd, script = t[["cmd_ux", "cmd_uy"]].to_numpy(), np.array(sc.actions, dtype=float)
    assert abs(cmd - script[np.arange(len(t)) % n]).max() < 0.5 / 30 + 1e-12
    assert not np.array_equal(cmd[:len(t) - n], cmd[n:])
    # the second play starts where the first did
    start = t[["ee_start_x_m", "ee_start_y_m"]].to_numpy()
    assert np.allclose(start[n], start[0], atol=1e-9) and not np.allclose(start[n - 1], start[0], atol=1e-3)


def test_rummage_is_capped_by_max_actions_and_checks_its_parameters(tmp_path):
    import pytest

    from pipeline.collect import collect_run
    from pipeline.policies import RummageParams
    from pipeline.scenes import load_scene

    _, params, res = collect_run(load_scene("TC"), 0, policy="rummage", max_actions=4,
                                 policy_params={"contacts": 1000})
    assert res.n_actions == 4 and res.n_contact < 1000 and params["max_actions"] == 4
    for bad in ({"contacts": 0}, {"contacts": 2.5}, {"contacts": 2_000_000}, {"actions_per_contact": 0}):
        with pytest.raises(ValueError, match="RummageParams"):
            RummageParams(**bad)


def test_scale_contacts_times_every_stage_per_run_and_keeps_the_warm_up_apart(tmp_path):
    out = tmp_path / "c"
    args = ["--seed", "0", "bench", "scale", "--scene", "TC", "--contacts", "2,4", "--estimators", "plausible",
            "--out", str(out), "--png", str(tmp_path / "c.png")]
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(open(out / "scale_contacts.csv")))
    stages = ["collect", "isolate", "track", "segment", "retrieve", "score"]
    for asked, warm in (("5", "True"), ("2", "False"), ("4", "False")):
        sel = [x for x in rows if x["requested"] == asked]
        assert [x["stage"] for x in sel] == stages and {x["warmup"] for x in sel} == {warm}
        assert {int(x["contacts"]) for x in sel} == {int(asked)}  # every contact of TC's first actions is isolated
        assert all(float(x["wall_s"]) >= 0 and float(x["cpu_s"]) >= 0 for x in sel)
    assert [x["estimator"] for x in rows[:6]] == ["", "", "", "", "plausible", "plausible"]
    assert (out / "TC-c4" / "scores").is_dir() and (tmp_path / "c.png").stat().st_size > 0
    assert "growth, CPU s ~ contacts^b: collect b=" in r.output and "| TC | 4 (4) |" in r.output
    again = CliRunner().invoke(cli, args)
    assert again.exit_code != 0 and "exists: a rerun stage is not a measurement" in again.output


def test_scale_contacts_refuses_bad_sizes_and_a_second_axis_in_one_line(tmp_path):
    out = tmp_path / "o"
    base = ["bench", "scale", "--out", str(out), "--estimators", "plausible"]
    for extra, says in ((["--contacts", "0"], "0 is not in [1, 100000]"),
                        (["--contacts", "many"], "expected comma-separated integers, got 'many'"),
                        (["--contacts", ","], "--contacts"),
                        (["--contacts", "5", "--runs", "3"], "--runs does not apply to the contacts axis"),
                        (["--contacts", "5", "--max-actions", "3"], "--max-actions does not apply"),
                        (["--contacts", "5", "--methods", "stucco,birch"], "expected one method")):
        r = CliRunner().invoke(cli, base + extra)
        assert r.exit_code != 0 and says in r.output, (extra, r.output)
        assert "Traceback" not in r.output and len(r.output.strip().splitlines()[-1]) > 0
    assert not (out / "scale_contacts.csv").exists()
