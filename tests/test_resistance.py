"""The segment that resisted: contact forces from a run file, per-segment resistance and the choice built on it
(a heavy target's segment wins over an object beside it that fits the shape as well; a light target, a segment
that does not fit, missing forces and ties keep the paper's choice)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pyarrow.parquet as pq
import pytest

from pipeline.detection import contact_forces, fixed_column, window_force
from pipeline.estimators.estimate import Segment, estimate, paper_choice, paper_segment
from pipeline.estimators.pushtrack.estimator import observed_actions
from pipeline.estimators.run_info import load_run, retrieval_rng
from pipeline.estimators.segment_choice import (
    resisting_choice,
    resisting_segment,
    segment_fits,
    segment_resistance,
    target_mass,
)
from pipeline.retrieve import RetrievalParams
from pipeline.robot import load_robot

STEPS = np.arange(6)
FORCE = np.array([2.0, 30.0, np.nan, 28.0, 3.0, 1.0])


def test_resistance_is_the_median_force_at_the_segments_steps():
    r = segment_resistance([np.array([1, 3]), np.array([0, 4, 5]), np.array([2]), np.array([9]), np.zeros(0)],
                           STEPS, FORCE)
    assert r[0] == 29.0 and r[1] == 2.0
    assert r[2] == -np.inf and r[3] == -np.inf and r[4] == -np.inf  # no measured force, an unknown step, no points
    assert np.all(segment_resistance([np.array([1])], np.zeros(0, np.int64), np.zeros(0)) == -np.inf)


@pytest.mark.parametrize("mass, limit, expected", [(10.0, 1.0, 1), (0.4, 1.0, None), (10.0, None, None)])
def test_the_rule_applies_to_a_heavy_target_only(mass, limit, expected):
    segs = [np.array([0, 4]), np.array([1, 3])]
    assert resisting_segment([0, 1], segs, [True, True], STEPS, FORCE, mass, limit) == expected


def test_only_segments_that_fit_compete_while_one_does():
    segs = [np.array([0, 4]), np.array([1, 3])]  # the second resists (a wall pushed against) but fits no box
    assert resisting_segment([0, 1], segs, [True, False], STEPS, FORCE, 10.0, 1.0) == 0
    assert resisting_segment([0, 1], segs, [False, False], STEPS, FORCE, 10.0, 1.0) == 1


def test_ties_missing_forces_and_no_segments_keep_the_ranking():
    segs = [np.array([1]), np.array([1])]
    assert resisting_segment([7, 3], segs, [True, True], STEPS, FORCE, 10.0, 1.0) == 7  # the first of equals
    assert resisting_segment([7, 3], [np.array([2]), np.array([2])], [True, True], STEPS, FORCE, 10.0, 1.0) is None
    assert resisting_segment([7, 3], segs, [True, True], STEPS, None, 10.0, 1.0) is None
    assert resisting_segment([], [], [], STEPS, FORCE, 10.0, 1.0) is None


def test_segment_fits_is_the_paper_gate_on_valid_restarts():
    cand = {"segment": np.array([0, 0, 1, 1, 2]), "valid": np.array([True, False, False, True, False]),
            "icp_rmse_m": np.array([0.01, 0.001, 0.001, 0.03, 0.0])}
    assert segment_fits(cand, [0, 1, 2, 5], 0.02).tolist() == [True, False, False, False]


@pytest.fixture(scope="module")
def fb():
    info = load_run("data/regression/FB-000.parquet")
    oid = pq.read_table(info.path, columns=["object_id"]).column("object_id").to_numpy()
    return info, oid


def test_contact_forces_of_a_run_file(fb):
    info, oid = fb
    f = contact_forces(pq.read_table(info.path))
    assert f.shape == info.steps.shape and np.array_equal(f, info.contact_force, equal_nan=True)
    assert np.all(np.isnan(f[oid == -1]) | (f[oid == -1] >= 0.0)) and np.all(f[np.isfinite(f)] >= 0.0)
    # the 10 kg box resists the gripper's pushes; the light clutter moves away at a few newtons
    mine, other = f[(oid == info.target_id)], f[(oid >= 0) & (oid != info.target_id) & (oid < 5)]
    assert np.nanmedian(mine) > 3 * np.nanmedian(other)
    assert target_mass(info.scene) == 10.0


def test_one_actions_force_is_its_row_of_the_runs_forces(fb):
    # what a policy reads of the action it just made (window_force) is what the run's later stages read of it
    info, _ = fb
    table = pq.read_table(info.path)
    win = fixed_column(table, "win_wrench", (table.num_rows, -1, 6))
    each = np.array([window_force(w) for w in win])
    assert np.array_equal(each, contact_forces(table), equal_nan=True)
    assert np.isnan(window_force(np.zeros((0, 6)))) and np.isnan(window_force(np.full((3, 6), np.nan)))


def test_a_heavy_targets_segment_wins_over_a_light_object_that_fits_as_well(fb):
    # two segments on the box's shape (the target's contacts split in halves): the half whose actions met the
    # forces wins whichever the paper ranks first; with the forces swapped the other half does
    info, oid = fb
    mine = np.flatnonzero(oid == info.target_id)
    contact_steps = info.steps[mine]
    halves = (contact_steps[: len(mine) // 2], contact_steps[len(mine) // 2:])
    segs = [Segment(i, np.zeros((len(h), 2)), h) for i, h in enumerate(halves)]
    cand = {"segment": np.array([0, 1]), "valid": np.array([True, True]), "icp_rmse_m": np.array([0.001, 0.001])}
    force = np.full(len(info.steps), np.nan)
    force[np.isin(info.steps, halves[1])] = 30.0
    force[np.isin(info.steps, halves[0])] = 3.0
    params = RetrievalParams()
    assert resisting_choice(segs, 0, cand, info.steps, force, 10.0, params) == (1, True)
    assert resisting_choice(segs, 1, cand, info.steps, force, 10.0, params) == (1, True)
    assert resisting_choice(segs, 0, cand, info.steps, 33.0 - force, 10.0, params) == (0, True)
    assert resisting_choice(segs, 0, cand, info.steps, force, 0.4, params) == (0, False)  # a light target
    off = RetrievalParams(heavy_target_kg=None)
    assert resisting_choice(segs, 0, cand, info.steps, force, 10.0, off) == (0, False)
    nothing = np.full(len(info.steps), np.nan)  # no force measured at any of their steps: the paper's, undecided
    assert resisting_choice(segs, 1, cand, info.steps, nothing, 10.0, params) == (1, False)


def test_the_estimators_start_from_the_resisting_segment_and_the_paper_estimate_is_unchanged(fb):
    # the box's isolated contacts split in two segments that both fit: the paper picks one by its restarts, the
    # estimators take the one whose actions met the forces
    info, oid = fb
    sdf = load_robot("panda")
    contact, _ = observed_actions(info, sdf)
    mine = np.flatnonzero((oid == info.target_id) & np.all(np.isfinite(contact), axis=1))
    h = len(mine) // 2
    segs = [Segment(0, contact[mine[:h]], info.steps[mine[:h]]), Segment(1, contact[mine[h:]], info.steps[mine[h:]])]
    params = RetrievalParams()
    paper = paper_choice(segs, info, sdf, params, retrieval_rng(0, info.run))
    assert segment_fits(paper.candidates, [0, 1], params.segment_fit_gate).all()
    heavy = np.where(np.isin(info.steps, segs[0].steps), 40.0, 1.0)
    for f, want in ((heavy, 0), (41.0 - heavy, 1)):
        est, seg = paper_segment(segs, dataclasses.replace(info, contact_force=f), sdf, params,
                                 retrieval_rng(0, info.run), 0.0)
        assert est.segment == paper.segment and seg.id == want  # the paper's own estimate does not change
        plausible = estimate("plausible", segs, dataclasses.replace(info, contact_force=f), sdf,
                             retrieval_rng(0, info.run), params)
        assert plausible.segment == want and set(plausible.candidates["segment"]) == {want}

