"""Safe writes (pipeline.atomic): all or nothing, no shared temporary names, one writer per folder."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from pipeline.atomic import FolderBusy, atomic_path, exclusive, save_figure, write_text


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "report.md"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half of the new")
            raise RuntimeError("interrupted")
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.md"]


def test_temporary_names_are_unique_hidden_and_end_in_tmp(tmp_path):
    names = []
    for _ in range(2):
        with atomic_path(tmp_path / "a.parquet") as tmp:
            names.append(tmp.name)
            tmp.write_bytes(b"x")
    assert names[0] != names[1]
    assert all(n.startswith(".a.parquet.") and n.endswith(".tmp") for n in names)


def test_write_text_and_save_figure(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    assert write_text(tmp_path / "sub" / "t.txt", "é\n").read_text(encoding="utf-8") == "é\n"
    fig = plt.figure()
    png = save_figure(fig, tmp_path / "f.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not plt.fignum_exists(fig.number)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.png", "sub"]


_HOLD = ("import sys, time\nfrom pipeline.atomic import exclusive\nwith exclusive(sys.argv[1]):\n"
         "    print('held', flush=True)\n    time.sleep(60)\n")


def test_one_writer_per_folder_and_a_killed_holder_releases_it(tmp_path):
    holder = subprocess.Popen([sys.executable, "-c", _HOLD, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(FolderBusy, match=f"pid {holder.pid}"):
            with exclusive(tmp_path):
                pass
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    deadline = time.monotonic() + 10
    while True:  # the kernel drops the lock with the process
        try:
            with exclusive(tmp_path):
                assert (tmp_path / ".lock").read_text().strip() == str(os.getpid())
                break
        except FolderBusy:
            assert time.monotonic() < deadline
            time.sleep(0.05)
    # released: the file names no process any more (a worker of this one may not write into the folder now)
    assert (tmp_path / ".lock").read_text() == ""


def test_all_or_none_touches_no_target_when_a_later_write_fails(tmp_path):
    from pipeline.atomic import all_or_none

    a, b = tmp_path / "diagnostics.parquet", tmp_path / "tracks.parquet"
    a.write_text("old diagnostics")
    b.write_text("old tracks")
    with pytest.raises(OSError):
        with all_or_none([a, b]) as (ta, tb):
            ta.write_text("new diagnostics")
            raise OSError(28, "No space left on device")
    assert (a.read_text(), b.read_text()) == ("old diagnostics", "old tracks")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["diagnostics.parquet", "tracks.parquet"]
    with pytest.raises(ValueError, match="share one path"):
        with all_or_none([a, a]):
            pass


@pytest.mark.parametrize("stage", ["track", "retrieve"])
def test_a_stage_whose_second_output_fails_keeps_its_previous_outputs(tmp_path, monkeypatch, stage):
    """The CLI's track (tracks + diagnostics) and retrieve (retrieval + candidates) write both or neither."""
    import shutil
    from pathlib import Path

    from click.testing import CliRunner

    import pipeline.schema.io as io
    from stucco_cli.main import cli

    data = Path(__file__).resolve().parents[1] / "data"
    contacts = tmp_path / "contacts.parquet"
    shutil.copyfile(data / "contacts" / "FB-000.parquet", contacts)
    runs = tmp_path / "runs"
    runs.mkdir()
    shutil.copyfile(data / "regression" / "FB-000.parquet", runs / "FB-000.parquet")
    args = {"track": ["track", "--in", str(contacts), "--out", str(tmp_path / "t.parquet"), "--robot", "disc:0.05",
                      "--particles", "10", "--every-step"],
            "retrieve": ["retrieve", "--segments", str(tmp_path / "s.parquet"), "--runs", str(runs), "--out",
                         str(tmp_path / "r.parquet"), "--estimator", "paper", "--no-grasp"]}
    runner = CliRunner()
    for prep in (["-q", *args["track"]], ["-q", "segment", "--in", str(tmp_path / "t.parquet"), "--out",
                                          str(tmp_path / "s.parquet")], ["-q", *args["retrieve"]]):
        assert runner.invoke(cli, prep).exit_code == 0
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}

    real, calls = io._write_parquet, []

    def second_fails(table, sink):
        calls.append(1)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        real(table, sink)

    monkeypatch.setattr(io, "_write_parquet", second_fails)
    r = runner.invoke(cli, ["-q", "--seed", "5", *args[stage], "--force-overwrite"])  # over the previous outputs
    assert r.exit_code == 1 and "No space left" in r.output, r.output
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


def test_segment_writes_no_table_when_its_plot_fails(tmp_path, monkeypatch):
    from pathlib import Path

    from click.testing import CliRunner

    import pipeline.figures.tables
    from stucco_cli.main import cli

    contacts = Path(__file__).resolve().parents[1] / "data" / "contacts" / "FB-000.parquet"
    tracks = tmp_path / "t.parquet"
    runner = CliRunner()
    r = runner.invoke(cli, ["-q", "track", "--in", str(contacts), "--out", str(tracks), "--robot", "disc:0.05",
                            "--particles", "10"])
    assert r.exit_code == 0, r.output

    def plot_fails(segments, tracks_path, path, **kw):
        Path(path).write_bytes(b"half a png")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(pipeline.figures.tables, "segments_figure", plot_fails)  # what `segment --plot` draws with
    before = sorted(p.name for p in tmp_path.iterdir())
    r = runner.invoke(cli, ["segment", "--in", str(tracks), "--out", str(tmp_path / "s.parquet"), "--plot",
                            str(tmp_path / "s.png")])
    assert r.exit_code == 1 and "No space left" in r.output, r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # neither the table nor the plot, no temporaries


def test_write_csv_rows_writes_header_and_rows_and_leaves_no_temporary(tmp_path):
    from pipeline.atomic import write_csv_rows

    path = write_csv_rows(tmp_path / "t.csv", [{"a": 1, "b": "x"}, {"a": 2, "b": "y"}], ["a", "b"])
    assert path.read_text().splitlines() == ["a,b", "1,x", "2,y"]
    assert [p.name for p in tmp_path.iterdir()] == ["t.csv"]
