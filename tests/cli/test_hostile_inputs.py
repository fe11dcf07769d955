"""Nothing believed that was not checked: hostile inputs through the CLI end in one line naming the file, never a
hang or a traceback.

* every reader refuses a FIFO (or device, directory, dangling link) in place of its file
  (:mod:`pipeline.safe_open`): Parquet tables, scene files, ``evaluation.json``, the folder's lock, a policy's
  side file, the anchor streams; a blocked reader is unblocked by the test (the FIFO's write end opened and
  closed) so a failure cannot hang the suite;
* the probing policy's times side file and log (``params.probe``) have a declared shape, checked on read;
* a run's ``probe`` column agrees with its policy and log, its ``run``/``scene``/``seed`` with one another and
  with the metadata; positions in cm are refused;
* ``evaluate`` compares its provenance on resume (a stored run collected again, a deleted ``evaluation.json``,
  a run of another seed in its folder).
"""
from __future__ import annotations

import json
import os
import shutil
import threading
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pytest

from pipeline import schema
from pipeline.layout import LOCK
from pipeline.probe.report import read_times, times_path
from tests.cli.stages import as_probe_run, invoke

REG = Path(__file__).resolve().parents[2] / "data" / "regression"
TINY = ("--methods", "stucco", "--restarts", "2", "--no-figures", "-j", "1")


def one_line_error(res, *needles) -> str:
    assert res.exit_code not in (0, None), res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: ") and "Traceback" not in res.stderr, res.stderr
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


def invoke_with_fifo(fifo: Path, *args, timeout: float = 120.0):
    """``stucco ARGS`` in a thread; a reader blocked on ``fifo`` past ``timeout`` is released (the FIFO's write
    end opened and closed) and the test fails."""
    out: dict = {}
    t = threading.Thread(target=lambda: out.setdefault("res", invoke(*args)), daemon=True)
    t.start()
    t.join(timeout)
    if t.is_alive():
        try:
            os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        except OSError:
            pass
        t.join(10)
        pytest.fail(f"stucco {' '.join(map(str, args))} blocked on the FIFO {fifo}")
    return out["res"]


