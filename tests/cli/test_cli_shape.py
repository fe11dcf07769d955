"""The CLI's shape: no module over 400 lines, every bench command registered, `make quick JOBS=1`, shell
completion as docs/cli.md documents it."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

from click.testing import CliRunner

from stucco_cli.main import cli

ROOT = Path(__file__).resolve().parents[2]


def test_no_cli_module_over_400_lines():
    sizes = {f.name: len(f.read_text().splitlines()) for f in (ROOT / "stucco_cli").glob("*.py")}
    assert max(sizes.values()) <= 400, sizes
    for f in (ROOT / "pipeline" / "figures").glob("*.py"):
        assert len(f.read_text().splitlines()) <= 400, f


def test_every_bench_command_is_registered():
    text = CliRunner().invoke(cli, ["bench", "--help"]).output
    for name in ("accuracy", "probe", "pushes", "retrieval", "scale", "sim", "track"):
        assert f"  {name} " in text, name


def test_make_quick_takes_jobs():
    env = dict(os.environ, MAKEFLAGS="")
    out = subprocess.run(["make", "-n", "-C", str(ROOT), "quick", "JOBS=1"], capture_output=True, text=True,
                         env=env).stdout
    assert "evaluate --quick --jobs 1" in out, out
    out = subprocess.run(["make", "-n", "-C", str(ROOT), "quick"], capture_output=True, text=True, env=env).stdout
    assert "evaluate --quick --jobs 2" in out, out


def test_shell_completion_as_documented():
    doc = (ROOT / "docs" / "cli.md").read_text()
    assert '_STUCCO_COMPLETE=bash_source stucco' in doc and "stucco plot" in doc and "--force-overwrite" in doc
    r = CliRunner().invoke(cli, [], prog_name="stucco", env={"_STUCCO_COMPLETE": "bash_source"})
    assert "_stucco_completion" in r.output
    r = CliRunner().invoke(cli, [], prog_name="stucco",
                           env={"_STUCCO_COMPLETE": "bash_complete", "COMP_WORDS": "stucco pl", "COMP_CWORD": "1"})
    assert "plain,plot" in r.output, r.output
