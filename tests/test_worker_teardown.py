"""An interrupted ``evaluate -j 2`` takes its workers with it: killed (SIGKILL, so no clean-up runs in it) or
terminated (SIGTERM), the parent leaves no worker process behind within 5 s, and nothing is written into the
folder afterwards (pipeline/parallel.py: each worker watches its parent; pipeline/atomic.py: a worker renames an
output into place only while the folder's lock names its parent)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _children(pid: int) -> set[int]:
    """Processes whose parent is ``pid`` (from /proc; psutil is not a dependency)."""
    out = set()
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.add(int(entry))
    return out


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _files(folder: Path) -> dict[str, int]:
    return {str(p.relative_to(folder)): p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file()}


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_killing_evaluate_leaves_no_worker_and_no_later_write(tmp_path, sig):
    out = tmp_path / "ev"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(
        [sys.executable, "-c", "from stucco_cli.main import cli; cli()", "evaluate", "--scenes", "FB", "--seeds",
         "0-1", "--methods", "stucco", "--max-actions", "60", "--no-figures", "-j", "2", "--out", str(out)],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 240
        # the jobs phase: both runs collected and isolated, the workers tracking
        while not (len(list(out.glob("contacts/**/*.parquet"))) >= 2 and len(_children(proc.pid)) >= 2):
            assert proc.poll() is None, "evaluate ended before its jobs could be interrupted"
            assert time.monotonic() < deadline, "evaluate's jobs did not start"
            time.sleep(0.05)
        children = _children(proc.pid)
        os.kill(proc.pid, sig)
        proc.wait(timeout=30)
        deadline = time.monotonic() + 5
        while any(_alive(c) for c in children) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not [c for c in children if _alive(c)], "worker processes outlived evaluate"
        before = _files(out)
        time.sleep(2.0)
        assert _files(out) == before, "a file was written into the folder after evaluate ended"
        assert not (out / "scores").exists() or not list((out / "scores").rglob("*.parquet"))
    finally:
        if proc.poll() is None:
            proc.kill()
        try:
            os.killpg(proc.pid, signal.SIGKILL)  # whatever of its session is left (the test failed)
        except ProcessLookupError:
            pass
