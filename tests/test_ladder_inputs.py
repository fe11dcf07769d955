"""`stucco bench retrieval` checks that the segments it reads belong to the run they are filed under, as
`retrieve` and `score` do (docs/retrieval.md, "Where grasps are lost")."""
from __future__ import annotations

import shutil
from pathlib import Path

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
