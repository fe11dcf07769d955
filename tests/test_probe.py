"""Active retrieval (pipeline/probe): ray casts, outcome entropy, the stop rule, guarded moves, the set grasp's
geometric rule, and the hard cases of issue 19 (docs/active.md)."""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pipeline import schema
from pipeline.estimators.target_model import target_primitive
from pipeline.geometry import Primitive, com_pose, primitive_pose
from pipeline.grasp import plan_for
from pipeline.grasp_rule import box_success, can_success
from pipeline.probe import attribution as attribution_mod
from pipeline.probe.belief import NO_TARGET, explaining, pose_set
from pipeline.probe.planning import PlanParams, agreement, choose_probe, obstacle_travel, outcome_entropy, ray_travel
from pipeline.probe.policy import ProbeParams, guarded_move, probe_run, retrace
from pipeline.probe.set_grasp import choose_grasp
from pipeline.robot import load_robot
from pipeline.scenes import load_scene

REG = Path(__file__).resolve().parents[1] / "data" / "regression"
BOX = Primitive(kind="box", half=(0.03, 0.08), centre=np.zeros(2), yaw=0.0)
CAN = Primitive(kind="cylinder", half=(0.04,), centre=np.zeros(2), yaw=0.0)


def _primitive(kind):
    return BOX if kind == "box" else CAN


# ---------------------------------------------------------------------------------------------------------------
# Planning kernels
# ---------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind, expected", [("box", 0.97), ("cylinder", 0.96)])
def test_ray_travel_known_answers(kind, expected):
    prim = _primitive(kind)
    origins = np.array([[[-1.0, 0.0]], [[-1.0, 0.5]]])  # one outline point per line
    dirs = np.array([[1.0, 0.0], [1.0, 0.0]])
    t = ray_travel(prim, np.zeros((1, 3)), origins, dirs, max_travel=2.0)
    assert t.shape == (2, 1)
    assert t[0, 0] == pytest.approx(expected)
    assert np.isinf(t[1, 0])  # passes beside it


def test_ray_travel_is_zero_inside_and_inf_beyond_max_travel():
    t = ray_travel(BOX, np.zeros((1, 3)), np.array([[[0.0, 0.0]], [[-1.0, 0.0]]]), np.array([[1.0, 0.0]] * 2), 0.5)
    assert t[0, 0] == 0.0 and np.isinf(t[1, 0])


def test_ray_travel_turns_with_the_hypothesis():
    # A box turned by pi/2 presents its long half (0.08) toward -x.
    t = ray_travel(BOX, np.array([[0.0, 0.0, 0.0], [0.0, 0.0, np.pi / 2]]), np.array([[[-1.0, 0.0]]]),
                   np.array([[1.0, 0.0]]), 2.0)
    assert t[0] == pytest.approx([0.97, 0.92])


def test_outcome_entropy_counts_distinct_outcomes():
    travel = np.array([[0.10, 0.10, 0.10, 0.10],     # all agree: nothing to learn
                       [0.10, 0.10, 0.20, 0.20],     # two equal halves: one bit
                       [0.10, 0.20, 0.30, np.inf]])  # four outcomes (a miss is one): two bits
    ent = outcome_entropy(travel, np.full(4, 0.25), 0.008)
    assert ent == pytest.approx([0.0, 1.0, 2.0])


def test_agreement_of_a_set_of_one_pose_is_one_and_yaw_is_modulo_symmetry():
    poses = np.array([[0.1, 0.2, 0.3], [0.1, 0.2, 0.3 + np.pi]])  # the same box turned by a half turn
    assert agreement(BOX, poses, np.array([0.5, 0.5]), 0, 0.05, 0.01) == pytest.approx(1.0)
    off = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.2]])
    assert agreement(BOX, off, np.array([0.5, 0.5]), 0, 0.05, 0.01) == pytest.approx(0.5)
    assert agreement(CAN, off, np.array([0.5, 0.5]), 0, 0.05, 0.01) == pytest.approx(1.0)  # a can has no yaw


