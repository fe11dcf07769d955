"""`make setup`'s environment rules, on stand-in environments (no network, no install): a new environment replaces
the previous one only when it passes its checks, else the previous one is put back untouched; an installed one that
fails its checks loses its stamp, so the next setup builds it again (docs/evaluation.md, "Same numbers on every
machine")."""
from __future__ import annotations

import os
import shutil
import stat
import subprocess
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(shutil.which("make") is None, reason="needs make")


def _exe(path: Path, code: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"#!/bin/sh\nexit {code}\n")
    path.chmod(path.stat().st_mode | stat.S_IXUSR)


def _project(tmp_path: Path, works: bool) -> Path:
    """A folder with the Makefile, its inputs, and a stand-in installed environment whose tools exit 0 or 1."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    shutil.copy(ROOT / "Makefile", tmp_path / "Makefile")
    for name in ("bin/python", "bin/uv", "bin/pip"):
        _exe(tmp_path / ".venv" / name, 0 if works else 1)
    (tmp_path / ".venv" / "marker").write_text("the previous environment")
    (tmp_path / ".venv" / ".installed").touch()
    old = time.time() - 100
    os.utime(tmp_path / ".venv" / ".installed", (old, old))
    (tmp_path / "pyproject.toml").write_text("")
    (tmp_path / "requirements.lock").write_text("")  # newer than the stamp: the environment is out of date
    return tmp_path


def _make(folder: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["make", "--no-print-directory", "-C", str(folder), *args], capture_output=True, text=True,
                          timeout=60)


def test_a_failed_install_keeps_the_previous_environment(tmp_path):
    folder = _project(tmp_path, works=True)
    r = _make(folder, ".venv/.installed", "PYTHON=/bin/false")  # the new environment cannot even be created
    assert r.returncode != 0
    assert "the previous one is kept as it was" in r.stderr
    assert (folder / ".venv" / "marker").read_text() == "the previous environment"
    assert (folder / ".venv" / ".installed").is_file() and not (folder / ".venv.old").exists()


def test_a_damaged_environment_loses_its_stamp_and_a_sound_one_keeps_it(tmp_path):
    damaged = _project(tmp_path / "damaged", works=False)
    r = _make(damaged, "verify-venv")
    assert r.returncode == 0 and "fails its checks" in r.stdout
    assert not (damaged / ".venv" / ".installed").exists()
    sound = _project(tmp_path / "sound", works=True)
    r = _make(sound, "verify-venv")
    assert r.returncode == 0 and r.stdout == ""
    assert (sound / ".venv" / ".installed").is_file()
