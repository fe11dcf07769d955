"""Outputs never destroy inputs, whichever input (issue 17, bad-input probe): every input of a command is protected,
folders included (the run files of ``--runs DIR``), also through symbolic links; a symbolic link loop in an output
path is one line, not a traceback; the evaluation folder's lock is never opened through a link.
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from stucco_cli.main import cli
from tests.cli.test_bad_runs import RUN, _stucco_segments

ANCHORS = Path(__file__).resolve().parents[2] / "data" / "anchors"


def _refused(r, *words: str) -> str:
    assert r.exit_code not in (0, None) and isinstance(r.exception, SystemExit), r.output
    assert "Traceback" not in r.output
    # one error line (a usage error is preceded by click's two usage lines)
    lines = [ln for ln in r.output.strip().splitlines() if ln.strip() and not ln.startswith(("Usage:", "Try "))]
    assert len(lines) == 1 and lines[0].startswith("Error:"), r.output
    for w in words:
        assert w in lines[0], r.output
    return lines[0]


@pytest.fixture
def stage(tmp_path):
    """A runs folder with FB-000, the STUCCO segments of FB/0, and a retrieval table stand-in."""
    runs = tmp_path / "runs"
    runs.mkdir()
    shutil.copyfile(RUN, runs / "FB-000.parquet")
    segments = _stucco_segments(tmp_path / "segments.parquet")
    retrieval = tmp_path / "retrieval.parquet"
    retrieval.write_bytes(b"not read: the paths are refused first")
    return tmp_path, runs, segments, retrieval


def _snapshot(root: Path) -> dict[Path, bytes]:
    return {p: p.read_bytes() for p in root.rglob("*") if p.is_file() and not p.is_symlink()}


@pytest.mark.parametrize("case", ["retrieve --out = a run of the --runs folder",
                                  "retrieve --candidates = a run of the --runs folder",
                                  "retrieve --out = the --runs file",
                                  "retrieve --out = a link to a run of the --runs folder",
                                  "score --out = a run of the --runs folder",
                                  "score --out = the --runs file",
                                  "isolate --out = a run of the --in folder"])
def test_no_output_may_be_any_input(stage, case):
    tmp, runs, segments, retrieval = stage
    run = runs / "FB-000.parquet"
    target = run
    if "a link to" in case:
        target = tmp / "link.parquet"
        target.symlink_to(run)
    given_runs = run if "--runs file" in case else runs
    command, option = case.split(" = ")[0].split()
    if command == "retrieve":
        args = ["retrieve", "--segments", str(segments), "--runs", str(given_runs), "--no-grasp"]
        args += ["--out", str(target)] if option == "--out" else ["--out", str(tmp / "r.parquet"),
                                                                 "--candidates", str(target)]
    elif command == "score":
        args = ["score", "--retrieval", str(retrieval), "--segments", str(segments), "--runs", str(given_runs),
                "--out", str(target)]
    else:
        args = ["isolate", "--in", str(runs), "--out", str(target), "--force-overwrite"]
    before = _snapshot(tmp)
    r = CliRunner().invoke(cli, ["-q", *args])
    _refused(r, option, "never overwrites its own input")
    assert _snapshot(tmp) == before


def test_bench_track_json_may_not_be_a_stream_file(tmp_path):
    streams = tmp_path / "streams"
    streams.mkdir()
    shutil.copyfile(ANCHORS / "stream_T50.npz", streams / "stream_T50.npz")
    before = _snapshot(tmp_path)
    r = CliRunner().invoke(cli, ["bench", "track", "--streams", str(streams), "--T", "50", "--N", "10",
                                 "--json", str(streams / "stream_T50.npz")])
    _refused(r, "--json", "stream_T50.npz", "never overwrites its own input")
    assert _snapshot(tmp_path) == before


@pytest.fixture
def loop(tmp_path) -> Path:
    a, b = tmp_path / "loopA", tmp_path / "loopB"
    a.symlink_to(b)
    b.symlink_to(a)
    return a


@pytest.mark.parametrize("inside", [False, True], ids=["the link", "under the link"])
@pytest.mark.parametrize("command", ["track --out", "segment --plot", "retrieve --candidates", "score --out",
                                     "collect --out", "evaluate --out", "evaluate --snapshot", "bench track --json",
                                     "isolate --out"])
def test_a_symbolic_link_loop_in_an_output_is_one_line(stage, loop, command, inside):
    tmp, runs, segments, retrieval = stage
    out = str(loop / "x.parquet" if inside else loop)
    args = {
        "track --out": ["track", "--in", str(tmp / "contacts.parquet"), "--out", out],
        "segment --plot": ["segment", "--in", str(tmp / "tracks.parquet"), "--out", str(tmp / "s.parquet"),
                           "--plot", out],
        "retrieve --candidates": ["retrieve", "--segments", str(segments), "--runs", str(runs), "--out",
                                  str(tmp / "r.parquet"), "--candidates", out],
        "score --out": ["score", "--retrieval", str(retrieval), "--segments", str(segments), "--runs", str(runs),
                        "--out", out],
        "collect --out": ["collect", "--scene", "FB", "--out", out],
        "evaluate --out": ["evaluate", "--scenes", "FB", "--seeds", "0", "--out", out],
        "evaluate --snapshot": ["evaluate", "--scenes", "FB", "--seeds", "0", "--out", str(tmp / "ev"),
                                "--snapshot", out],
        "bench track --json": ["bench", "track", "--T", "50", "--N", "10", "--json", out],
        "isolate --out": ["isolate", "--in", str(runs), "--out", out],
    }[command]
    before = _snapshot(tmp)
    r = CliRunner().invoke(cli, ["-q", *args])
    _refused(r, command.split()[-1], "symbolic link")
    assert _snapshot(tmp) == before and loop.is_symlink()


@pytest.mark.parametrize("kind", ["link to a file", "dangling link", "fifo"])
def test_evaluate_never_opens_its_lock_through_a_link(tmp_path, kind):
    out = tmp_path / "ev"
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    lock = out / ".evaluate.lock"
    if kind == "fifo":
        os.mkfifo(lock)
    else:
        lock.symlink_to(victim if kind == "link to a file" else tmp_path / "nowhere")
    r = CliRunner().invoke(cli, ["-q", "evaluate", "--scenes", "FB", "--seeds", "0", "--methods", "stucco",
                                 "--out", str(out), "--no-figures", "--max-actions", "2"])
    _refused(r, ".evaluate.lock", "symbolic link" if "link" in kind else "not a regular file")
    assert victim.read_text() == "precious\n" and not (tmp_path / "nowhere").exists()
    assert sorted(p.name for p in out.iterdir()) == [".evaluate.lock"]


@pytest.mark.parametrize("command", ["retrieve", "evaluate --from-runs"])
def test_a_fifo_among_the_run_files_is_refused_not_waited_on(stage, command):
    tmp, runs, segments, retrieval = stage
    fifo = runs / "FB-001.parquet"
    os.mkfifo(fifo)
    if command == "retrieve":
        args = ["retrieve", "--segments", str(segments), "--runs", str(runs), "--out", str(tmp / "r.parquet"),
                "--no-grasp"]
    else:
        args = ["evaluate", "--from-runs", str(runs), "--methods", "stucco", "--out", str(tmp / "ev"),
                "--no-figures"]
    r = CliRunner().invoke(cli, ["-q", *args])
    _refused(r, str(fifo), "not a regular file")
    assert not (tmp / "r.parquet").exists() and not (tmp / "ev").exists()
