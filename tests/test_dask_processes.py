"""`stucco evaluate --backend dask` against a scheduler and a worker started the way a user starts them.

``dask scheduler`` and ``dask worker`` run as separate processes on localhost; ``stucco evaluate`` runs as a third
process and sends its jobs to them. The scores must equal those of a local (loky) run of the same jobs, which the
regression snapshot holds: where a job runs changes nothing but the timings (docs/studies.md, "Beyond one
machine").
"""
from __future__ import annotations

import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from pipeline import registry

pytest.importorskip("distributed")

REGRESSION = Path(__file__).resolve().parents[1] / "data" / "regression"
BIN = Path(sys.executable).parent
COMPARED = ["scene", "seed", "method", "estimator", "run", "grasp_success", "fmi", "contact_error_cm",
            "position_error_cm", "yaw_error_rad", "low_confidence", "n_points", "n_segments"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _scores(out: Path):
    rows = []
    for f in sorted((out / "scores").glob("*.parquet")):
        rows += pq.read_table(f, columns=COMPARED).to_pylist()
    return sorted(rows, key=lambda r: (r["scene"], r["seed"], r["method"], r["estimator"]))


def _evaluate(out: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / "stucco"), "-q", "evaluate", "--from-runs", str(REGRESSION), "--scenes", "FB",
                           "--seeds", "0", "--methods", "stucco,dbscan", "--no-figures", "--out", str(out), *extra],
                          capture_output=True, text=True, timeout=600)


@pytest.mark.skipif(shutil.which("dask", path=str(BIN)) is None, reason="the dask command is not installed")
def test_scheduler_and_worker_processes_give_the_local_results(tmp_path):
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    logs = open(tmp_path / "dask.log", "w")
    procs = [subprocess.Popen([str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", str(port),
                               "--no-dashboard"], stdout=logs, stderr=logs)]
    try:
        procs.append(subprocess.Popen([str(BIN / "dask"), "worker", address, "--nworkers", "1", "--nthreads", "1",
                                       "--no-dashboard", "--memory-limit", "0"], stdout=logs, stderr=logs,
                                      cwd=tmp_path))
        from distributed import Client

        with Client(address, timeout=60) as client:
            client.wait_for_workers(1, timeout=120)
        remote = _evaluate(tmp_path / "dask", "--backend", "dask", "--scheduler", address)
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
        logs.close()
    assert remote.returncode == 0, remote.stderr[-2000:]
    # The local results of the same jobs are the regression snapshot (tests/test_regression.py replays them with
    # loky and compares exactly), so they need no second evaluation here.
    expected = pq.read_table(REGRESSION / "expected" / "scores.parquet", columns=COMPARED).to_pylist()
    want = sorted((r for r in expected if r["scene"] == "FB" and r["method"] in ("stucco", "dbscan")),
                  key=lambda r: (r["scene"], r["seed"], r["method"], r["estimator"]))
    got = _scores(tmp_path / "dask")
    assert len(got) == len(want) == 2 * len(registry.estimator_names())  # two methods x every pose estimator
    for g, w in zip(got, want):  # exactly: every stage computes the same bits in any process (docs/evaluation.md)
        for c in COMPARED:
            assert g[c] == w[c], (c, g, w)
