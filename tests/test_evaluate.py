"""`stucco evaluate` on a tiny grid: every stage file, the report, skipping finished jobs, resuming, errors.

One evaluation (IB seed 0 cut to 12 actions, STUCCO and GM-PHD, 5 ICP restarts) is made once per module; tests
that change files work on a copy.
"""
from __future__ import annotations

import csv
import io
import json
import pickle
import re
import shutil
from pathlib import Path

import numpy as np
import pyarrow.dataset as ds
import pytest
from click.testing import CliRunner

from pipeline import registry, schema
from pipeline.evaluate import (
    KINDS,
    STAGE_COLUMNS,
    STAGE_SPECS,
    STAGES,
    EvalConfig,
    Job,
    evaluate,
    job_paths,
    parse_methods,
    parse_scenes,
    partition,
    read_kind,
    stale_stages,
)
from pipeline.figures import figure_path

CFG = EvalConfig(root_seed=0, max_actions=12, restarts=5)
METHODS = ("stucco", "gmphd")


def _run(out: Path, cfg: EvalConfig = CFG):
    return evaluate(out, ["IB"], [0], METHODS, cfg, jobs=1, progress=True)


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("eval") / "ev"
    ev = _run(out)
    # collect and isolate run once for both methods, before the jobs.
    assert ev.prepared == [("IB", 0, ("collect", "isolate"))]
    assert [r.ran for r in ev.results] == [STAGES[2:], STAGES[2:]]
    return out


@pytest.fixture
def copy(evaluated, tmp_path) -> Path:
    dst = tmp_path / "ev"
    shutil.copytree(evaluated, dst)
    return dst


def _mtimes(out: Path) -> dict[Path, int]:
    return {p: p.stat().st_mtime_ns for p in out.rglob("*.parquet")}


def test_every_stage_file_report_and_figure_are_written(evaluated):
    for m in METHODS:
        for kind in KINDS:
            path = partition(evaluated, kind, "IB", 0, m)
            assert path.is_file(), path
    assert partition(evaluated, "tracks", "IB", 0, "stucco") == \
        evaluated / "tracks" / "scene=IB" / "seed=0" / "method=stucco" / "part.parquet"
    md = (evaluated / "report.md").read_text()
    assert "| IB | ours (STUCCO) | 1 |" in md and "| IB | GM-PHD | 1 |" in md
    header = (evaluated / "report.csv").read_text().splitlines()[0]
    assert header.startswith("scene,method,estimator,estimator_stream,runs,grasp_success_pct")
    assert figure_path(evaluated, "IB", 0).is_file() and (evaluated / "summary.png").is_file()
    assert json.loads((evaluated / "evaluation.json").read_text())["max_actions"] == 12


def test_scores_carry_stage_wall_times_and_their_sum(evaluated):
    scores = read_kind(evaluated, "scores")
    n = len(registry.estimator_names())  # every registered estimator by default
    assert scores.num_rows == 2 * n and sorted(scores.column("method").to_pylist()) == ["gmphd"] * n + ["stucco"] * n
    assert sorted(scores.column("estimator").to_pylist()) == sorted(registry.estimator_names() * 2)
    # The online paper estimator reads the estimate after every step: the evaluation tracked every step.
    tracks = evaluated / "tracks" / "scene=IB" / "seed=0" / "method=stucco" / "part.parquet"
    assert schema.read_metadata(tracks)["params"]["every_step"] is True
    for row in scores.to_pylist():
        walls = [row[c] for c in STAGE_COLUMNS]
        assert all(w is not None and w >= 0 for w in walls)
        assert row["wall_s"] == pytest.approx(sum(walls))


def test_methods_share_one_collected_run_and_contacts(evaluated):
    runs = read_kind(evaluated, "runs")
    assert runs.num_rows == 12 and set(runs.column("run").to_pylist()) == {"IB/0"}
    tracks = read_kind(evaluated, "tracks", filter=ds.field("method") == "gmphd")
    assert set(tracks.column("method").to_pylist()) == {"gmphd"}
    for m in METHODS:
        meta = schema.read_metadata(partition(evaluated, "tracks", "IB", 0, m))
        assert meta["inputs"]["contacts"]["sha256"] == schema.file_digest(partition(evaluated, "contacts", "IB", 0))
        assert meta["params"]["method"] == m and meta["seed"] == 0


