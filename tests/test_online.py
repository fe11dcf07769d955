"""The paper's estimator run online (``--estimator paper``): ICP at every in-contact step, warm starts, the choice
redone each step, the grasp at the last in-contact step; its per-step segments from the tables; the CLI."""
from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from click.testing import CliRunner

import pipeline.estimators.paper.online as online
from pipeline.estimators.estimate import history_from_final, needs_every_step
from pipeline.estimators.paper.online import online_protocol, visited_until
from pipeline.geometry import apply_pose
from pipeline.retrieve import (
    RetrievalParams,
    Segment,
    estimate_run,
    load_run,
    min_clearance,
    model_points,
    pose_error,
    read_retrieval,
    retrieval_rng,
    target_primitive,
)
from pipeline.retrieve.stage import contact_step_segments
from pipeline.robot import load_robot
from pipeline.scenes import load_scene
from pipeline.schema import write_table

REGRESSION = Path(__file__).resolve().parents[1] / "data" / "regression" / "FB-000.parquet"
PARAMS = RetrievalParams()
TRUTH = np.array([0.28, 0.04, 0.2])
EE = np.array([[0.0, 0.1], [0.02, 0.1], [0.04, 0.1], [0.06, 0.1], [0.08, 0.1]])  # start, then after steps 0..3
STEPS = np.arange(4)


@pytest.fixture(scope="module")
def box():
    return target_primitive(load_scene("FB"))[1]


@pytest.fixture(scope="module")
def panda():
    return load_robot("panda")


def _on_box(box, every: int, seed: int = 9) -> np.ndarray:
    """Points on the box's outline at TRUTH (every ``every``-th model point)."""
    local = model_points(box, PARAMS, retrieval_rng(seed, "hard/0")[0])[::every]
    return apply_pose(TRUTH, local)


def _wall() -> np.ndarray:
    return np.column_stack([np.full(20, 1.0), np.linspace(-0.6, 0.6, 20)])


def _run(history, box, panda, seed=0):
    return online_protocol(history, box, EE, STEPS, panda, PARAMS, *retrieval_rng(seed, "online/0")[:2])


# ------------------------------------------------------------------------------------------------ pieces
def test_pruned_min_clearance_equals_every_pair(panda):
    rng = np.random.default_rng(1)
    for _ in range(50):
        model = rng.normal(0, 0.05, (30, 2))
        poses = np.column_stack([rng.uniform(-0.3, 0.3, (20, 2)), rng.uniform(-3, 3, 20)])
        ee = rng.uniform(-0.4, 0.4, (int(rng.integers(0, 40)), 2))
        world = apply_pose(poses, model)
        every = (panda.query(world[:, :, None, :] - ee[None, None]).reshape(len(world), -1).min(axis=1)
                 if len(ee) else np.full(len(poses), panda.outside_value))
        np.testing.assert_array_equal(min_clearance(panda, model, poses, ee), every)


def test_visited_positions_end_with_the_steps_action():
    np.testing.assert_array_equal(visited_until(EE, STEPS, 0), EE[:2])
    np.testing.assert_array_equal(visited_until(EE, STEPS, 3), EE)
    np.testing.assert_array_equal(visited_until(EE, STEPS, -1), EE[:1])
    # Steps with gaps (free-space steps are actions too, but a run may skip numbers): by value, not by index.
    np.testing.assert_array_equal(visited_until(EE, np.array([0, 2, 5, 9]), 5), EE[:4])


def test_only_the_estimators_that_read_every_step_ask_for_it():
    assert needs_every_step(["paper"]) and needs_every_step(["plausible", "paper"])
    assert not needs_every_step(["plausible"]) and not needs_every_step([])


# ------------------------------------------------------------------------------------------------ hard cases
def test_no_in_contact_step_gives_the_flagged_last_gripper_position(box, panda):
    est, trail = _run([], box, panda)
    assert trail == [] and est.segment == -1 and est.notes == ["no_points"]
    np.testing.assert_array_equal(est.pose, [EE[-1, 0], EE[-1, 1], 0.0])
    assert len(est.candidates["segment"]) == 0
    # A step whose segments are all empty is no step.
    est2, trail2 = _run([(2, [(0, np.zeros((0, 2)))])], box, panda)
    assert trail2 == [] and est2.notes == ["no_points"]


