"""Bad option and parameter values are refused where they enter (issue 12, classes 3 and 4).

Every case: a non-zero exit, a last line that names the option or parameter, no traceback, no output written and
every input byte-identical afterwards. Numbers must be finite and within their physical or logical range
(docs/tables.md for units); tracker parameters given with ``--set`` must have the kind of their default.
"""
from __future__ import annotations

import io
import shutil
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from stucco_cli.main import cli

CONTACTS = Path(__file__).resolve().parents[2] / "data" / "contacts" / "FB-000.parquet"

#: (command, extra arguments, text the message must contain).
CASES = [
    ("track", ["--particles", "0"], "--particles"),
    ("track", ["--particles", "1000000000"], "--particles"),
    ("track", ["--length", "0"], "--length"),
    ("track", ["--length", "-1"], "--length"),
    ("track", ["--length", "nan"], "--length"),
    ("track", ["--length", "inf"], "--length"),
    ("track", ["--penetration-length", "nan"], "--penetration-length"),
    ("track", ["--alpha", "0"], "--alpha"),
    ("track", ["--alpha", "1"], "--alpha"),
    ("track", ["--alpha", "2"], "--alpha"),
    ("track", ["--alpha", "-1"], "--alpha"),
    ("track", ["--alpha", "nan"], "--alpha"),
    ("track", ["--tolerance", "-0.001"], "--tolerance"),
    ("track", ["--ess-threshold", "1.5"], "--ess-threshold"),
    ("track", ["--method", "birch", "--set", "threshold=abc"], "threshold"),
    ("track", ["--method", "birch", "--set", "threshold=nan"], "threshold"),
    ("track", ["--method", "dbscan", "--set", "min_samples=2.5"], "min_samples"),
    ("track", ["--method", "dbscan", "--set", "eps=true"], "eps"),
    ("track", ["--set", "n_particles=many"], "n_particles"),
    ("segment", ["--length", "-1"], "--length"),
    ("segment", ["--length", "0"], "--length"),
    ("segment", ["--alpha", "0"], "--alpha"),
    ("segment", ["--alpha", "-1"], "--alpha"),
    ("segment", ["--alpha", "2"], "--alpha"),
    ("segment", ["--alpha", "nan"], "--alpha"),
    ("retrieve", ["--method", "foo"], "--method"),
    ("collect", ["--noise-mm", "nan"], "--noise-mm"),
    ("collect", ["--noise-mm", "inf"], "--noise-mm"),
    ("collect", ["--noise-mm", "-1"], "--noise-mm"),
    ("seed", ["--seed", "-1"], "--seed"),
]


def _args(command: str, extra: list[str], files: dict[str, Path]) -> list[str]:
    if command == "track":
        return ["track", "--in", str(files["contacts"]), "--out", str(files["out"]), "--robot", "disc:0.05", *extra]
    if command == "segment":
        return ["segment", "--in", str(files["tracks"]), "--out", str(files["out"]), *extra]
    if command == "retrieve":
        return ["retrieve", "--segments", str(files["segments"]), "--runs", str(files["runs"]), "--out",
                str(files["out"]), *extra]
    if command == "collect":
        return ["collect", "--scene", "FB", "--seeds", "0", "--out", str(files["runs"]), *extra]
    return [*extra, "track", "--in", str(files["contacts"]), "--out", str(files["out"]), "--robot", "disc:0.05"]