def test_obstacle_travel_stops_at_the_first_known_point():
    t = obstacle_travel(np.array([[0.5, 0.0], [0.3, 0.0]]), np.array([[[0.0, 0.0]]]), np.array([[1.0, 0.0]]),
                        0.01, 1.0)
    assert t[0] == pytest.approx(0.29)


def _outline():
    return np.array([[0.0, 0.0]])


def test_choose_probe_separates_two_yaws_and_starts_in_visited_space():
    # Two hypotheses: the box along y or turned a quarter; the probe must tell them apart.
    poses = np.array([[0.3, 0.0, 0.0], [0.3, 0.0, np.pi / 2]])
    visited = np.array([[0.0, -0.2], [0.0, -0.1], [0.0, 0.0], [0.0, 0.1], [0.0, 0.2]])
    plan = choose_probe(BOX, poses, np.array([0.5, 0.5]), 0, visited, _outline(), PlanParams())
    assert plan is not None
    assert any(np.allclose(plan.start, v) for v in visited)
    assert plan.gain > 0.5  # the two hypotheses predict different contacts (perturbed copies share the rest)
    assert plan.predicted[0] != pytest.approx(plan.predicted[1])


# ---------------------------------------------------------------------------------------------------------------
# Hard cases (issue 19)
# ---------------------------------------------------------------------------------------------------------------


def test_no_segment_fits_the_target_probe_toward_the_most_likely_region_anyway():
    sdf = load_robot("panda")
    ee = np.array([[0.0, 0.1], [0.03, 0.1], [0.06, 0.1], [0.06, 0.07]])
    s = pose_set(NO_TARGET, BOX, ee, np.arange(3), sdf, np.random.default_rng(0), np.zeros((0, 2)),
                 np.zeros(0), np.zeros((0, 2)))
    assert s.segment == -1 and s.notes == ["no_segment"]
    assert len(s.poses) > 4 and np.all(np.isfinite(s.poses)) and s.weights.sum() == pytest.approx(1.0)
    plan = choose_probe(BOX, s.poses, s.weights, s.best, ee, _outline(), PlanParams())
    assert plan is not None
    centre = BOX.centre_world(s.poses).mean(axis=0)
    assert plan.direction @ (centre - plan.start) > 0  # heads toward the prior's region


@pytest.fixture(scope="module")
def stored_run():
    path = REG / "TC-000.parquet"
    table = schema.read_run(path)
    start = np.array([table.column("ee_start_x_m")[0].as_py(), table.column("ee_start_y_m")[0].as_py()])
    return table, start, target_primitive(load_scene("TC"))[1]


def _no_act(dx, dy):
    raise AssertionError("the policy moved although it should not probe")


def test_set_of_one_pose_from_the_start_makes_no_probe(stored_run, monkeypatch):
    table, start, prim = stored_run
    monkeypatch.setattr(attribution_mod, "agreement", lambda *a, **k: 1.0)
    params = ProbeParams(min_target_contacts=0)
    log = probe_run(_no_act, lambda: table, "TC/0", 0, prim, start, params, scene=load_scene("TC"))
    assert log.probes == 0 and log.actions == 0 and log.agreed and log.flagged == ""
    assert len(log.decision_s) == 1 and log.history[0]["rows"] == table.num_rows


def test_budget_spent_with_the_set_still_wide_grasps_anyway_flagged(stored_run, monkeypatch):
    table, start, prim = stored_run
    monkeypatch.setattr(attribution_mod, "agreement", lambda *a, **k: 0.2)
    log = probe_run(_no_act, lambda: table, "TC/0", 0, prim, start, ProbeParams(budget=0), scene=load_scene("TC"))
    assert log.probes == 0 and not log.agreed and log.flagged == "budget_spent"
    # the grasp goes ahead on the wide set
    sc = load_scene("TC")
    poses = np.array([[0.2, 0.0, 0.0], [0.2, 0.15, 0.0]])
    g = choose_grasp(sc, prim, poses, np.array([0.5, 0.5]), 0)
    assert 0.0 < g.share < 1.0 and np.all(np.isfinite(g.pregrasp))


