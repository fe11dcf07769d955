"""One overwrite rule for every stage command (and `stucco plot`): an output that exists is refused in one line
naming it, its option and --force-overwrite, nothing is written; with --force-overwrite it is replaced."""
from __future__ import annotations

import pytest

from tests.cli.stages import commands, invoke, ok

COMMANDS = ("collect", "isolate", "track", "segment", "retrieve", "score", "plot")


@pytest.mark.parametrize("name", COMMANDS)
def test_every_stage_refuses_to_overwrite_without_force(stages, name):
    d, _ = stages
    args, outputs = commands(d)[name]
    before = {p: p.read_bytes() for p in outputs.values()}
    res = invoke(*args)
    assert res.exit_code == 1 and "Traceback" not in res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    first = next(iter(outputs.items()))
    assert lines[0] == f"Error: {first[1]}: exists ({first[0]}); pass --force-overwrite to replace it"
    assert {p: p.read_bytes() for p in outputs.values()} == before


@pytest.mark.parametrize("name", ["track", "segment", "retrieve"])
def test_a_side_output_that_exists_is_refused_too(stages, tmp_path, name):
    # --diagnostics, --plot, --candidates: refused like --out, naming their own option
    d, _ = stages
    args, outputs = commands(d)[name]
    (opt, side), = [(o, p) for o, p in outputs.items() if o != "--out"]
    out = tmp_path / "new.parquet"
    args = [out if a == outputs["--out"] else a for a in args]
    if opt != "--plot":
        args += [opt, side]
    res = invoke(*args)
    assert res.exit_code == 1 and f"{side}: exists ({opt}); pass --force-overwrite" in res.stderr, res.output
    assert not out.exists()


@pytest.mark.parametrize("name", ["isolate", "score", "plot", "segment"])
def test_force_overwrite_replaces(stages, name):
    d, _ = stages
    args, outputs = commands(d)[name]
    before = {p: p.stat().st_mtime_ns for p in outputs.values()}
    ok(invoke(*args, "--force-overwrite", "-q"))
    assert all(p.stat().st_mtime_ns >= before[p] for p in outputs.values())


def test_every_stage_command_takes_force_overwrite():
    for name in COMMANDS:
        assert "--force-overwrite" in invoke(name, "--help").output, name


def test_collect_checks_the_file_of_every_seed(stages):
    d, _ = stages
    res = invoke("collect", "--scene", "FB", "--seeds", "0-1", "--max-actions", 1, "--out", d / "runs")
    assert res.exit_code == 1 and f"{d / 'runs' / 'FB-000.parquet'}: exists (--out)" in res.stderr, res.output
    assert not (d / "runs" / "FB-001.parquet").exists()
