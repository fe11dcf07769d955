"""A policy's side files (what a run keeps out of its Parquet file): declared on its PolicySpec, named ``_<run>
<suffix>`` so Parquet readers of the runs folder skip them, copied with a stored run by ``evaluate --from-runs``,
and read back under the name they had before layout 3."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from pipeline import registry
from pipeline.evaluate import EvalConfig, Job, job_paths
from pipeline.evaluate.stages import run_collect
from pipeline.probe.report import PROBE_POLICY, run_stats, save_times, times_path

REG = Path(__file__).resolve().parents[1] / "data" / "regression"


def test_the_probing_policy_declares_its_times_file():
    spec = registry.policy(PROBE_POLICY)
    assert spec.side_files == (".probe_s.json",)
    run = Path("out/runs/FB-003.parquet")
    assert spec.side_paths(run) == (Path("out/runs/_FB-003.probe_s.json"),) == (times_path(run),)
    assert registry.policy("scripted").side_paths(run) == ()


@pytest.mark.parametrize("suffix", ["probe.json", ".x.parquet", "./x.json", ".a/b.json"])
def test_a_side_file_that_could_pass_for_a_partition_or_leave_the_folder_is_refused(suffix):
    spec = registry.PolicySpec("side-toy", "toy", "pipeline.policies:ScriptedPolicy", side_files=(suffix,))
    with pytest.raises(ValueError, match="side file suffix"):
        registry.register(spec)
    assert "side-toy" not in registry.policy_names()


def test_times_written_under_the_new_name_and_read_under_the_old_one(tmp_path):
    path = tmp_path / "FB-000.parquet"
    path.write_bytes((REG / "FB-000.parquet").read_bytes())
    legacy = tmp_path / "FB-000.probe_s.json"  # layout 2's name
    legacy.write_text(json.dumps({"decision_s": [0.2], "prior_s": 0.1}))
    assert run_stats(path)["decision_s"] == [0.2]
    save_times(path, {"decision_s": [0.3], "prior_s": 0.45})
    assert (tmp_path / "_FB-000.probe_s.json").is_file()
    assert run_stats(path)["decision_s"] == [0.3]  # the new name first


def test_a_stored_run_is_copied_with_its_side_files_and_no_wall_time(tmp_path):
    source = tmp_path / "stored"
    source.mkdir()
    (source / "FB-000.parquet").write_bytes((REG / "FB-000.parquet").read_bytes())
    times_path(source / "FB-000.parquet").write_text('{"decision_s": [0.5], "prior_s": 0.25}')
    paths = job_paths(tmp_path / "ev", Job("FB", 0, "stucco"))
    assert run_collect(paths, EvalConfig(source=str(source))) is None
    assert paths["runs"].read_bytes() == (source / "FB-000.parquet").read_bytes()
    assert times_path(paths["runs"]).read_text() == '{"decision_s": [0.5], "prior_s": 0.25}'


def test_stucco_collect_writes_the_policys_side_file_and_never_leaves_a_stale_one(tmp_path):
    # `stucco collect --policy scripted+probe` writes the run's times beside it, as evaluate does; a run collected
    # again over it with another policy (--force-overwrite) takes the old run's side file away with it
    from click.testing import CliRunner

    from stucco_cli.main import cli

    def collect(*extra):
        r = CliRunner().invoke(cli, ["-q", "collect", "--scene", "TC", "--seeds", "104", "--max-actions", "20",
                                     "--out", str(tmp_path), *extra])
        assert r.exit_code == 0, r.output

    run = tmp_path / "TC-104.parquet"
    collect("--policy", "scripted+probe", "--policy-param", "budget=1")
    times = json.loads(times_path(run).read_text())
    assert set(times) == {"decision_s", "prior_s"} and times["decision_s"]
    collect("--force-overwrite")  # the scene's own policy, scripted: no side file of its own
    assert run.is_file() and not times_path(run).exists()
    assert run_stats(run)["decision_s"] == []


def test_remove_side_files_removes_every_policys_and_keeps_the_run(tmp_path):
    run = tmp_path / "TC-000.parquet"
    run.write_bytes(b"run")
    sides = [registry.side_path(run, s) for s in registry.side_suffixes()]
    assert sides  # the probing policies declare one
    for side in sides:
        side.write_text("{}")
    registry.remove_side_files(run)
    registry.remove_side_files(run)  # none left: nothing to do, no error
    assert run.read_bytes() == b"run" and not any(side.exists() for side in sides)