def test_probe_line_blocked_by_another_object_predicts_the_block_and_the_contact_is_not_the_targets():
    poses = np.array([[0.25, 0.0, 0.0], [0.25, 0.0, np.pi / 2]])  # near face at 0.22 or 0.17 m
    visited = np.array([[0.0, 0.0], [0.0, 0.02]])
    # a known point of another object right in front of both starts, toward the target
    blocked = choose_probe(BOX, poses, np.array([0.5, 0.5]), 0, visited, _outline(), PlanParams(),
                           obstacles=np.array([[0.1, 0.0], [0.1, 0.02]]))
    free = choose_probe(BOX, poses, np.array([0.5, 0.5]), 0, visited, _outline(), PlanParams())
    assert free is not None and free.direction @ [1.0, 0.0] > 0.99  # straight at the box
    # every hypothesis of a line through the obstacle predicts the obstacle's stop: no such line is chosen
    assert blocked is None or not (blocked.direction @ [1.0, 0.0] > 0.99)
    # a contact on the other object is not explained by the set, so the policy attributes it elsewhere
    assert not explaining(BOX, poses, np.array([0.1, 0.0]), 0.025).any()
    assert explaining(BOX, poses, np.array([0.22, 0.0]), 0.025).any()


def test_a_contact_whose_force_the_hypothesis_surface_does_not_face_is_not_explained_by_it():
    """A contact on the +x face pushes the gripper along +x: a force along y or -x there is not this surface's,
    although the position fits (docs/active.md, "Whose contact (attribution)")."""
    upright = np.array([[0.0, 0.0, 0.0]])
    turned = np.array([[0.0, 0.2, np.pi / 2]])  # far from the contact
    on_face = np.array([0.031, 0.0])
    assert explaining(BOX, upright, on_face, 0.025, np.array([2.0, 0.1]), 60.0, 0.015).any()
    assert not explaining(BOX, upright, on_face, 0.025, np.array([0.0, 3.0]), 60.0, 0.015).any()
    assert not explaining(BOX, upright, on_face, 0.025, np.array([-2.0, 0.0]), 60.0, 0.015).any()  # pulled, not pushed
    # position only: every direction is explained, as with no force measured (NaN) or a zero force
    assert explaining(BOX, upright, on_face, 0.025, np.array([0.0, 3.0]), 180.0, 0.015).any()
    assert explaining(BOX, upright, on_face, 0.025, np.array([np.nan, np.nan]), 60.0, 0.015).any()
    assert explaining(BOX, upright, on_face, 0.025, np.zeros(2), 60.0, 0.015).any()
    # a corner's normals span a quarter turn: near one, a force within 60 deg of that cone is explained, and only
    # such a force (the +x, +y corner: its cone runs from +x to +y)
    corner = np.array([0.031, 0.079])
    assert explaining(BOX, upright, corner, 0.025, np.array([0.0, 1.0]), 60.0, 0.015).any()
    assert explaining(BOX, upright, corner, 0.025, np.array([1.0, 1.0]), 60.0, 0.015).any()  # inside the cone
    assert explaining(BOX, upright, corner, 0.025, np.array([-0.5, 1.0]), 60.0, 0.015).any()  # 27 deg beyond +y
    assert not explaining(BOX, upright, corner, 0.025, np.array([-1.0, 0.2]), 60.0, 0.015).any()  # 79 deg beyond
    assert not explaining(BOX, upright, corner, 0.025, np.array([-1.0, -1.0]), 60.0, 0.015).any()  # into the box
    assert not explaining(BOX, upright, corner, 0.025, np.array([0.0, -1.0]), 60.0, 0.0).any()
    # the same corner of a turned hypothesis: the cone turns with it
    quarter = np.array([[0.0, 0.0, np.pi / 2]])
    turned_corner = np.array([-0.079, 0.031])  # the +x, +y corner turned a quarter: cone from +y to -x
    assert explaining(BOX, quarter, turned_corner, 0.025, np.array([-1.0, 1.0]), 60.0, 0.015).any()
    assert not explaining(BOX, quarter, turned_corner, 0.025, np.array([1.0, -1.0]), 60.0, 0.015).any()
    # the set explains the contact when one of its hypotheses does, in position and direction
    both = np.vstack([turned, upright])
    assert explaining(BOX, both, on_face, 0.025, np.array([1.0, 0.0]), 60.0, 0.015).any()
    far = np.array([[0.5, 0.5, 0.0]])
    assert not explaining(BOX, far, on_face, 0.025, np.array([1.0, 0.0]), 60.0, 0.015).any()