@pytest.mark.parametrize("command, extra, culprit", CASES, ids=[f"{c}:{' '.join(e)}" for c, e, _ in CASES])
def test_bad_value_is_refused_in_one_line_and_touches_nothing(tmp_path, command, extra, culprit):
    files = {"contacts": tmp_path / "contacts.parquet", "tracks": tmp_path / "tracks.parquet",
             "segments": tmp_path / "segments.parquet", "runs": tmp_path / "runs", "out": tmp_path / "out.parquet"}
    shutil.copyfile(CONTACTS, files["contacts"])
    files["tracks"].write_bytes(b"tracks the user keeps")
    files["segments"].write_bytes(b"segments the user keeps")
    files["runs"].mkdir()
    before = {p: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}

    r = CliRunner().invoke(cli, _args(command, extra, files))

    assert r.exit_code != 0, r.output
    assert "Traceback" not in r.output and not isinstance(r.exception, (TypeError, AttributeError, MemoryError))
    last = [ln for ln in r.output.splitlines() if ln.strip()][-1]
    assert last.startswith("Error:") and culprit in last, r.output
    assert {p: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before
    assert not files["out"].exists() and not any(files["runs"].iterdir())


# ------------------------------------------------------------------------------------------ bad output paths

#: (command line with placeholders, culprit): {dir} an existing directory, {file} an existing file (so {file}/x
#: lies under a file), {long} a 300-byte name; {contacts}, {tracks}, {segments}, {runs} as above.
PATH_CASES = [
    ("track --in {contacts} --out {dir}", "--out"),
    ("track --in {contacts} --out {file}/t.parquet", "--out"),
    ("track --in {contacts} --out {long}", "--out"),
    ("track --in {contacts} --out {tmp}/t.parquet --diagnostics {dir}", "--diagnostics"),
    ("segment --in {tracks} --out {dir}", "--out"),
    ("segment --in {tracks} --out {tmp}/s.parquet --plot {dir}", "--plot"),
    ("segment --in {tracks} --out {tmp}/s.parquet --plot {file}/p.png", "--plot"),
    ("segment --in {tracks} --out {tmp}/s.parquet --plot {long}", "--plot"),
    ("retrieve --segments {segments} --runs {runs} --out {dir}", "--out"),
    ("retrieve --segments {segments} --runs {runs} --out {tmp}/r.parquet --candidates {dir}", "--candidates"),
    ("retrieve --segments {segments} --runs {runs} --out {tmp}/r.parquet --candidates {file}/c.parquet",
     "--candidates"),
    ("score --retrieval {segments} --segments {tracks} --runs {runs} --out {dir}", "--out"),
    ("isolate --in {runs} --out {dir}", "--out"),
    ("isolate --in {runs} --out {file}/c.parquet", "--out"),
    ("collect --scene FB --out {file}/runs", "--out"),
    ("evaluate --quick --out {file}/eval", "--out"),
    ("evaluate --quick --out {tmp}/eval --snapshot {file}/snap", "--snapshot"),
    ("bench accuracy --out {file}/acc", "--out"),
    ("bench retrieval --runs-from {tmp} --out {file}/ladder", "--out"),
    ("bench track --json {file}/b.json", "--json"),
    ("bench track --json {dir}", "--json"),
    ("study training --out {file}/training", "--out"),
]


@pytest.mark.parametrize("line, culprit", PATH_CASES, ids=[c for c, _ in PATH_CASES])
def test_unwritable_output_is_refused_before_any_work(tmp_path, line, culprit):
    (tmp_path / "runs").mkdir()
    (tmp_path / "adir").mkdir()
    shutil.copyfile(CONTACTS, tmp_path / "contacts.parquet")
    for name in ("tracks", "segments", "afile"):
        (tmp_path / name).write_bytes(f"{name} the user keeps".encode())
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    names = dict(tmp=tmp_path, dir=tmp_path / "adir", file=tmp_path / "afile", long=tmp_path / ("x" * 300),
                 contacts=tmp_path / "contacts.parquet", tracks=tmp_path / "tracks", segments=tmp_path / "segments",
                 runs=tmp_path / "runs")

    r = CliRunner().invoke(cli, line.format(**names).split())

    assert r.exit_code != 0, r.output
    assert "Traceback" not in r.output and (r.exception is None or isinstance(r.exception, SystemExit)), r.exception
    last = [ln for ln in r.output.splitlines() if ln.strip()][-1]
    assert last.startswith("Error:") and culprit in last, r.output
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


# ------------------------------------------------------------------------------ inputs that do not belong together

REGRESSION = Path(__file__).resolve().parents[2] / "data" / "regression"


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("mismatch") / "ev"
    r = CliRunner().invoke(cli, ["-q", "evaluate", "--from-runs", str(REGRESSION), "--scenes", "FB,TC", "--seeds",
                                 "0", "--methods", "stucco", "--estimators", "paper", "--no-figures", "--out",
                                 str(out)])
    assert r.exit_code == 0, r.output
    return out


def _part(out: Path, kind: str, scene: str) -> Path:
    from pipeline.layout import partition

    return partition(out, kind, scene, 0, "stucco", "paper")


@pytest.mark.parametrize("segments_of, diagnostics_of, culprit", [
    ("TC", "FB", "not the segments table"),
    ("FB", "TC", "no diagnostics for run"),
])
def test_score_refuses_inputs_of_another_run(two_runs, tmp_path, segments_of, diagnostics_of, culprit):
    files = [_part(two_runs, k, s) for k, s in (("retrieval", "FB"), ("segments", segments_of),
                                                ("diagnostics", diagnostics_of))]
    before = [f.read_bytes() for f in files]
    out = tmp_path / "scores.parquet"
    r = CliRunner().invoke(cli, ["score", "--retrieval", str(files[0]), "--segments", str(files[1]), "--diagnostics",
                                 str(files[2]), "--runs", str(_part(two_runs, "runs", "FB").parent), "--out",
                                 str(out)])
    assert r.exit_code == 1, r.output
    last = [ln for ln in r.output.splitlines() if ln.strip()][-1]
    assert last.startswith("Error:") and culprit in last and "Traceback" not in r.output, r.output
    assert [f.read_bytes() for f in files] == before and not out.exists()


def test_score_accepts_the_inputs_the_retrieval_was_made_from(two_runs, tmp_path):
    out = tmp_path / "scores.parquet"
    r = CliRunner().invoke(cli, ["score", "--retrieval", str(_part(two_runs, "retrieval", "FB")), "--segments",
                                 str(_part(two_runs, "segments", "FB")), "--diagnostics",
                                 str(_part(two_runs, "diagnostics", "FB")), "--runs",
                                 str(_part(two_runs, "runs", "FB").parent), "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert out.exists()


# ------------------------------------------------------------------------------------------ bench track

#: (arguments with placeholders, culprit): {empty} an empty folder, {corrupt} a folder whose stream is not an
#: npz, {pickled} one holding an object array (refused: no pickles are loaded), {false} a python that fails.
BENCH_TRACK_CASES = [
    ("--streams {empty}", "no stream for T=50"),
    ("--streams {corrupt} --T 50", "not a stream file"),
    ("--streams {pickled} --T 50", "not a stream file"),
    ("--streams {partial} --T 50", "'x' missing"),
    ("--T abc", "--T"),
    ("--T 500", "no stream for T=500"),  # longer than every stream: nothing to cut it from
    ("--T 0", "--T"),
    ("--N 0", "--N"),
    ("--N 1000000000", "--N"),
    ("--N abc", "--N"),
    ("--methods foo", "--methods"),
    ("--T 50 --N 100 --methods stucco,foo", "--methods"),
    ("--reference-python {false}", "--reference-python"),
]


@pytest.mark.parametrize("line, culprit", BENCH_TRACK_CASES, ids=[c for c, _ in BENCH_TRACK_CASES])
def test_bench_track_refuses_bad_input_before_measuring(tmp_path, line, culprit):
    import numpy as np

    folders = {k: tmp_path / k for k in ("empty", "corrupt", "pickled", "partial")}
    for f in folders.values():
        f.mkdir()
    (folders["corrupt"] / "stream_T50.npz").write_bytes(b"not an npz file at all")
    np.savez(folders["pickled"] / "stream_T50.npz", x=np.array([{"a": 1}], dtype=object))
    np.savez(folders["partial"] / "stream_T50.npz", dx=np.zeros((3, 2)))
    false = tmp_path / "false"
    false.write_text("#!/bin/sh\nexit 3\n")
    false.chmod(0o755)
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}

    r = CliRunner().invoke(cli, ["bench", "track", *line.format(false=false, **folders).split()])

    assert r.exit_code != 0, r.output
    assert "Traceback" not in r.output and (r.exception is None or isinstance(r.exception, SystemExit)), r.exception
    assert "SPEED" not in r.output  # refused before the first measurement
    last = [ln for ln in r.output.splitlines() if ln.strip()][-1]
    assert last.startswith("Error:") and culprit in last, r.output
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


def test_a_stored_run_filed_under_another_runs_name_is_refused(tmp_path):
    # each job copies the stored run named after its scene and seed: a file holding another run under that name
    # would be evaluated as the run its name says
    runs = tmp_path / "runs"
    runs.mkdir()
    shutil.copy(REGRESSION / "FB-000.parquet", runs / "FB-001.parquet")
    r = CliRunner().invoke(cli, ["-q", "evaluate", "--from-runs", str(runs), "--methods", "stucco", "--no-figures",
                                 "--out", str(tmp_path / "ev")])
    assert r.exit_code != 0 and "Traceback" not in r.output
    assert "FB-001.parquet: holds run FB/0, which evaluate reads from FB-000.parquet" in r.output.splitlines()[-1]
    assert not (tmp_path / "ev" / "scores").exists()


@pytest.mark.parametrize("collect_args, setting", [
    (["--max-actions", "5"], "max_actions 5"),
    (["--max-actions", "10", "--noise-mm", "20"], "effects"),
    (["--max-actions", "10", "--policy", "scripted+probe", "--policy-param", "budget=1"], "policy 'scripted+probe'"),
])
def test_a_run_collected_otherwise_in_an_evaluation_folder_is_refused(tmp_path, collect_args, setting):
    # evaluate reuses the run file of its folder: one collected with other settings (placed there by hand) would be
    # evaluated as this evaluation's run
    def stucco(*args):
        return CliRunner().invoke(cli, ["-q", "--seed", "0", *args])

    grid = ["evaluate", "--scenes", "FB", "--seeds", "0", "--methods", "stucco", "--estimators", "plausible",
            "--no-figures", "--max-actions", "10", "--out", str(tmp_path / "ev")]
    assert stucco(*grid).exit_code == 0
    r = stucco("collect", "--scene", "FB", "--seeds", "0", "--out", str(tmp_path / "ev" / "runs"), "--force-overwrite",
               *collect_args)
    assert r.exit_code == 0, r.output
    r = stucco(*grid)
    last = r.output.splitlines()[-1]
    assert r.exit_code != 0 and "FB-000.parquet: collected with " + setting in last, r.output
    assert "not" in last and "remove it to collect it again" in last


def test_a_damaged_scores_file_is_rebuilt_on_resume(tmp_path):
    # the resume rebuilds a damaged output; the stage times it borrows from earlier scores must not trip on it
    def stucco(*args):
        return CliRunner().invoke(cli, ["-q", "--seed", "0", *args])

    grid = ["evaluate", "--scenes", "FB", "--seeds", "0", "--methods", "stucco", "--estimators", "plausible",
            "--no-figures", "--max-actions", "10", "--out", str(tmp_path / "ev")]
    assert stucco(*grid).exit_code == 0
    scores = tmp_path / "ev" / "scores" / "FB-000-stucco-plausible.parquet"
    good = scores.read_bytes()
    scores.write_text("garbage")
    r = stucco(*grid)
    assert r.exit_code == 0, r.output
    assert pq.read_table(scores).drop_columns([c for c in pq.read_schema(scores).names if c.endswith("_s")]).equals(
        pq.read_table(io.BytesIO(good)).drop_columns([c for c in pq.read_schema(scores).names if c.endswith("_s")]))


def test_a_figure_is_redrawn_when_the_methods_it_shows_change(tmp_path):
    # a figure is stale when older than a scores file it shows, and also when it shows other panels than the
    # evaluation would draw now (a method dropped from the grid: no scores file is newer)
    from pipeline.figures import drawn, figure_path

    def grid(methods):
        r = CliRunner().invoke(cli, ["-q", "--seed", "0", "evaluate", "--scenes", "FB", "--seeds", "0", "--methods",
                                     methods, "--estimators", "plausible", "--max-actions", "10", "--out",
                                     str(tmp_path / "ev")])
        assert r.exit_code == 0, r.output
        return drawn(figure_path(tmp_path / "ev", "FB", 0))

    assert grid("stucco,kmeans") == {"methods": ["stucco", "kmeans"], "estimator": "plausible"}
    assert grid("stucco") == {"methods": ["stucco"], "estimator": "plausible"}
    assert drawn(tmp_path / "nothing.png") is None


@pytest.mark.parametrize("policy_args", [["--policy", "rummage", "--policy-param", "contacts=3"],
                                         ["--policy", "scripted+probe", "--policy-param", "budget=1"]])
def test_an_evaluation_of_a_policy_with_parameters_resumes(tmp_path, policy_args):
    # the run-settings check reads each policy's parameters where it records them: the same command again resumes
    args = ["-q", "--seed", "0", "evaluate", "--scenes", "FB", "--seeds", "0", "--methods", "stucco", "--estimators",
            "plausible", "--no-figures", "--max-actions", "30", "--out", str(tmp_path / "ev"), *policy_args]
    first = CliRunner().invoke(cli, args)
    assert first.exit_code == 0, first.output
    again = CliRunner().invoke(cli, args[1:])  # without -q: the summary line
    assert again.exit_code == 0, again.output
    assert "0 run, 1 already done" in again.output
