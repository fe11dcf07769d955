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


_HOLD = "import sys, time\nfrom pipeline.atomic import exclusive\nwith exclusive(sys.argv[1]):\n    print('held', flush=True)\n    time.sleep(60)\n"


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
                break
        except FolderBusy:
            assert time.monotonic() < deadline
            time.sleep(0.05)
    assert (tmp_path / ".lock").read_text().strip() == str(os.getpid())