def _fifo(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    os.mkfifo(path)
    return path


# -- 1. regular files only -------------------------------------------------------------------------------------


def test_a_fifo_for_a_parquet_table_is_refused_in_one_line(tmp_path):
    fifo = _fifo(tmp_path / "runs" / "FB-000.parquet")
    res = invoke_with_fifo(fifo, "isolate", "--in", fifo, "--out", tmp_path / "c.parquet")
    one_line_error(res, str(fifo), "FIFO")


def test_a_fifo_for_a_scene_file_is_refused_in_one_line(tmp_path):
    fifo = _fifo(tmp_path / "mine.toml")
    res = invoke_with_fifo(fifo, "collect", "--scene", fifo, "--out", tmp_path / "runs")
    one_line_error(res, str(fifo), "FIFO")


def test_a_fifo_for_evaluation_json_is_refused_in_one_line(tmp_path):
    fifo = _fifo(tmp_path / "ev" / "evaluation.json")
    res = invoke_with_fifo(fifo, "evaluate", "--scenes", "FB", "--seeds", "0", "--max-actions", "4", *TINY,
                           "--out", tmp_path / "ev")
    one_line_error(res, str(fifo), "FIFO")


def test_a_fifo_for_the_lock_file_is_refused_in_one_line(tmp_path):
    fifo = _fifo(tmp_path / "ev" / LOCK)
    res = invoke_with_fifo(fifo, "evaluate", "--scenes", "FB", "--seeds", "0", "--max-actions", "4", *TINY,
                           "--out", tmp_path / "ev")
    one_line_error(res, str(fifo), "not a regular file")


def test_a_fifo_for_a_stored_runs_side_file_is_refused_in_one_line(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    shutil.copyfile(REG / "FB-000.parquet", src / "FB-000.parquet")
    fifo = _fifo(times_path(src / "FB-000.parquet"))
    res = invoke_with_fifo(fifo, "evaluate", "--from-runs", src, *TINY, "--out", tmp_path / "ev")
    one_line_error(res, str(fifo), "FIFO")
    assert not (tmp_path / "ev" / "runs").exists()  # refused before any job


def test_a_fifo_for_an_anchor_stream_is_refused_in_one_line(tmp_path):
    fifo = _fifo(tmp_path / "streams" / "stream_T50.npz")
    res = invoke_with_fifo(fifo, "bench", "track", "--streams", fifo.parent, "--T", "50", "--N", "100",
                           "--repeats", "1", "--accuracy-seeds", "0")
    one_line_error(res, str(fifo), "FIFO")


def test_a_dangling_link_and_a_directory_are_named_for_what_they_are(tmp_path):
    (tmp_path / "gone.parquet").symlink_to(tmp_path / "nowhere.parquet")
    one_line_error(invoke("isolate", "--in", tmp_path / "gone.parquet", "--out", tmp_path / "c.parquet"),
                   "gone.parquet")
    (tmp_path / "d.toml").mkdir()
    one_line_error(invoke("collect", "--scene", tmp_path / "d.toml", "--out", tmp_path / "runs"), "d.toml",
                   "directory")


# -- 2. the side file's and the probe log's shapes -------------------------------------------------------------


@pytest.mark.parametrize("text, key", [('{"decision_s": 5}', "decision_s"),
                                       ('{"decision_s": [NaN], "prior_s": 0.1}', "decision_s"),
                                       ('{"decision_s": [Infinity]}', "decision_s"),
                                       ('{"decision_s": [0.1, -2.0]}', "decision_s"),
                                       ('{"decision_s": [0.1], "prior_s": -1}', "prior_s"),
                                       ('{"decision_s": [0.1], "prior": 1}', "expected"), ("[1, 2", "not JSON")])
def test_a_side_file_of_another_shape_is_refused_naming_the_file_and_key(tmp_path, text, key):
    run = tmp_path / "FB-000.parquet"
    shutil.copyfile(REG / "FB-000.parquet", run)
    times_path(run).write_text(text)
    with pytest.raises(ValueError, match=key) as e:
        read_times(run)
    assert str(times_path(run)) in str(e.value) and "\n" not in str(e.value)


def test_a_bad_side_file_of_a_stored_run_is_refused_before_any_job(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    shutil.copyfile(REG / "FB-000.parquet", src / "FB-000.parquet")
    times_path(src / "FB-000.parquet").write_text('{"decision_s": 5}')
    one_line_error(invoke("evaluate", "--from-runs", src, *TINY, "--out", tmp_path / "ev"), "_FB-000.probe_s.json",
                   "decision_s")
    assert not (tmp_path / "ev" / "runs").exists()


def test_a_consistent_probe_run_is_read(tmp_path):
    run = as_probe_run(REG / "FB-000.parquet", tmp_path / "runs" / "FB-000.parquet")
    assert schema.probe_record(run)["actions"] == 3


@pytest.mark.parametrize("edit, needles", [
    (dict(drop_column=True), ("column 'probe'", "missing")),
    (dict(record={"probes": -3}), ("stucco.params.probe.probes", "-3")),
    (dict(record={"probes": 1e300}), ("stucco.params.probe.probes",)),
    (dict(record={"history": []}), ("stucco.params.probe.history", "probes + 1")),
    (dict(record={"history": "x"}), ("stucco.params.probe.history",)),
    (dict(record={"history": [{"rows": 10**9, "share": 0.5, "target_steps": []}]}), ("history[0].rows",)),
    (dict(record={"actions": 7}), ("stucco.params.probe.actions",)),
    (dict(record={"target_steps": [10**6]}), ("stucco.params.probe.target_steps",)),
    (dict(columns={"seed": lambda c: pc.add(c, 1)}), ("column 'seed'", "run_seed")),
    (dict(columns={"run": lambda c: pa.array(["FB/7"] * len(c))}), ("column 'run'", "FB/0")),
])
def test_a_run_whose_rows_and_metadata_disagree_is_refused_in_one_line(tmp_path, edit, needles):
    run = as_probe_run(REG / "FB-000.parquet", tmp_path / "runs" / "FB-000.parquet", **edit)
    one_line_error(invoke("isolate", "--in", run, "--out", tmp_path / "c.parquet"), str(run), *needles)


def test_a_scripted_run_with_probe_rows_is_refused(tmp_path):
    t = schema.read_run(REG / "FB-000.parquet")
    meta = schema.read_metadata(REG / "FB-000.parquet")
    t = t.append_column("probe", pa.array([True] * t.num_rows, pa.bool_()))
    run = schema.write_table(t, tmp_path / "FB-000.parquet", stage="collect", params=meta["params"],
                             seed=meta["seed"], kind="sim_run")
    one_line_error(invoke("isolate", "--in", run, "--out", tmp_path / "c.parquet"), "column 'probe'", "scripted")


# -- 4. units by plausibility ----------------------------------------------------------------------------------


def _in_cm(table: pa.Table, names) -> pa.Table:
    for name in names:
        table = table.set_column(table.column_names.index(name), name, pc.multiply(table.column(name), 100.0))
    return table


def test_a_run_file_in_cm_is_refused_naming_the_file_and_column(tmp_path):
    meta = schema.read_metadata(REG / "FB-000.parquet")
    t = _in_cm(pa.Table.from_batches(schema.read_parquet(REG / "FB-000.parquet").to_batches()),
               ["ee_start_x_m", "ee_start_y_m", "ee_x_m", "ee_y_m"])
    run = tmp_path / "FB-000.parquet"
    import pyarrow.parquet as pq

    pq.write_table(t.replace_schema_metadata({f"stucco.{k}": (v if isinstance(v, str) else json.dumps(v))
                                              for k, v in meta.items()}), run)
    line = one_line_error(invoke("isolate", "--in", run, "--out", tmp_path / "c.parquet"), str(run), "ee_")
    assert "cm" in line


def test_segments_in_cm_are_refused_naming_the_file_and_column(stages, tmp_path):
    d, _ = stages
    import pyarrow.parquet as pq

    seg = tmp_path / "segments.parquet"
    pq.write_table(_in_cm(pq.read_table(d / "segments.parquet"), ["x_m", "y_m"]), seg)
    line = one_line_error(invoke("retrieve", "--segments", seg, "--runs", d / "runs", "--out",
                                 tmp_path / "r.parquet"), str(seg), "x_m")
    assert "cm" in line


# -- 6. provenance compared on resume --------------------------------------------------------------------------


def test_evaluate_compares_its_sources_and_its_record_on_resume(tmp_path):
    src, ev = tmp_path / "src", tmp_path / "ev"
    collect = ("collect", "--scene", "FB", "--out", src, "--force-overwrite")
    assert invoke(*collect, "--seeds", "0-1", "--max-actions", "6").exit_code == 0
    run = ("evaluate", "--from-runs", src, "--seeds", "0", *TINY, "--out", ev)
    assert "1 run, 0 already done" in invoke(*run).stderr
    assert "0 run, 1 already done" in invoke(*run).stderr
    # the stored run collected again (longer): copied again and its job rerun, not the old results kept
    assert invoke(*collect, "--seeds", "0", "--max-actions", "8").exit_code == 0
    assert "1 run, 0 already done" in invoke(*run).stderr
    assert schema.read_run(ev / "runs" / "FB-000.parquet").num_rows == 8
    # a run of another seed in the folder is not scored as this seed
    kept = (ev / "runs" / "FB-000.parquet").read_bytes()
    shutil.copyfile(src / "FB-001.parquet", ev / "runs" / "FB-000.parquet")
    one_line_error(invoke(*run), "FB-000.parquet", "FB/1, not FB/0")
    (ev / "runs" / "FB-000.parquet").write_bytes(kept)
    # a deleted evaluation.json is refused, not stamped with this call's settings over the results
    (ev / "evaluation.json").unlink()
    one_line_error(invoke("evaluate", "--from-runs", src, "--seeds", "0", "--methods", "stucco", "--restarts", "5",
                          "--no-figures", "-j", "1", "--out", ev), "evaluation.json", "missing")
    assert not (ev / "evaluation.json").exists()


# -- 8. outputs that belong together ---------------------------------------------------------------------------


def test_a_group_of_writes_appears_all_together_or_not_at_all(tmp_path):
    from pipeline.atomic import together, write_text

    with together():
        write_text(tmp_path / "a.md", "a")
        assert not (tmp_path / "a.md").exists()  # renamed only at the end of the group
        write_text(tmp_path / "b.csv", "b")
    assert (tmp_path / "a.md").read_text() == "a" and (tmp_path / "b.csv").read_text() == "b"
    with pytest.raises(OSError), together():
        write_text(tmp_path / "a.md", "new a")
        raise OSError(28, "No space left on device")
    assert (tmp_path / "a.md").read_text() == "a" and sorted(p.name for p in tmp_path.iterdir()) == ["a.md", "b.csv"]


def test_a_report_that_fails_halfway_leaves_neither_file(tmp_path, monkeypatch):
    import pipeline.evaluate.results as results

    def full(path, text):  # report.md written, then the disk is full
        if Path(path).name == "report.csv":
            raise OSError(28, "No space left on device", str(path))
        return write_text(path, text)

    write_text = results.write_text
    monkeypatch.setattr(results, "write_text", full)
    ev = tmp_path / "ev"
    res = invoke("evaluate", "--scenes", "FB", "--seeds", "0", "--max-actions", "4", *TINY, "--out", ev)
    one_line_error(res, "No space left on device")
    assert not (ev / "report.md").exists() and not (ev / "report.csv").exists()
    assert not [p for p in ev.iterdir() if p.name.endswith(".tmp")]


# -- 9. lower ----------------------------------------------------------------------------------------------------


def test_an_error_names_the_file_not_its_hidden_temporary(tmp_path):
    from pipeline.atomic import atomic_path

    with pytest.raises(OSError) as e, atomic_path(tmp_path / "_FB-000.wall_s.json") as tmp:
        raise FileNotFoundError(2, "No such file or directory", str(tmp))
    assert e.value.filename == str(tmp_path / "_FB-000.wall_s.json") and ".tmp" not in str(e.value)


@pytest.mark.parametrize("option", [("--restarts", "5"), ("--no-figures",), ("--policy", "scripted"),
                                    ("--estimators", "plausible")])
def test_suite_training_refuses_the_options_it_would_drop(tmp_path, option):
    res = invoke("evaluate", "--suite", "training", *option, "--out", tmp_path / "t")
    assert res.exit_code == 2 and option[0].lstrip("-").split("/")[0] in res.stderr
    assert "does not apply to --suite training" in res.stderr


def test_collect_noise_has_the_scene_files_bound(tmp_path):
    res = invoke("collect", "--scene", "FB", "--noise-mm", "1e308", "--out", tmp_path / "runs")
    assert res.exit_code == 2 and "--noise-mm" in res.stderr and "50" in res.stderr


def test_a_scene_file_of_more_actions_than_the_cap_is_refused_in_one_line(tmp_path):
    from pipeline.scenes import load_scene
    from pipeline.scenes.parse import MAX_ACTIONS

    text = load_scene("FB").source
    start = text.index("\nsequence = [") + 1
    end = text.index("\n]\n", start) + 2
    big = tmp_path / "BIG.toml"
    big.write_text(text[:start] + "sequence = [" + ", ".join(["[0.5, 0.0]"] * (MAX_ACTIONS + 1)) + "]" + text[end:])
    one_line_error(invoke("collect", "--scene", big, "--out", tmp_path / "runs"), "BIG.toml", "sequence",
                   str(MAX_ACTIONS))