def test_one_in_contact_step_is_the_end_only_procedure_on_that_steps_points(box, panda):
    segs = [(1, _on_box(box, 3))]
    est, trail = _run([(1, segs)], box, panda)
    # Same draws (model points, then the restarts), no warm start, the gripper positions visited up to step 1:
    # exactly the end-only estimate of those points.
    ref = estimate_run(segs, box, EE[:3], panda, PARAMS, *retrieval_rng(0, "online/0")[:2])
    np.testing.assert_array_equal(est.pose, ref.pose)
    assert est.segment == ref.segment == 1 and est.notes == ref.notes == []
    for k, v in ref.candidates.items():
        np.testing.assert_array_equal(est.candidates[k], v, err_msg=k)
    assert len(trail) == 1 and trail[0].warm is None and trail[0].segment == 1
    assert pose_error(box, est.pose, TRUTH)[0] < 0.01
    # With a second segment, only its restart 0 differs: it starts from the first segment's best of the step.
    segs = [(0, _wall()), (1, _on_box(box, 3))]
    est = _run([(1, segs)], box, panda)[0]
    ref = estimate_run(segs, box, EE[:3], panda, PARAMS, *retrieval_rng(0, "online/0")[:2])
    same = np.ones(60, dtype=bool)
    same[30] = False
    for k in ("x_m", "y_m", "yaw_rad", "icp_rmse_m", "valid"):
        np.testing.assert_array_equal(est.candidates[k][same], ref.candidates[k][same], err_msg=k)
    assert est.segment == 1 and pose_error(box, est.pose, TRUTH)[0] < 0.01


def test_warm_start_restart_zero_starts_from_the_best_so_far(box, panda, monkeypatch):
    warms = []
    real = online.icp_segment

    def recording(points, model, normals, params, rng, warm=None):
        warms.append(None if warm is None else np.array(warm))
        return real(points, model, normals, params, rng, warm)

    monkeypatch.setattr(online, "icp_segment", recording)
    pts = _on_box(box, 3)
    est, trail = _run([(0, [(0, pts)]), (2, [(0, pts)])], box, panda)
    assert warms[0] is None and warms[1] is not None
    np.testing.assert_array_equal(trail[1].warm, warms[1])
    # Restart 0 of the second step starts at the first step's optimum of the same points and stays there.
    first = trail[0].pose
    restart0 = np.array([est.candidates[c][0] for c in ("x_m", "y_m", "yaw_rad")])
    assert pose_error(box, restart0, first)[0] < 1e-6 and pose_error(box, restart0, first)[1] < 1e-6
    assert est.candidates["valid"][0]


def test_segment_choice_changes_between_steps_and_warm_start_follows_it(box, panda, monkeypatch):
    warms = []
    real = online.icp_segment

    def recording(points, model, normals, params, rng, warm=None):
        res = real(points, model, normals, params, rng, warm)
        warms.append((None if warm is None else np.array(warm), res))
        return res

    monkeypatch.setattr(online, "icp_segment", recording)
    # Step 0 sees only the wall; step 3 sees the wall and the box: the choice moves to the box, and the grasp
    # goes to step 3's estimate (the box), not to anything fitted earlier.
    est, trail = _run([(0, [(0, _wall())]), (3, [(0, _wall()), (1, _on_box(box, 2))])], box, panda)
    assert [t.segment for t in trail] == [0, 1]
    assert est.segment == 1 and pose_error(box, est.pose, TRUTH)[0] < 0.01
    assert "poor_fit" not in est.notes
    # Inside step 3 the authors' best_tsf_guess moves with the segment loop: the box's restart 0 starts from the
    # wall's best of that same step, the wall's from step 0's choice.
    (w0, r0), (w1, r1), (w2, _) = warms
    assert w0 is None
    np.testing.assert_array_equal(w1, r0.world_to_model[trail[0].restart])
    assert any(np.array_equal(w2, t) for t in r1.world_to_model)  # one of step 3's wall fits
    assert trail[1].warm is w1 or np.array_equal(trail[1].warm, w1)


def test_a_far_segment_chosen_early_does_not_stick(box, panda):
    # The box alone first, then a wall appears beside it: the box stays chosen (lowest variance, fit gate).
    est, trail = _run([(1, [(0, _on_box(box, 3))]), (2, [(0, _on_box(box, 2)), (1, _wall())])], box, panda)
    assert [t.segment for t in trail] == [0, 0] and est.segment == 0 and est.n_segments == 2
    # The last step's candidates hold every segment with its penetration.
    assert sorted(set(est.candidates["segment"].tolist())) == [0, 1]
    assert np.all(np.isfinite(est.candidates["penetration_m"]))


# ------------------------------------------------------------------------------------------------ tables
def _table(rows) -> pa.Table:
    """A segments table from (estimate_step, step, x, y, segment) rows of run R/0."""
    est, step, x, y, seg = (np.array(c) for c in zip(*rows))
    ci = np.zeros(len(rows), np.int64)
    for i in range(1, len(rows)):  # contact_index counts the rows of one (estimate_step, step)
        if est[i] == est[i - 1] and step[i] == step[i - 1]:
            ci[i] = ci[i - 1] + 1
    return pa.table({"run": pa.array(["R/0"] * len(rows)), "step": pa.array(step, pa.int64()),
                     "contact_index": pa.array(ci), "estimate_step": pa.array(est, pa.int64()),
                     "x_m": pa.array(x, pa.float64()), "y_m": pa.array(y, pa.float64()),
                     "tracker_label": pa.array(np.maximum(seg, 0), pa.int64()), "segment": pa.array(seg, pa.int64())})