# ---------------------------------------------------------------------------------------------------------------
# Guarded moves
# ---------------------------------------------------------------------------------------------------------------


class FakeArm:
    """Moves exactly as told; reports contact once x passes ``wall``."""

    def __init__(self, wall: float):
        self.pos = np.zeros(2)
        self.wall = wall
        self.moves = []

    def __call__(self, dx, dy):
        self.pos = self.pos + [dx, dy]
        self.moves.append((dx, dy))
        return {"ee_x_m": self.pos[0], "ee_y_m": self.pos[1], "in_contact": bool(self.pos[0] >= self.wall)}


def test_guarded_move_slows_near_the_prediction_stops_at_contact_and_backs_off():
    arm = FakeArm(wall=0.1)
    p = ProbeParams()
    here, n, contact, travel = guarded_move(arm, np.zeros(2), np.array([1.0, 0.0]), np.array([0.1, 0.12]), p)
    assert 0.1 <= travel <= 0.1 + p.fine_step + 1e-9
    assert contact
    steps = [m[0] for m in arm.moves]
    assert steps[0] == pytest.approx(p.coarse_step) and steps[-2] == pytest.approx(p.fine_step)
    assert steps[-1] == pytest.approx(-p.backoff)
    assert here[0] == pytest.approx(arm.pos[0]) and 0.1 - p.backoff <= here[0] + 1e-9 <= 0.1 + p.fine_step


def test_guarded_move_gives_up_past_the_latest_prediction():
    arm = FakeArm(wall=10.0)
    p = ProbeParams()
    here, n, contact, travel = guarded_move(arm, np.zeros(2), np.array([0.0, 1.0]), np.array([0.05, np.inf]), p)
    assert np.isinf(travel)
    assert not contact and here[1] == pytest.approx(0.05 + p.overshoot, abs=p.fine_step)


def test_retrace_stops_at_a_contact_on_the_way_and_backs_off():
    arm = FakeArm(wall=0.05)
    here, n, contact = retrace(arm, np.zeros(2), np.array([[0.09, 0.0], [0.09, 0.09]]), 0.03, 0.015)
    assert contact and arm.moves[-1][0] < 0 and here[0] < 0.06


# ---------------------------------------------------------------------------------------------------------------
# The set grasp's geometric rule
# ---------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("scene", ["FB", "BC", "IB"])
def test_box_rule_holds_at_the_pose_and_within_0_05_rad_and_slips_at_0_10(scene):
    # docs/retrieval.md, "Where grasps are lost": simulated, every box grasp holds at +-0.05 rad and few at 0.10.
    sc = load_scene(scene)
    _, prim = target_primitive(sc)
    plan = plan_for(sc)
    truth = np.array([0.25, 0.05, 0.3])
    pp = primitive_pose(prim, truth)
    yaw = np.array([pp[2]])
    centre = prim.centre_world(truth)[None]
    turned = com_pose(prim, pp[None] + np.array([[0, 0, 0.0], [0, 0, 0.05], [0, 0, -0.05], [0, 0, 0.10],
                                                 [0, 0, -0.10], [0.015, 0, 0], [0, 0.015, 0]]))
    ok = box_success(prim, turned, yaw, centre, np.array([4.0]), plan, sc.action_scale)[0]
    assert ok.tolist() == [True, True, True, False, False, True, True]