def test_rerun_skips_finished_jobs(copy):
    before = _mtimes(copy)
    ev = _run(copy)
    assert [r.ran for r in ev.results] == [(), ()] and ev.skipped == 2 and ev.prepared == []
    assert _mtimes(copy) == before
    assert ev.scores.num_rows == 2 * len(registry.estimator_names())  # two jobs, every pose estimator each


def test_tracks_made_without_every_step_are_tracked_again_for_the_online_estimator(copy):
    # A folder made before `paper` ran at every in-contact step holds final-only tracks: they are out of date.
    import pyarrow.parquet as pq

    path = partition(copy, "tracks", "IB", 0, "stucco")
    t = pq.read_table(path)
    meta = dict(t.schema.metadata)
    params = json.loads(meta[b"stucco.params"])
    assert params["every_step"] is True
    meta[b"stucco.params"] = json.dumps(dict(params, every_step=False)).encode()
    pq.write_table(t.replace_schema_metadata(meta), path)
    # (the rewritten file has a new digest, so its segments are out of date either way)
    assert stale_stages(copy, Job("IB", 0, "stucco"), ("plausible",)) == STAGES[3:]
    assert stale_stages(copy, Job("IB", 0, "stucco"), ("plausible", "paper")) == STAGES[2:]
    assert stale_stages(copy, Job("IB", 0, "gmphd"), ("plausible", "paper")) == ()


def test_interrupted_job_resumes_from_the_missing_stage(copy):
    partition(copy, "retrieval", "IB", 0, "stucco").unlink()
    before = _mtimes(copy)
    assert stale_stages(copy, Job("IB", 0, "stucco")) == ("retrieve", "score")
    ev = _run(copy)
    assert {r.job.method: r.ran for r in ev.results} == {"stucco": ("retrieve", "score"), "gmphd": ()}
    after = _mtimes(copy)
    unchanged = [k for k in ("runs", "contacts", "tracks", "segments")]
    for kind in unchanged:
        p = partition(copy, kind, "IB", 0, "stucco")
        assert after[p] == before[p], kind
    assert after[partition(copy, "scores", "IB", 0, "stucco")] > before[partition(copy, "scores", "IB", 0, "stucco")]


def test_a_stage_rewritten_with_different_content_reruns_what_follows(copy):
    # Contacts rewritten (here: one row dropped) -> every method's track and later stages are out of date.
    path = partition(copy, "contacts", "IB", 0)
    t = schema.read_contacts(path)
    schema.write_table(t.slice(0, t.num_rows - 1), path, stage="isolate", params={}, seed=0,
                       inputs={"IB-000": partition(copy, "runs", "IB", 0)}, kind="contacts")
    assert stale_stages(copy, Job("IB", 0, "gmphd")) == STAGES[2:]
    ev = _run(copy)
    assert [r.ran for r in ev.results] == [STAGES[2:], STAGES[2:]]


def test_same_directory_with_another_config_is_refused(copy):
    with pytest.raises(ValueError, match=r"was made with max_actions=12, this evaluation asks for max_actions=13"):
        _run(copy, EvalConfig(root_seed=0, max_actions=13, restarts=5))


def test_cli_prints_the_table_of_a_finished_grid(copy):
    from stucco_cli.main import cli

    res = CliRunner().invoke(cli, ["evaluate", "--scenes", "IB", "--seeds", "0", "--methods", "stucco,gmphd",
                                   "--max-actions", "12", "--restarts", "5", "--out", str(copy)])
    assert res.exit_code == 0, res.output
    assert "| IB | ours (STUCCO) | 1 |" in res.stdout
    assert "2 job(s): 0 run, 2 already done" in res.stderr


