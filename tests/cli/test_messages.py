"""Every command says what it wrote (one line on stderr), -q silences it; progress bars only on a terminal, through
the one helper of stucco_cli/progress.py."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from stucco_cli import progress
from stucco_cli.common import Settings
from tests.cli.stages import commands, invoke, ok

CLI = Path(__file__).resolve().parents[2] / "stucco_cli"


def test_every_stage_says_what_it_wrote(stages):
    d, said = stages
    assert said["collect"].strip().splitlines()[-1] == f"wrote 1 run file(s) to {d / 'runs'}"
    assert re.fullmatch(r"isolated (\d+) contact\(s\) of \1 in contact over 12 actions of 1 run\(s\) -> "
                        + re.escape(str(d / "contacts.parquet")), said["isolate"].strip())
    assert f"-> {d / 'tracks.parquet'}" in said["track"]
    assert said["segment"].strip().endswith(f"-> {d / 'segments.parquet'} (plot: {d / 'segments.png'})")
    assert f"-> {d / 'retrieval.parquet'}" in said["retrieve"] and f"-> {d / 'scores.parquet'}" in said["score"]
    assert said["plot"].strip() == f"drew run FB/0 of the segments table {d / 'segments.parquet'} -> {d / 'plot.png'}"


@pytest.mark.parametrize("name", ["collect", "isolate", "segment", "score", "plot"])
def test_quiet_says_nothing(stages, name):
    d, _ = stages
    args, _ = commands(d)[name]
    res = ok(invoke("-q", *args, "--force-overwrite"))
    assert res.stderr == "" and res.stdout == ""


def test_no_carriage_returns_off_a_terminal(stages):
    # CliRunner's stderr is not a terminal, as a log file or a pipe: no bar, no \r
    assert not any("\r" in text for text in stages[1].values())


def test_bars_only_on_a_terminal_and_never_when_quiet(monkeypatch):
    monkeypatch.setattr(progress, "stderr_is_terminal", lambda: False)
    assert progress.bars_off(Settings()) is True
    monkeypatch.setattr(progress, "stderr_is_terminal", lambda: True)
    assert progress.bars_off(Settings()) is False and progress.bars_off(Settings(verbosity=-1)) is True
    assert progress.progress_lines(Settings(verbosity=-1)) is None


def test_one_progress_helper():
    # every command hands stages progress through stucco_cli/progress.py; none builds its own bar
    for f in CLI.glob("*.py"):
        text = f.read_text()
        if f.name != "progress.py":
            assert "tqdm" not in text and "settings.progress" not in text, f.name
