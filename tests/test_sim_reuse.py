"""pipeline.sim.world's spare clients: a world built in a client that an earlier world of another scene used (and
``resetSimulation`` emptied) simulates to the bit what a world in a fresh ``p.connect`` client simulates, for a
grasp and for a collected run (docs/experiments/reproduce-time.md)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

import pipeline.grasp as grasp_module
from pipeline.collect import collect_run
from pipeline.grasp import GraspParams, grasp_at
from pipeline.retrieve import load_run
from pipeline.scenes import load_scene
from pipeline.sim import world as world_module

REGRESSION = Path(__file__).resolve().parents[1] / "data" / "regression"


def _grasp_bits(g) -> tuple:
    return (g.success, g.outcome, g.reached, g.yaw, g.pregrasp.tobytes(), g.target_pose.tobytes(),
            tuple((f.points.tobytes(), f.normals.tobytes(), f.force) for f in g.fingers))


@pytest.fixture
def fresh_clients(monkeypatch):
    """No spare clients: every world connects a new client and disconnects it on close (the former behaviour)."""
    monkeypatch.setattr(world_module, "_MAX_SPARE", 0)
    monkeypatch.setattr(world_module, "_SPARE", [])


@pytest.fixture
def spare_clients(monkeypatch):
    monkeypatch.setattr(world_module, "_MAX_SPARE", 2)
    monkeypatch.setattr(world_module, "_SPARE", [])


def _grasps() -> list[tuple]:
    """Grasps of two stored runs, interleaved so that each client is reused across scenes: a box grasp at the
    true pose (succeeds), a can grasp at the true pose and 3 cm off across the approach, a box grasp 5 cm off in x."""
    grasp_module._MEMO.clear()
    out = []
    fb, tc = load_run(REGRESSION / "FB-000.parquet"), load_run(REGRESSION / "TC-000.parquet")
    for run, shift in ((fb, (0.0, 0.0)), (tc, (0.0, 0.0)), (tc, (0.0, 0.03)), (fb, (0.05, 0.0))):
        est = run.true_pose + np.array([shift[0], shift[1], 0.0])
        out.append(_grasp_bits(grasp_at(run.scene, run.final_poses, run.final_ee, est, GraspParams())))
    grasp_module._MEMO.clear()
    return out


def test_grasps_in_reused_clients_equal_grasps_in_fresh_clients_to_the_bit(fresh_clients, monkeypatch):
    fresh = _grasps()
    monkeypatch.setattr(world_module, "_MAX_SPARE", 2)
    reused = _grasps()
    assert world_module._SPARE  # the second pass did reuse clients
    assert reused == fresh
    assert [g[0] for g in fresh] == [True, True, False, False]  # known outcomes: not four identical failures


def _bytes(table: pa.Table) -> bytes:
    """The table's Arrow IPC bytes: equal tables, NaN included (``Table.equals`` calls NaN unequal to NaN)."""
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, table.schema) as w:
        w.write_table(table)
    return sink.getvalue().to_pybytes()


def _short_runs() -> list[bytes]:
    return [_bytes(collect_run(load_scene(name), seed, max_actions=6)[0])
            for name, seed in (("BC", 3), ("TC", 4), ("BC", 3))]


def test_collected_runs_in_reused_clients_equal_runs_in_fresh_clients(fresh_clients, monkeypatch):
    fresh = _short_runs()
    monkeypatch.setattr(world_module, "_MAX_SPARE", 2)
    reused = _short_runs()
    assert reused == fresh
    assert fresh[0] == fresh[2] and fresh[0] != fresh[1]
