"""The pushes' prior of the active protocol (pipeline/probe/history.py; docs/active.md, "What the pushes said: a prior
from pushtrack"): its cost's shape, the prior of a stored run, its effect on a set, and the run files and
side files written before it."""
from __future__ import annotations

import hashlib
import json
import math
from functools import partial
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from pipeline import schema
from pipeline.estimators.run_info import load_run
from pipeline.estimators.target_model import target_primitive
from pipeline.geometry import Primitive, com_pose
from pipeline.probe.belief import Sensing, TargetChoice, pose_set
from pipeline.probe.history import HistoryPrior, history_prior
from pipeline.probe.params import ProbeParams
from pipeline.probe.report import run_stats, save_times, times_path
from pipeline.probe.retrieval import recorded_prior
from pipeline.robot import load_robot
from pipeline.scenes import load_scene

REG = Path(__file__).resolve().parents[1] / "data" / "regression"
BOX = Primitive(kind="box", half=(0.03, 0.08), centre=np.zeros(2), yaw=0.0)
CAN = Primitive(kind="cylinder", half=(0.04,), centre=np.zeros(2), yaw=0.0)
CAP = -math.log(ProbeParams().history_floor)


def _prior(poses, weights=None, segment=0, **kw):
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    w = np.full(len(poses), 1.0 / len(poses)) if weights is None else np.asarray(weights, dtype=np.float64)
    return HistoryPrior(poses, w, segment, ProbeParams(**kw))


def test_cost_is_nothing_within_the_band_and_the_cap_at_a_quarter_turn():
    prior = _prior([[0.3, 0.0, 0.2]])
    c = prior.cost(BOX, np.array([[0.3, 0.0, 0.2], [0.3, 0.0, 0.2 + 0.7], [0.32, 0.05, 0.2 - 0.79],
                                  [0.3, 0.0, 0.2 + math.pi / 2], [0.3, 0.0, 0.2 + math.pi]]))
    assert c[0] == pytest.approx(0.0, abs=1e-12) and c[1] == pytest.approx(0.0, abs=1e-12)
    assert c[2] == pytest.approx(0.0, abs=1e-12)  # 5.4 cm off lies within the 10 cm reach
    assert c[3] == pytest.approx(CAP, abs=0.02)  # a quarter turn: almost only the uniform floor
    assert c[4] == pytest.approx(0.0, abs=1e-12)  # a half turn is the same box
    assert np.all(np.diff(prior.cost(BOX, np.column_stack([np.full(9, 0.3), np.zeros(9),
                                                           0.2 + np.linspace(0.8, 1.5, 9)]))) > 0)


def test_cost_weighs_the_priors_modes_and_never_exceeds_the_cap():
    prior = _prior([[0.3, 0.0, 0.0], [0.3, 0.0, math.pi / 2]], [0.8, 0.2])
    c = prior.cost(BOX, np.array([[0.3, 0.0, 0.0], [0.3, 0.0, math.pi / 2], [0.3, 0.0, math.pi / 4]]))
    floor = ProbeParams().history_floor
    assert c[0] == pytest.approx(-math.log(floor + (1 - floor) * 0.8), rel=2e-3)
    assert c[1] == pytest.approx(-math.log(floor + (1 - floor) * 0.2), rel=2e-3)
    assert c[1] > c[0] and 0.0 <= c[2] <= c[0]  # pi/4 is within 0.8 rad of both
    with np.errstate(over="raise", invalid="raise"):  # no overflow however far off
        far = prior.cost(BOX, np.array([[5.0, 5.0, 1.0], [-1e6, 1e6, 0.0], [1e300, -1e300, 0.0]]))
    assert np.all(np.isfinite(far)) and np.allclose(far, CAP)  # another object's place: the cap, no more


def test_a_can_is_judged_by_position_only():
    prior = _prior([[0.3, 0.0, 0.0]])
    c = prior.cost(CAN, np.array([[0.3, 0.0, 1.3], [0.3, 0.09, -2.0], [0.3, 0.3, 0.0]]))
    assert c[0] == pytest.approx(0.0, abs=1e-12) and c[1] == pytest.approx(0.0, abs=1e-12)
    assert c[2] == pytest.approx(CAP, abs=0.01)