def test_can_rule_holds_centred_and_not_beside_the_fingers():
    sc = load_scene("TC")
    _, prim = target_primitive(sc)
    plan = plan_for(sc)
    truth = np.array([0.2, 0.05, 0.0])
    c = prim.centre_world(truth)
    poses = np.array([truth, truth + [0.0, 0.01, 0.0], truth + [0.0, 0.06, 0.0]])
    ok = can_success(prim, poses, np.array([-np.pi / 2]), c[None], np.array([4.0]), plan, sc.action_scale)[0]
    assert ok.tolist() == [True, True, False]


def test_set_grasp_serves_the_heavier_cluster():
    sc = load_scene("BC")
    _, prim = target_primitive(sc)
    base = np.array([0.25, 0.05, 0.3])
    poses = np.array([base, base, base + [0, 0, 0.3]])
    g = choose_grasp(sc, prim, poses, np.array([0.35, 0.35, 0.3]), 2)  # the estimate is the lighter one
    assert g.share == pytest.approx(0.7)
    assert math.isclose(g.yaw, float(primitive_pose(prim, base)[2] - np.pi), abs_tol=1e-9) or \
        math.isclose(g.yaw, float(primitive_pose(prim, base)[2]), abs_tol=1e-9)


# ---------------------------------------------------------------------------------------------------------------
# Collect and CLI
# ---------------------------------------------------------------------------------------------------------------


def test_collect_scripted_plus_probe_marks_probe_actions_and_records_the_log():
    from pipeline.collect import collect_run

    sc = load_scene("TC")
    table, params, res = collect_run(sc, 104, policy="scripted+probe", max_actions=20,
                                     policy_params=dataclasses.replace(ProbeParams(), budget=1))
    flags = np.asarray(table.column("probe").to_pylist())
    assert not flags[:20].any() and flags[20:].all() and table.num_rows > 20
    log = params["probe"]
    assert log["probes"] <= 1 and log["actions"] == table.num_rows - 20
    assert len(res.probe_s["decision_s"]) == log["probes"] + 1 and log["params"]["budget"] == 1
    assert res.probe_s["prior_s"] > 0.0  # the pushes' prior was computed, once
    assert "decision_s" not in log and "prior_s" not in log  # wall times stay out of the file
    again, params2, _ = collect_run(sc, 104, policy="scripted+probe", max_actions=20,
                                    policy_params=dataclasses.replace(ProbeParams(), budget=1))
    assert _parquet_bytes(again) == _parquet_bytes(table) and params2 == params  # the same run, byte for byte
    from pipeline.schema.validate import validate_spec

    validate_spec(table, schema.SIM_RUN)  # the probe column is the run table's optional column
    # what the policy senses of its probes: one point, step and contact force per isolated probe contact
    from pipeline.detection import contact_forces
    from pipeline.probe.belief import Sensing

    sensing = Sensing("TC/104", 0, np.zeros(2), 20)
    sensing.observe(table)
    assert len(sensing.probe_points) == len(sensing.probe_steps) == len(sensing.probe_forces) == \
        len(sensing.probe_force_n)
    assert sensing.probe_steps  # the probe touched something
    force_n = contact_forces(table, sensing.detection)
    for f, fn, step in zip(sensing.probe_forces, sensing.probe_force_n, sensing.probe_steps):
        row = table.slice(step, 1).to_pylist()[0]  # one row per action, in step order
        assert row["step"] == step and f.shape == (2,)
        assert np.array_equal(f, [row["force_rep_x_n"], row["force_rep_y_n"]], equal_nan=True)
        assert fn == force_n[step] or np.isnan(fn) and np.isnan(force_n[step])  # the action's force, as isolate's


def _parquet_bytes(table) -> bytes:
    import io

    import pyarrow.parquet as pq

    buf = io.BytesIO()
    pq.write_table(table, buf)
    return buf.getvalue()


def test_bench_probe_refuses_a_bad_budget(tmp_path):
    from stucco_cli.main import cli

    r = CliRunner().invoke(cli, ["bench", "probe", "--budgets", "1,x", "--out", str(tmp_path)])
    assert r.exit_code == 2 and "--budgets" in r.output


