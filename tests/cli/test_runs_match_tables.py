"""Run files are checked against the tables made from them (issue 17, bad-input probe): retrieve and score refuse,
in one line naming the run file, a run of another root seed, a truncated run, or another run filed under this
run's name, instead of scoring the wrong truth; ``--estimators paper,paper`` is refused."""
from __future__ import annotations

import shutil
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from pipeline.evaluate import EvalConfig
from stucco_cli.main import cli
from tests.cli.test_run_scene import _moved_fb, collect_file

N_ACTIONS = 12


def _ok(*args):
    r = CliRunner().invoke(cli, ["-q", *[str(a) for a in args]])
    assert r.exit_code == 0, r.output
    return r


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """FB/0 (12 actions) collected, isolated, tracked and segmented side by side, plus three impostors of its run
    file: the same run collected with root seed 1, the run cut to 8 actions, and FB/0 of another scene file named
    FB (its box moved)."""
    tmp = tmp_path_factory.mktemp("made")
    _ok("collect", "--scene", "FB", "--seeds", 0, "--max-actions", N_ACTIONS, "--out", tmp / "runs")
    _ok("isolate", "--in", tmp / "runs", "--out", tmp / "contacts.parquet")
    _ok("track", "--in", tmp / "contacts.parquet", "--out", tmp / "tracks.parquet", "--robot", "disc:0.05",
        "--every-step")
    _ok("segment", "--in", tmp / "tracks.parquet", "--out", tmp / "segments.parquet")
    _ok("retrieve", "--segments", tmp / "segments.parquet", "--runs", tmp / "runs", "--out",
        tmp / "retrieval.parquet", "--no-grasp", "--estimator", "paper", "--restarts", 2)
    _ok("--seed", 1, "collect", "--scene", "FB", "--seeds", 0, "--max-actions", N_ACTIONS, "--out", tmp / "seed1")
    collect_file(_moved_fb(tmp / "my" / "FB.toml"), tmp / "moved", N_ACTIONS)  # `stucco collect` refuses it
    run = pq.read_table(tmp / "runs" / "FB-000.parquet")
    (tmp / "cut").mkdir()
    pq.write_table(run.slice(0, 8), tmp / "cut" / "FB-000.parquet")
    return tmp


def _runs_with(tmp: Path, impostor: str) -> Path:
    runs = tmp / "runs"
    runs.mkdir()
    shutil.copyfile(impostor, runs / "FB-000.parquet")
    return runs


#: impostor folder -> what the one-line refusal says (segments recording the runs they derive from, as every
#: stage writes them now, and segments without that record, as older files: only the run's content can tell).
CASES = {"seed1": ("root seed 1", "root seed 1"), "cut": ("SHA-256", "ends at step 7"),
         "moved": ("SHA-256", None)}


def _without_runs_record(src: Path, dst: Path) -> Path:
    t = pq.read_table(src)
    meta = {k: v for k, v in t.schema.metadata.items() if k != b"stucco.runs"}
    pq.write_table(t.replace_schema_metadata(meta), dst)
    return dst


def test_every_stage_carries_the_runs_it_derives_from(made):
    from pipeline.schema import file_digest, read_metadata

    digest = {"FB/0": file_digest(made / "runs" / "FB-000.parquet")}
    for name in ("contacts", "tracks", "tracks.diagnostics", "segments", "retrieval"):
        assert read_metadata(made / f"{name}.parquet")["runs"] == digest, name


@pytest.mark.parametrize("chain", ["recorded", "not recorded"])
@pytest.mark.parametrize("impostor", list(CASES))
@pytest.mark.parametrize("command", ["retrieve", "score"])
def test_a_run_file_that_is_not_the_tables_run_is_refused(made, tmp_path, impostor, chain, command):
    expect = CASES[impostor][0 if chain == "recorded" else 1]
    if expect is None:
        pytest.skip("same steps, a moved box: only the recorded digest tells the runs apart")
    if command == "score" and chain == "not recorded":
        pytest.skip("the retrieval recorded the segments' digest: an edited copy is refused as such")
    runs = _runs_with(tmp_path, made / impostor / "FB-000.parquet")
    if chain == "recorded":
        segments = tmp_path / "segments.parquet"
        shutil.copyfile(made / "segments.parquet", segments)  # away from its tracks and contacts: it suffices
    else:
        segments = _without_runs_record(made / "segments.parquet", tmp_path / "segments.parquet")
    out = tmp_path / "out.parquet"
    if command == "retrieve":
        args = ["retrieve", "--segments", segments, "--runs", runs, "--out", out, "--no-grasp", "--estimator",
                "paper", "--restarts", 2]
    else:
        args = ["score", "--retrieval", made / "retrieval.parquet", "--segments", segments, "--runs", runs,
                "--out", out, "--diagnostics", made / "tracks.diagnostics.parquet"]
    r = CliRunner().invoke(cli, ["-q", *[str(a) for a in args]])
    assert r.exit_code == 1 and isinstance(r.exception, SystemExit), r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and "FB-000.parquet" in lines[0] and expect in lines[0], r.output
    assert not out.exists()


def test_the_tables_own_run_passes(made, tmp_path):
    _ok("score", "--retrieval", made / "retrieval.parquet", "--segments", made / "segments.parquet",
        "--runs", made / "runs", "--out", tmp_path / "scores.parquet")
    assert (tmp_path / "scores.parquet").is_file()


@pytest.mark.parametrize("command", ["evaluate", "bench retrieval"])
def test_an_estimator_given_twice_is_refused(tmp_path, command):
    args = (["evaluate", "--scenes", "FB", "--seeds", "0", "--out", str(tmp_path / "ev")] if command == "evaluate"
            else ["bench", "retrieval", "--runs-from", str(tmp_path), "--out", str(tmp_path / "b")])
    (tmp_path / "runs").mkdir()
    r = CliRunner().invoke(cli, ["-q", *args, "--estimators", "paper,paper"])
    assert r.exit_code == 2 and "'paper' is given twice" in r.output, r.output
    with pytest.raises(ValueError, match="each may be given once"):
        EvalConfig(estimators=("paper", "paper"))
