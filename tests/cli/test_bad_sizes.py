"""Every size a user gives is bounded by what the machine holds, and every path to a parameter is validated the
same way (issue 17, bad-input probe): one line saying the bound, never a MemoryError traceback; ``--set`` goes
through the checks of the dedicated options because the parameter dataclasses check themselves."""
from __future__ import annotations

from pathlib import Path

import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from pipeline.collect import MAX_SEEDS, parse_seeds
from pipeline.retrieve import PlausibleParams, RetrievalParams
from pipeline.studies.anchors import load_stream, stream_path, stream_to_contacts
from pipeline.track.soft import MAX_PARTICLES, SoftTrackingParams
from stucco_cli.main import cli
from stucco_cli.track import MAX_PARTICLES as CLI_MAX_PARTICLES
from tests.cli.test_bad_runs import RUN, _stucco_segments


@pytest.fixture
def contacts(tmp_path) -> Path:
    path = tmp_path / "contacts.parquet"
    pq.write_table(stream_to_contacts(load_stream(stream_path(50)), "r").slice(0, 70), path)
    return path


def _one_line(r, *words: str) -> str:
    assert r.exit_code not in (0, None) and isinstance(r.exception, SystemExit), r.output
    lines = [ln for ln in r.output.strip().splitlines() if ln.strip() and not ln.startswith(("Usage:", "Try "))]
    assert len(lines) == 1 and "Traceback" not in r.output, r.output
    for w in words:
        assert w in lines[0], r.output
    return lines[0]


@pytest.mark.parametrize("args, words", [
    (["--set", "n_particles=1000000"], ["n_particles", str(MAX_PARTICLES)]),
    (["--set", "n_particles=1e9"], ["n_particles", str(MAX_PARTICLES)]),
    (["--set", "alpha=5"], ["alpha must be in (0, 1)"]),
    (["--set", "alpha=0"], ["alpha must be in (0, 1)"]),
    (["--robot", "disc:1000"], ["radius must be at most 1.0 metres"]),
    (["--robot", "panda:1e-7"], ["resolution must be in [0.00025, 0.05]"]),
], ids=["set particles", "set particles float", "set alpha 5", "set alpha 0", "huge disc", "fine panda grid"])
def test_track_bounds_every_size_and_validates_set_like_the_options(tmp_path, contacts, args, words):
    out = tmp_path / "tracks.parquet"
    robot = [] if "--robot" in args else ["--robot", "disc:0.05"]
    r = CliRunner().invoke(cli, ["-q", "track", "--in", str(contacts), "--out", str(out), *robot, *args])
    _one_line(r, *words)
    assert not out.exists()


def test_the_cli_and_the_tracker_share_the_particle_bound():
    assert CLI_MAX_PARTICLES == MAX_PARTICLES


@pytest.mark.parametrize("option, value", [("--hypotheses", "100000"), ("--restarts", "100000")])
def test_retrieve_bounds_hypotheses_and_restarts(tmp_path, option, value):
    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / "FB-000.parquet").write_bytes(RUN.read_bytes())
    segments = _stucco_segments(tmp_path / "segments.parquet")
    r = CliRunner().invoke(cli, ["-q", "retrieve", "--segments", str(segments), "--runs", str(runs),
                                 "--out", str(tmp_path / "r.parquet"), option, value])
    assert r.exit_code == 2
    _one_line(r, option, "100000")


@pytest.mark.parametrize("command", ["collect", "evaluate"])
def test_a_seed_range_of_a_billion_is_refused_at_once(tmp_path, command):
    args = (["collect", "--scene", "FB", "--out", str(tmp_path / "runs")] if command == "collect" else
            ["evaluate", "--scenes", "FB", "--out", str(tmp_path / "ev")])
    r = CliRunner().invoke(cli, ["-q", *args, "--seeds", "0-1000000000"])
    _one_line(r, "--seeds", f"at most {MAX_SEEDS} seeds")
    assert not any(tmp_path.iterdir())


def test_parse_seeds_counts_overlapping_parts_once():
    assert parse_seeds("0-3,2-5") == [0, 1, 2, 3, 4, 5]
    assert len(parse_seeds(f"0-{MAX_SEEDS - 1}")) == MAX_SEEDS
    with pytest.raises(ValueError, match="seeds are at most"):
        parse_seeds(f"{2**32}")


@pytest.mark.parametrize("make, match", [
    (lambda: SoftTrackingParams(alpha=1.5), r"alpha must be in \(0, 1\)"),
    (lambda: SoftTrackingParams(n_particles=MAX_PARTICLES + 1), "n_particles"),
    (lambda: RetrievalParams(n_restarts=10**6), "n_restarts must be .*at most 1000"),
    (lambda: PlausibleParams(n_hypotheses=10**6), "n_hypotheses must be .*at most 4096"),
], ids=["alpha", "particles", "restarts", "hypotheses"])
def test_parameter_dataclasses_check_their_bounds(make, match):
    with pytest.raises(ValueError, match=match):
        make()


@pytest.mark.parametrize("method, setting, words", [
    ("gmphd", "birth_grid=100000", ["birth_grid must be", "at most 100,"]),
    ("kmeans", "n_init=1000000000", ["n_init must be", "at most 1000,"]),
])
def test_baseline_sizes_set_with_set_are_bounded(tmp_path, contacts, method, setting, words):
    out = tmp_path / "tracks.parquet"
    r = CliRunner().invoke(cli, ["-q", "track", "--in", str(contacts), "--out", str(out), "--robot", "disc:0.05",
                                 "--method", method, "--set", setting])
    _one_line(r, *words)
    assert not out.exists()


@pytest.mark.parametrize("args", [["-j", "100000", "scenes"], ["evaluate", "-j", "100000", "--quick"],
                                  ["study", "training", "-j", "100000"]], ids=["group", "evaluate", "study"])
def test_worker_processes_are_bounded(args):
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 2
    _one_line(r, "100000", "1<=x<=64")