def test_contact_step_segments_keep_only_the_estimates_after_a_contact():
    rows = [(2, 2, 0.0, 0.0, 0),                                 # step 2: first contact
            (3, 2, 0.01, 0.0, 0),                                # step 3: free space, the point moved
            (4, 2, 0.01, 0.0, 0), (4, 4, 0.5, 0.5, 1), (4, 4, 0.6, 0.5, -1),  # step 4: two contacts
            (5, 2, 0.02, 0.0, 0), (5, 4, 0.5, 0.5, 1), (5, 4, 0.6, 0.5, -1)]  # step 5: free space
    hist = contact_step_segments(_table(rows))["R/0"]
    assert [k for k, _ in hist] == [2, 4]
    assert [s.id for s in hist[0][1]] == [0] and [s.id for s in hist[1][1]] == [0, 1]  # segment -1 left out
    np.testing.assert_array_equal(hist[1][1][0].points, [[0.01, 0.0]])
    np.testing.assert_array_equal(hist[1][1][1].steps, [4])


def test_history_from_final_grows_the_segments_by_observation_step():
    segs = [Segment(0, np.array([[0.0, 0.0], [1.0, 0.0]]), np.array([1, 5])), Segment(3, np.array([[2.0, 2.0]]),
                                                                                      np.array([4]))]
    hist = history_from_final(segs)
    assert [k for k, _ in hist] == [1, 4, 5]
    assert [s.id for s in hist[0][1]] == [0] and [len(s.points) for s in hist[1][1]] == [1, 1]
    assert [len(s.points) for s in hist[2][1]] == [2, 1]
    assert history_from_final([]) == []


# ------------------------------------------------------------------------------------------------ CLI
def _invoke(args):
    import stucco_cli.retrieve  # noqa: F401  (registers the commands)
    from stucco_cli.main import cli

    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.fixture()
def fb_inputs(tmp_path):
    runs = tmp_path / "runs"
    runs.mkdir()
    shutil.copy(REGRESSION, runs / REGRESSION.name)
    return tmp_path, runs, load_run(REGRESSION)


def test_cli_paper_refuses_final_only_segments_in_one_line(fb_inputs):
    tmp, runs, info = fb_inputs
    seg = tmp / "final.parquet"
    write_table(_table([(5, 2, 0.3, 0.05, 0)]).replace_schema_metadata(None).set_column(
        0, "run", pa.array([info.run])), seg, stage="segment", params={"method": "stucco"}, seed=0, kind="segments")
    out = tmp / "r.parquet"
    r = _invoke(["-q", "retrieve", "--segments", seg, "--runs", runs, "--out", out, "--no-grasp",
                 "--estimator", "paper"])
    assert r.exit_code == 1 and isinstance(r.exception, SystemExit)
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and "final.parquet" in lines[0] and "--every-step" in lines[0]
    assert not out.exists() and not (tmp / "r.candidates.parquet").exists()


def test_cli_paper_grasps_at_the_last_in_contact_steps_estimate(fb_inputs, box, panda):
    tmp, runs, info = fb_inputs
    wall, near = _wall(), _on_box(box, 3)
    # Step 3 touched the box (its points), steps 4 and 5 were free space, and by step 5 the tracker had moved
    # them 20 cm: the online estimator grasps at step 3's estimate and never fits the moved points.
    rows = [(3, 3, *p, 1) for p in near] + [(3, 1, *p, 0) for p in wall[:1]]
    rows = sorted(rows, key=lambda r: (r[0], r[1]))
    later = [(k, s, x + 0.2, y, g) for k in (4, 5) for (_, s, x, y, g) in rows]
    seg = tmp / "every.parquet"
    write_table(_table(rows + later).set_column(0, "run", pa.array([info.run] * (len(rows) + len(later)))), seg,
                stage="segment", params={"method": "stucco", "every_step": True}, seed=0, kind="segments")
    out = tmp / "r.parquet"
    r = _invoke(["-q", "--seed", "0", "retrieve", "--segments", seg, "--runs", runs, "--out", out, "--no-grasp",
                 "--estimator", "paper"])
    assert r.exit_code == 0, r.output
    row = read_retrieval(out).to_pylist()[0]
    ref, trail = online_protocol([(3, [(0, wall[:1]), (1, near)])], info.target, info.ee, info.steps, panda,
                                 PARAMS, *retrieval_rng(0, info.run)[:2])
    assert (row["x_m"], row["y_m"], row["yaw_rad"]) == tuple(float(v) for v in ref.pose)
    assert [t.step for t in trail] == [3]
    assert row["segment"] == 1 and row["estimator"] == "paper" and row["n_segments"] == 2
    assert math.hypot(row["x_m"] - TRUTH[0], row["y_m"] - TRUTH[1]) < 0.05