@pytest.mark.parametrize("args, match", [
    (["--scenes", "FB,XX"], r"Invalid value for --scenes: unknown scene 'XX'; expected some of"),
    (["--scenes", "SELECT1"], r"Invalid value for --scenes: scene 'SELECT1' is a training scene"),
    (["--methods", "stucco,kmean"], r"Invalid value for --methods: unknown method 'kmean'; expected some of "
                                    r"stucco, birch, dbscan, kmeans, gmphd or 'all'"),
    (["--methods", ","], r"Invalid value for --methods: no method given"),
    (["--seeds", "3-1"], r"Invalid value for --seeds: seed range '3-1': end before start"),
    (["--estimators", "plausible,icp"], r"Invalid value for --estimators: unknown estimator 'icp'; expected some of "
                                        r"plausible, paper"),
    (["--estimator-stream", "-1"], r"Invalid value for '--estimator-stream': -1 is not in the range x>=0"),
])
def test_bad_options_fail_with_one_line(tmp_path, args, match):
    from stucco_cli.main import cli

    res = CliRunner().invoke(cli, ["evaluate", *args, "--out", str(tmp_path / "x")])
    assert res.exit_code == 2
    last = [line for line in res.output.splitlines() if line.strip()][-1]
    assert last.startswith("Error: ")
    assert re.search(match, last), last
    assert not (tmp_path / "x").exists()


def test_parsers_keep_table_ii_order():
    assert parse_methods("gmphd,stucco") == ("stucco", "gmphd")
    assert parse_methods("all") == ("stucco", "birch", "dbscan", "kmeans", "gmphd")
    assert parse_scenes("TC,FB,TC") == ("TC", "FB")
    assert parse_scenes("all") == ("FB", "BC", "IB", "TC")


def test_an_estimator_stream_is_recorded_and_refused_in_a_folder_of_another(copy):
    # Stream 0 is the default and left out of evaluation.json (folders made before the option still resume).
    assert "estimator_stream" not in json.loads((copy / "evaluation.json").read_text())
    with pytest.raises(ValueError, match=r"was made with estimator_stream=0, this evaluation asks for "
                                         r"estimator_stream=1"):
        _run(copy, EvalConfig(root_seed=0, max_actions=12, restarts=5, estimator_stream=1))
    assert EvalConfig(estimator_stream=2).to_dict()["estimator_stream"] == 2
    for bad in (-1, True, 1.5, "1"):
        with pytest.raises(ValueError, match="estimator_stream must be a non-negative integer"):
            EvalConfig(estimator_stream=bad)
    assert EvalConfig(estimator_stream=np.int64(3)).to_dict()["estimator_stream"] == 3  # numpy's ints are ints


def test_another_estimator_stream_reruns_only_the_estimators_draws(evaluated, tmp_path):
    # A folder of stream 1 replaying the same stored run: the same segments, the stochastic estimators' draws
    # differ, deterministically.
    runs = tmp_path / "runs"
    runs.mkdir()
    shutil.copy(partition(evaluated, "runs", "IB", 0), runs / "IB-000.parquet")
    cfg = dict(root_seed=0, restarts=5, estimators=("pushtrack",), source=str(runs))
    outs = {}
    for name, stream in (("s1", 1), ("s1again", 1), ("s0", 0)):
        out = tmp_path / name
        evaluate(out, ["IB"], [0], ("stucco",), EvalConfig(**cfg, estimator_stream=stream), jobs=1, progress=False)
        outs[name] = out
    seg = {k: partition(o, "segments", "IB", 0, "stucco").read_bytes() for k, o in outs.items()}
    assert seg["s1"] == seg["s0"]
    cand = {k: read_kind(o, "candidates").drop_columns(["estimator"]) for k, o in outs.items()}
    assert cand["s1"].equals(cand["s1again"])
    assert not cand["s1"].equals(cand["s0"])
    assert json.loads((outs["s1"] / "evaluation.json").read_text())["estimator_stream"] == 1
    # report.csv says which stream made it, so reports of several streams can be concatenated.
    streams = {k: {r["estimator_stream"] for r in csv.DictReader(io.StringIO((o / "report.csv").read_text()))}
               for k, o in outs.items()}
    assert streams == {"s1": {"1"}, "s1again": {"1"}, "s0": {"0"}}
    meta = schema.read_metadata(partition(outs["s1"], "retrieval", "IB", 0, "stucco", "pushtrack"))["params"]
    assert meta["stream"] == 1
    meta0 = schema.read_metadata(partition(outs["s0"], "retrieval", "IB", 0, "stucco", "pushtrack"))["params"]
    assert "stream" not in meta0
    assert "random stream 1 (--estimator-stream" in (outs["s1"] / "report.md").read_text()
    assert "random stream" not in (outs["s0"] / "report.md").read_text()
    # From the CLI: the stream-1 folder resumes with stream 1 (nothing to do) and refuses the default stream.
    from stucco_cli.main import cli

    args = ["--seed", "0", "evaluate", "--from-runs", str(runs), "--methods", "stucco", "--estimators", "pushtrack",
            "--restarts", "5", "--no-figures", "--out", str(outs["s1"])]
    res = CliRunner().invoke(cli, args + ["--estimator-stream", "1"])
    assert res.exit_code == 0, res.output
    assert "1 job(s): 0 run, 1 already done" in res.stderr and "random stream 1 (--estimator-stream" in res.stdout
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 1
    assert "was made with estimator_stream=1, this evaluation asks for estimator_stream=0" in res.output
    assert "Traceback" not in res.output