def test_a_prior_beyond_every_hypothesis_leaves_the_set_as_it_was_and_one_against_a_mode_removes_it():
    # two yaw modes of a box touched at one end only: points along its short face
    truth = np.array([0.3, 0.0, 0.0])
    ys = np.linspace(-0.025, 0.025, 6)
    pts = np.column_stack([np.full(6, 0.3 + 0.08), ys])
    choice = TargetChoice(0, pts, np.arange(6), np.zeros((0, 2)),
                          np.array([com_pose(BOX, truth), com_pose(BOX, [0.3 + 0.05, 0.0, math.pi / 2])]))
    sdf = load_robot("panda")
    ee = np.array([[0.6, 0.0], [0.55, 0.0]])
    args = (choice, BOX, ee, np.array([0]), sdf)
    none = pose_set(*args, np.random.default_rng(0), np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros((0, 2)))
    far = _prior([[3.0, 3.0, 0.0]])
    same = pose_set(*args, np.random.default_rng(0), np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros((0, 2)),
                    prior=partial(far.cost, BOX))
    assert np.array_equal(same.poses, none.poses) and np.allclose(same.weights, none.weights)
    assert same.best == none.best
    yaws = np.mod(none.poses[:, 2], math.pi)
    assert np.any(np.abs(yaws - math.pi / 2) < 0.3) and np.any(np.minimum(yaws, math.pi - yaws) < 0.3)
    near = _prior([com_pose(BOX, truth)])
    told = pose_set(*args, np.random.default_rng(0), np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros((0, 2)),
                    prior=partial(near.cost, BOX))
    ty = np.mod(told.poses[:, 2], math.pi)
    assert np.all(np.minimum(ty, math.pi - ty) < 0.8)  # the quarter-turned mode is out of the set
    assert np.all(np.isfinite(told.weights)) and told.weights.sum() == pytest.approx(1.0)


@pytest.fixture(scope="module")
def scripted_run():
    path = REG / "FB-000.parquet"
    table = schema.read_run(path)
    info = load_run(path)
    start = info.ee[0]
    sensing = Sensing(info.run, 0, start, table.num_rows)
    sensing.observe(table)
    return table, info, sensing


def test_the_prior_of_a_stored_run_is_pushtracks_set_and_reads_no_ground_truth(scripted_run):
    table, info, sensing = scripted_run
    found = history_prior(table, sensing.segments(), info.scene, info.run, 0, sensing.sdf)
    assert found is not None and found.poses.shape[1] == 3 and len(found.poses) == len(found.weights)
    assert np.all(found.weights >= 0) and found.weights.sum() == pytest.approx(1.0)
    again = history_prior(table, sensing.segments(), info.scene, info.run, 0, sensing.sdf)
    assert np.array_equal(found.poses, again.poses) and np.array_equal(found.weights, again.weights)
    # no ground truth is read: the recorded poses scrambled, the same prior
    junk = table.set_column(table.column_names.index("obj_pose"), "obj_pose",
                            pa.array([[[9.0] * len(b) for b in v] for v in table.column("obj_pose").to_pylist()],
                                     type=table.schema.field("obj_pose").type))
    blind = history_prior(junk, sensing.segments(), info.scene, info.run, 0, sensing.sdf)
    assert np.array_equal(found.poses, blind.poses) and np.array_equal(found.weights, blind.weights)
    assert found.segment in [s.id for s in sensing.segments()]
    # (the set's yaw, judged against the recorded truth here only)
    _, prim = target_primitive(info.scene)
    truth = info.true_pose
    assert found.cost(prim, truth[None, :])[0] < 0.5


def test_the_prior_keeps_its_filter_when_pushtracks_defaults_move(scripted_run):
    # The prior was chosen and checked with the point pusher and its noise (docs/active.md, "What the pushes said: a
    # prior from pushtrack"); these are the bits it gave before pushtrack's default pushing model and noise changed.
    table, info, sensing = scripted_run
    found = history_prior(table, sensing.segments(), info.scene, info.run, 0, sensing.sdf)
    digest = hashlib.sha256(np.ascontiguousarray(found.poses).tobytes()
                            + np.ascontiguousarray(found.weights).tobytes()).hexdigest()
    assert digest == "a0321e4f347090ec2c897b512cbdcdc232550fa63bfbf4faed9a42a65efe9886"


