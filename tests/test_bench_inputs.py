"""The benches check that their inputs belong together: `stucco bench retrieval`'s segments are of the run they
are filed under, as `retrieve` and `score` check (docs/retrieval.md, "Where grasps are lost"); `stucco bench probe`
reads only runs of the probing policy collected with its root seed (docs/active.md)."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from pipeline.layout import partition
from stucco_cli.main import cli

REGRESSION = Path(__file__).resolve().parents[1] / "data" / "regression"


def _ok(*args):
    r = CliRunner().invoke(cli, ["-q", "--seed", "0", *map(str, args)])
    assert r.exit_code == 0, r.output


def test_segments_of_another_run_are_refused_in_one_line(tmp_path):
    # an evaluation folder whose FB seed 0 segments were made from TC seed 0's run
    work = tmp_path / "work"
    work.mkdir()
    shutil.copy(REGRESSION / "TC-000.parquet", work / "TC-000.parquet")
    _ok("isolate", "--in", work, "--out", work / "c.parquet")
    _ok("track", "--in", work / "c.parquet", "--out", work / "t.parquet")
    _ok("segment", "--in", work / "t.parquet", "--out", work / "s.parquet")
    ev = tmp_path / "ev"
    run = partition(ev, "runs", "FB", 0)
    seg = partition(ev, "segments", "FB", 0, "stucco")
    run.parent.mkdir(parents=True)
    seg.parent.mkdir(parents=True)
    shutil.copy(REGRESSION / "FB-000.parquet", run)
    shutil.copy(work / "s.parquet", seg)
    r = CliRunner().invoke(cli, ["-q", "--seed", "0", "bench", "retrieval", "--runs-from", str(ev), "--scenes", "FB",
                                 "--seeds", "0", "--estimators", "plausible", "--out", str(tmp_path / "out")])
    assert r.exit_code != 0 and "Traceback" not in r.output
    last = [line for line in r.output.splitlines() if line.strip()][-1]
    assert "holds segments of run 'TC/0', not only of 'FB/0'" in last and str(seg) in last


def test_bench_probe_refuses_a_run_of_another_policy_or_root_seed(tmp_path):
    runs = tmp_path / "runs"
    runs.mkdir()
    shutil.copy(REGRESSION / "FB-000.parquet", runs / "FB-000.parquet")  # the paper's protocol, not the probing one
    args = ["bench", "probe", "--scenes", "FB", "--seeds", "0", "--runs", str(runs), "--budgets", "0",
            "--out", str(tmp_path / "out")]
    r = CliRunner().invoke(cli, ["-q", "--seed", "0", *args])
    assert r.exit_code != 0 and "Traceback" not in r.output
    assert "not of scripted+probe" in r.output.splitlines()[-1]


@pytest.mark.parametrize("root_seed, refusal", [
    ("1", "collected with root seed 1"),
    # a run cut short (or of an edited scene, other effects or policy parameters) is not the run the bench stands
    # for: it was reported as the scene's before
    ("0", "TC-000.parquet: collected with max_actions 20, not None"),
])
def test_bench_probe_refuses_a_stored_run_it_would_not_have_collected(tmp_path, root_seed, refusal):
    runs = tmp_path / "runs"
    _ok("--seed", root_seed, "collect", "--scene", "TC", "--seeds", "0", "--policy", "scripted+probe", "--max-actions",
        "20", "--out", runs)
    r = CliRunner().invoke(cli, ["-q", "--seed", "0", "bench", "probe", "--scenes", "TC", "--seeds", "0", "--runs",
                                 str(runs), "--budgets", "0", "--out", str(tmp_path / "out")])
    assert r.exit_code != 0 and "Traceback" not in r.output
    assert refusal in r.output.splitlines()[-1]