# --- One pass through a job: each input hashed once, the stale stages and paths handed on, times in memory -------

def _count_digests(monkeypatch) -> dict[Path, int]:
    """Count every digest the evaluation takes to decide what is stale, per file (the stages' own checks inside
    their ``<stage>_file`` functions, the same as on the command line, are not the evaluation's)."""
    from pipeline.evaluate import freshness

    calls: dict[Path, int] = {}
    real = freshness.file_digest

    def counting(path):
        calls[Path(path)] = calls.get(Path(path), 0) + 1
        return real(path)

    monkeypatch.setattr(freshness, "file_digest", counting)
    return calls


def _inputs_of_every_job(out: Path) -> set[Path]:
    """Every file some stage of the module's grid records as an input (StageSpec.inputs)."""
    files = set()
    for m in METHODS:
        paths = job_paths(out, Job("IB", 0, m), registry.estimator_names())
        for spec in STAGE_SPECS:
            for est in paths.estimators:
                files |= set(paths.inputs(spec, est).values())
    return files


def test_a_resumed_evaluation_with_nothing_stale_hashes_each_input_once_and_runs_no_stage(copy, monkeypatch):
    from pipeline.evaluate import jobs as jobs_module

    def refuse(*args, **kwargs):
        raise AssertionError("no stage may run")

    for name in ("run_collect", "run_isolate", "run_track", "run_segment", "run_retrieve", "run_score"):
        monkeypatch.setattr(jobs_module, name, refuse)
    calls = _count_digests(monkeypatch)
    every = {}  # every SHA-256 taken by anyone: with no stage run, only the freshness check's
    real = schema.file_digest
    monkeypatch.setattr(schema, "file_digest", lambda p: every.setdefault(Path(p), []).append(1) or real(p))
    ev = _run(copy)
    assert [r.ran for r in ev.results] == [(), ()] and ev.prepared == []
    assert {p: len(v) for p, v in every.items()} == calls
    # runs, contacts; per method tracks, segments, diagnostics; per method and estimator retrieval: once each
    assert set(calls) == _inputs_of_every_job(copy)
    assert len(calls) == 2 + 3 * len(METHODS) + len(METHODS) * len(registry.estimator_names())
    assert set(calls.values()) == {1}, calls


def test_each_input_of_a_job_is_hashed_once_per_evaluation_call(copy, monkeypatch):
    # One job resumes from retrieve (its retrieval deleted), the other is finished: the check of both, the
    # preparation and the job itself hash each input at most once in all.
    partition(copy, "retrieval", "IB", 0, "stucco").unlink()
    calls = _count_digests(monkeypatch)
    ev = _run(copy)
    assert {r.job.method: r.ran for r in ev.results} == {"stucco": ("retrieve", "score"), "gmphd": ()}
    assert max(calls.values()) == 1, calls
    assert partition(copy, "contacts", "IB", 0) in calls and partition(copy, "runs", "IB", 0) in calls


def test_a_fresh_evaluation_hashes_each_input_at_most_once(tmp_path, monkeypatch):
    calls = _count_digests(monkeypatch)
    cfg = EvalConfig(root_seed=0, max_actions=6, restarts=2, estimators=("plausible",), grasp=False)
    evaluate(tmp_path / "ev", ["IB"], [0], ("gmphd",), cfg, jobs=1, progress=True, figures=False)
    assert not calls or max(calls.values()) == 1, calls