def test_evaluate_config_keeps_old_directories_and_refuses_an_unknown_policy():
    from pipeline.evaluate import EvalConfig

    assert "policy" not in EvalConfig().to_dict()  # evaluation.json of the paper's protocol is unchanged
    assert EvalConfig(policy="scripted+probe").to_dict()["policy"] == "scripted+probe"
    with pytest.raises(ValueError, match="unknown policy 'wander'"):
        EvalConfig(policy="wander")


def test_set_grasp_with_a_margin_keeps_the_estimates_grasp_against_a_cluster_barely_heavier():
    # With a margin, a quarter-turned cluster a little heavier does not win; without one it does.
    sc = load_scene("BC")
    _, prim = target_primitive(sc)
    base = np.array([0.25, 0.05, 0.3])
    poses = np.array([base, base + [0, 0, np.pi / 2], base + [0, 0, np.pi / 2]])
    g = choose_grasp(sc, prim, poses, np.array([0.45, 0.275, 0.275]), 0, margin=0.25)
    assert g.share == pytest.approx(0.45)
    assert math.isclose(math.cos(2 * (g.yaw - primitive_pose(prim, base)[2])), 1.0, abs_tol=1e-9)
    assert choose_grasp(sc, prim, poses, np.array([0.45, 0.275, 0.275]), 0).share == pytest.approx(0.55)


def test_active_row_is_computed_once_for_the_estimators_of_a_job(monkeypatch):
    """Every pose estimator of a job gets the active protocol's same row: computed once for the same run file,
    method, seed and grasp parameters, afresh when any of them changes."""
    from pipeline.grasp import GraspParams
    from pipeline.probe import retrieval
    from pipeline.retrieve import load_run

    calls = []
    real = retrieval._active_row
    monkeypatch.setattr(retrieval, "_active_row", lambda *a: calls.append(a) or real(*a))
    monkeypatch.setattr(retrieval, "_LAST_ROW", [])
    info = load_run(REG / "FB-000.parquet")
    first = retrieval.active_row(info, "stucco", 0, False, GraspParams())
    again = retrieval.active_row(info, "stucco", 0, False, GraspParams())
    assert len(calls) == 1 and again == first and again is not first
    retrieval.active_row(info, "stucco", 1, False, GraspParams())
    retrieval.active_row(info, "stucco", 1, False, GraspParams(settle_steps=239))
    assert len(calls) == 3


@pytest.mark.parametrize("held, probes_expected", [(1.0, 0), (0.5, None)])
def test_a_wide_set_that_one_grasp_holds_stops_the_probing(stored_run, monkeypatch, held, probes_expected):
    """The poses disagree (agreement 0.2), but the grasp chosen for the set holds ``held`` of it: at 1.0 the
    policy stops at once, unflagged; at 0.5 it goes on (here the budget is 0, so it stops flagged)."""
    table, start, prim = stored_run
    monkeypatch.setattr(attribution_mod, "agreement", lambda *a, **k: 0.2)
    log = probe_run(_no_act, lambda: table, "TC/0", 0, prim, start,
                    ProbeParams(min_target_contacts=0, budget=0 if probes_expected is None else 8),
                    grasp_share=lambda belief: held, scene=load_scene("TC"))
    assert log.probes == 0 and not log.agreed
    assert log.history[0]["stop"] == (held == 1.0) and log.history[0]["held"] == held
    assert log.flagged == ("" if held == 1.0 else "budget_spent")


def test_bench_probes_default_budgets_are_the_curves_budgets_and_end_at_the_policys():
    # The CLI keeps numpy out of its import, so it repeats the list: the two must stay one fact, and the curve
    # ends at the budget the policy runs with (the run files of `make reproduce-active` replay every budget).
    from pipeline.studies.probe_budget import BUDGETS
    from stucco_cli.bench_runs import bench_probe

    option = next(p for p in bench_probe.params if p.name == "budgets")
    assert tuple(int(b) for b in option.default.split(",")) == BUDGETS
    assert BUDGETS[-1] == ProbeParams().budget
