"""``stucco bench track --reference-python``: the authors' harness is run on the stream our replay uses, also for a
contact count the harness has no stream file for (T=300, cut from T=400 as the harness cuts its own).

The harness here is a stand-in with the real one's interface (``--worker --T --N --seed --budget``, the stream read
from ``stream_T{T}.npz`` beside the script, one JSON line out): no torch needed."""
from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from pipeline.studies.anchors import ANCHOR_DIR, load_contacts_stream
from pipeline.studies.trackers import REFERENCE_BUDGET_S, WorkerError, run_reference_worker

STAND_IN = '''
import argparse, json, os
import numpy as np
a = argparse.ArgumentParser()
for k in ("--T", "--N", "--seed"):
    a.add_argument(k, type=int)
a.add_argument("--budget", type=float)
a.add_argument("--worker", action="store_true")
args = a.parse_args()
here = os.path.dirname(os.path.abspath(__file__))
with np.load(os.path.join(here, f"stream_T{args.T}.npz")) as z:
    s = {k: z[k] for k in z.files}
with open(os.environ["STAND_IN_SAW"], "w") as f:  # what the harness was given, for the test to read
    json.dump(dict(contacts=int(s["in_contact"].sum()), steps=len(s["x"]), x_sum=float(s["x"].sum()), here=here,
              budget=args.budget), f)
print(json.dumps(dict(total_s=1.0, mean_ms_contact=2.0, last10pct_contact_ms=3.0, rss_peak_mb=4.0)))
'''


@pytest.fixture
def harness(tmp_path):
    """A harness folder with the stand-in script and the T=400 stream only."""
    folder = tmp_path / "anchors"
    folder.mkdir()
    (folder / "ref_tracker_bench.py").write_text(STAND_IN)
    np.savez(folder / "stream_T400.npz", **load_contacts_stream(400, ANCHOR_DIR))
    return folder / "ref_tracker_bench.py"


def _run(harness, T, monkeypatch, **kwargs):
    saw = harness.parent.parent / "saw.json"
    monkeypatch.setenv("STAND_IN_SAW", str(saw))
    r = run_reference_worker(T, 100, sys.executable, harness, streams=ANCHOR_DIR, **kwargs)
    return r, json.loads(saw.read_text())


def test_a_count_the_harness_has_no_file_for_runs_on_our_cut_of_the_longer_stream(harness, monkeypatch):
    r, seen = _run(harness, 300, monkeypatch)
    ours = load_contacts_stream(300, ANCHOR_DIR)
    assert seen["contacts"] == 300 and seen["steps"] == len(ours["x"]) < len(load_contacts_stream(400)["x"])
    assert seen["x_sum"] == float(ours["x"].sum())
    assert seen["here"] != str(harness.parent)  # a temporary copy of the harness, removed afterwards
    assert not list(harness.parent.glob("stream_T300.npz"))
    assert r["total_s"] == 1.0 and r["source"] == "rerun here"


def test_a_count_the_harness_has_runs_in_place(harness, monkeypatch):
    r, seen = _run(harness, 400, monkeypatch)
    assert seen["contacts"] == 400 and seen["here"] == str(harness.parent)


def test_the_harness_gets_its_default_budget_or_the_one_asked_for(harness, monkeypatch):
    assert _run(harness, 400, monkeypatch)[1]["budget"] == 180.0  # the harness's own default: N=500 is cut
    assert _run(harness, 400, monkeypatch, budget_s=900.0)[1]["budget"] == 900.0  # --reference-budget 900


def test_a_failing_harness_is_one_line_naming_the_count(harness):
    harness.write_text("raise SystemExit('no torch here')\n")
    with pytest.raises(WorkerError, match=r"T=300, N=100\) failed with exit code 1: no torch here"):
        run_reference_worker(300, 100, sys.executable, harness, streams=ANCHOR_DIR)


def test_the_clis_default_budget_is_the_harness_default():
    # The CLI keeps numpy out of its import, so it repeats the figure: the two must stay one fact.
    from stucco_cli.bench import bench_track

    option = next(p for p in bench_track.params if p.name == "reference_budget")
    assert option.default == REFERENCE_BUDGET_S