def test_no_segment_gives_no_prior(scripted_run):
    table, info, sensing = scripted_run
    assert history_prior(table, [], info.scene, info.run, 0, sensing.sdf) is None
    assert history_prior(table.slice(0, 0), sensing.segments(), info.scene, info.run, 0, sensing.sdf) is None


def test_a_run_file_from_before_the_prior_is_retrieved_without_one(scripted_run):
    table, info, sensing = scripted_run
    segments = sensing.segments()
    assert recorded_prior(info, table, segments, sensing.sdf, 0, "stucco", {}) is None
    assert recorded_prior(info, table, segments, sensing.sdf, 0, "stucco", {"history": "off"}) is None
    prior = recorded_prior(info, table, segments, sensing.sdf, 0, "stucco",
                           {"history": "pushtrack", "history_floor": 0.5})
    assert prior is not None and prior.params.history_floor == 0.5
    assert np.max(prior.cost(info.target, np.array([[9.0, 9.0, 0.0]]))) == pytest.approx(-math.log(0.5))


def test_times_side_files_old_and_new(tmp_path):
    run = REG / "FB-000.parquet"
    path = tmp_path / "FB-000.parquet"
    path.write_bytes(run.read_bytes())
    times_path(path).write_text(json.dumps([0.1, 0.2]))  # written before the prior was timed
    st = run_stats(path)
    assert st["decision_s"] == [0.1, 0.2] and st["prior_s"] is None
    save_times(path, {"decision_s": [0.3], "prior_s": 0.45})
    st = run_stats(path)
    assert st["decision_s"] == [0.3] and st["prior_s"] == pytest.approx(0.45)


def test_bad_history_parameters_are_refused():
    for bad in ({"history": "vision"}, {"history_floor": 0.0}, {"history_yaw_sigma": 0.0},
                {"history_reach": -0.1}):
        with pytest.raises(ValueError):
            ProbeParams(**bad)


def test_the_prior_applies_only_to_sets_of_the_segment_it_tracked():
    from pipeline.probe.policy import prior_for

    class _Sensed:
        prior = _prior([[0.3, 0.0, 0.0]], segment=2)

    mine = TargetChoice(2, np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 3)))
    other = TargetChoice(5, np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 3)))
    assert prior_for(_Sensed(), mine, BOX) is not None and prior_for(_Sensed(), other, BOX) is None
    _Sensed.prior = None
    assert prior_for(_Sensed(), mine, BOX) is None


def test_the_policy_needs_the_scene_for_its_prior():
    from pipeline.probe.policy import probe_run

    table = schema.read_run(REG / "TC-000.parquet")
    prim = target_primitive(load_scene("TC"))[1]
    with pytest.raises(ValueError, match="scene"):
        probe_run(lambda dx, dy: {}, lambda: table, "TC/0", 0, prim, np.zeros(2), ProbeParams())


def test_the_retrieve_stage_recomputes_the_policys_prior_bit_for_bit(tmp_path, monkeypatch):
    from pipeline.collect import collect_file
    from pipeline.probe import policy as policy_mod
    from pipeline.probe.retrieval import active_set

    seen = []
    real = policy_mod.history_prior

    def spy(*a, **k):
        seen.append(real(*a, **k))
        return seen[-1]

    monkeypatch.setattr(policy_mod, "history_prior", spy)
    path = tmp_path / "TC-104.parquet"
    collect_file(load_scene("TC"), 104, path, policy="scripted+probe", max_actions=20,
                 policy_params=ProbeParams(budget=1))
    assert len(seen) == 1 and seen[0] is not None  # computed once, and found
    info = load_run(path)
    table = schema.read_run(path)
    n0 = int(np.argmax(np.asarray(table.column("probe").to_pylist(), dtype=bool)))
    assert n0 == 20
    recorded = (schema.read_metadata(path)["params"]["probe"])["params"]
    sensing = Sensing(info.run, 0, info.ee[0], n0)
    sensing.observe(table.slice(0, n0))
    again = recorded_prior(info, table.slice(0, n0), sensing.segments(), sensing.sdf, 0, "stucco",
                           recorded)
    assert again.segment == seen[0].segment
    assert np.array_equal(again.poses, seen[0].poses) and np.array_equal(again.weights, seen[0].weights)
    belief, _ = active_set(info, 0)
    assert np.all(np.isfinite(belief.weights))