def test_a_partly_rerun_job_keeps_the_stored_times_of_the_stages_it_skips(copy):
    def times(out):
        return {(r["method"], r["estimator"]): {c: r[c] for c in STAGE_COLUMNS}
                for r in read_kind(out, "scores").to_pylist()}

    before = times(copy)
    partition(copy, "retrieval", "IB", 0, "stucco").unlink()  # the default estimator's
    ev = _run(copy)
    after = times(copy)
    (stucco,) = [r for r in ev.results if r.job.method == "stucco"]
    for est in registry.estimator_names():
        # what the job returned in memory is what its scores hold
        assert {f"stage_{s}_s": v for s, v in stucco.stage_s[est].items()} == after[("stucco", est)]
        for stage in ("collect", "isolate", "track", "segment"):  # not rerun: the stored times
            c = f"stage_{stage}_s"
            assert after[("stucco", est)][c] == before[("stucco", est)][c], (est, c)
        assert after[("stucco", est)]["stage_score_s"] != before[("stucco", est)]["stage_score_s"]
    assert {k: v for k, v in after.items() if k[0] == "gmphd"} == {k: v for k, v in before.items() if k[0] == "gmphd"}


def test_a_method_added_to_the_grid_books_the_stored_times_of_its_seeds_shared_stages(copy):
    ev = evaluate(copy, ["IB"], [0], (*METHODS, "dbscan"), CFG, jobs=1, progress=True, figures=False)
    assert {r.job.method: r.ran for r in ev.results} == {"stucco": (), "gmphd": (), "dbscan": STAGES[2:]}
    rows = {(r["method"], r["estimator"]): r for r in read_kind(copy, "scores").to_pylist()}
    for est in registry.estimator_names():
        for c in ("stage_collect_s", "stage_isolate_s"):  # collected and isolated once, for every method
            assert rows[("dbscan", est)][c] == rows[("stucco", est)][c] is not None


def test_no_side_file_is_written_beside_the_tables(evaluated):
    for kind in KINDS:
        others = [p for p in (evaluated / kind).rglob("*") if p.is_file() and p.suffix != ".parquet"]
        assert not others, others


def test_a_folder_of_layout_2_is_migrated_in_place_and_resumes(copy):
    from pipeline.layout import LAYOUT_VERSION

    config = json.loads((copy / "evaluation.json").read_text())
    (copy / "evaluation.json").write_text(json.dumps(dict(config, layout=2)))
    hive = partition(copy, "tracks", "IB", 0, "stucco").parent / "_wall_s.json"
    flat = copy / "scores" / "_wall_s" / "IB-000-stucco-plausible.json"
    flat.parent.mkdir()
    for p in (hive, flat):
        p.write_text('{"wall_s": 1.0}')
    old_side = copy / "runs" / "IB-000.probe_s.json"
    old_side.write_text('{"decision_s": [0.5], "prior_s": 0.25}')
    before = _mtimes(copy)
    ev = _run(copy)
    assert [r.ran for r in ev.results] == [(), ()] and _mtimes(copy) == before
    assert not hive.exists() and not flat.parent.exists() and not old_side.exists()
    assert registry.side_path(partition(copy, "runs", "IB", 0), ".probe_s.json").read_text().startswith('{"decision')
    assert json.loads((copy / "evaluation.json").read_text()) == dict(config, layout=LAYOUT_VERSION)


def test_stage_specs_declare_every_kind_once_and_inputs_made_before(tmp_path):
    made: list[str] = []
    for spec in STAGE_SPECS:
        assert all(kind in made for _, kind in spec.inputs) and all(k in made for k in spec.reads), spec.name
        made += spec.outputs
    assert sorted(made) == sorted(KINDS) and tuple(s.name for s in STAGE_SPECS) == STAGES
    paths = job_paths(tmp_path, Job("FB", 3, "kmeans"), ("plausible", "paper"))
    assert paths.of("scores", "paper") == partition(tmp_path, "scores", "FB", 3, "kmeans", "paper")
    assert paths["tracks"] == partition(tmp_path, "tracks", "FB", 3, "kmeans")
    assert paths.inputs(STAGE_SPECS[1]) == {"FB-003": partition(tmp_path, "runs", "FB", 3)}
    assert pickle.loads(pickle.dumps(paths)) == paths  # handed to worker processes
    assert paths.inputs(STAGE_SPECS[5], "paper") == {
        "retrieval": partition(tmp_path, "retrieval", "FB", 3, "kmeans", "paper"),
        "segments": paths["segments"], "diagnostics": paths["diagnostics"]}
