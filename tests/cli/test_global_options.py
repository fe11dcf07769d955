"""The global options (--seed, -j, -v, -q) after the command mean what they mean before it; where one cannot
apply, a usage error says where it goes; `evaluate -j` keeps working."""
from __future__ import annotations

import pytest

from pipeline import schema
from tests.cli.stages import FAST_TRACK, invoke, ok


def test_seed_and_jobs_after_the_command_mean_the_same(stages, tmp_path):
    d, _ = stages
    before, after = tmp_path / "before.parquet", tmp_path / "after.parquet"
    ok(invoke("--seed", 3, "-j", 1, "track", "--in", d / "contacts.parquet", "--out", before, *FAST_TRACK))
    ok(invoke("track", "--in", d / "contacts.parquet", "--out", after, *FAST_TRACK, "-j", 1, "--seed", 3))
    assert schema.read_metadata(after)["seed"] == 3
    assert schema.read_tracks(after).equals(schema.read_tracks(before))


def test_after_the_command_wins(stages, tmp_path):
    d, _ = stages
    out = tmp_path / "t.parquet"  # (track draws from its seed; isolate, drawing nothing, records its runs')
    ok(invoke("--seed", 1, "track", "--in", d / "contacts.parquet", "--out", out, "--robot", "disc:0.05",
              "--particles", 20, "--seed", 2))
    assert schema.read_metadata(out)["seed"] == 2


def test_jobs_after_the_command_is_checked_like_before(stages, tmp_path):
    d, _ = stages
    for pre, post in ((["-j", 65], []), ([], ["-j", 65])):
        res = invoke(*pre, "track", "--in", d / "contacts.parquet", "--out", tmp_path / "t.parquet", *post)
        assert res.exit_code == 2 and "Invalid value for '--jobs' / '-j'" in res.stderr, res.output


@pytest.mark.parametrize("args, needle", [
    (["isolate", "--in", "x", "--out", "y.parquet", "-j", 2], "-j/--jobs does not apply to `stucco isolate`: it runs "
                                                             "in one process; -j goes with collect, track, retrieve"),
    (["scenes", "--seed", 1], "--seed does not apply to `stucco scenes`: it draws nothing at random"),
    (["plot", "--in", "x", "--out", "y.png", "-j", 2], "-j/--jobs does not apply to `stucco plot`"),
    (["score", "--retrieval", "r", "--segments", "s", "--runs", "d", "--out", "o", "-j", 2], "-j/--jobs does not"),
])
def test_an_option_that_cannot_apply_says_where_it_goes(args, needle):
    res = invoke(*args, prog_name="stucco")
    assert res.exit_code == 2 and needle in res.stderr, res.output


def test_quiet_and_verbose_after_the_command(stages, tmp_path):
    d, _ = stages
    out = tmp_path / "c.parquet"
    res = ok(invoke("isolate", "--in", d / "runs", "--out", out, "-q"))
    assert res.stderr == "" and res.stdout == ""
    res = ok(invoke("isolate", "--in", d / "runs", "--out", out, "--force-overwrite", "-v"))
    assert f"-> {out}" in res.stderr


def test_evaluate_keeps_its_own_jobs_and_takes_the_others():
    text = invoke("evaluate", "--help").output
    assert text.count("--jobs") == 1 and "--seed" in text and "--quiet" in text
    res = invoke("evaluate", "--jobs", 0)
    assert res.exit_code == 2 and "'--jobs' / '-j'" in res.stderr
    for sub in (["bench", "accuracy"], ["study", "training"]):
        assert invoke(*sub, "--help").output.count("--jobs") == 1, sub
