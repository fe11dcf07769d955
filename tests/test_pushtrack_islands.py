"""pushtrack's islands: independent filters over the same actions, pooled by their evidence
(pipeline.estimators.pushtrack.estimator.filter_islands / pool_islands; docs/estimators.md, "Islands")."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from pipeline.estimators.pushtrack.estimator import filter_islands, final_pose, pool_islands
from pipeline.estimators.pushtrack.filter import Actions, FilterResult, PushTrackParams, run_filter
from pipeline.geometry import Primitive
from pipeline.scenes import load_scene

BOX = Primitive("box", (0.03, 0.08), np.array([0.0, 0.0]), 0.0, "box")
NO_FREE = lambda rows, centre: np.zeros((0, 2))  # noqa: E731


def _island(n: int, evidence: float, offset: float, t: int = 2) -> FilterResult:
    """n particles at x = offset + 0.001 k, equal weights, the given evidence."""
    poses = np.column_stack([offset + 0.001 * np.arange(n), np.zeros(n), np.zeros(n)])
    return FilterResult(poses=poses, log_w=np.full(n, -math.log(n)), local=np.zeros((n, t, 2)),
                        choice=np.zeros(n), pushed=np.full(t, 0.01), n_pushes=t, n_resampled=1,
                        log_evidence=evidence)


def _still_box_actions(k: int = 6) -> Actions:
    """k touches of a still box at (0.4, 0, 0.2), walking round its -x, -y and +y faces."""
    yaw = 0.2
    s = np.linspace(-0.05, 0.05, k)
    f = np.arange(k) % 3
    local = np.where((f == 0)[:, None], np.column_stack([np.full(k, -0.03), s]),
                     np.where((f == 1)[:, None], np.column_stack([s / 3, np.full(k, -0.08)]),
                              np.column_stack([s / 3, np.full(k, 0.08)])))
    world = np.column_stack([0.4 + math.cos(yaw) * local[:, 0] - math.sin(yaw) * local[:, 1],
                             math.sin(yaw) * local[:, 0] + math.cos(yaw) * local[:, 1]])
    return Actions(ee_start=world - 0.02, ee_end=world - 0.01, touch=np.ones(k, dtype=bool), contact=world,
                   push=np.zeros((k, 2)))


def test_islands_pool_every_particle_weighted_by_their_evidence():
    a, b = _island(4, -10.0, 0.0), _island(6, -30.0, 1.0)
    pooled = pool_islands([a, b])
    assert pooled.poses.shape == (10, 3) and pooled.local.shape == (10, 2, 2) and pooled.choice.shape == (10,)
    w = np.exp(pooled.log_w)
    assert np.all(np.isfinite(pooled.log_w)) and math.isclose(float(w.sum()), 1.0, rel_tol=1e-12)
    # island b's share is e^-20 of island a's: its six particles hold 1 / (1 + e^20) together
    assert math.isclose(float(w[4:].sum()), 1.0 / (1.0 + math.exp(20.0)), rel_tol=1e-9)
    assert np.allclose(w[:4], w[0]) and np.allclose(w[4:], w[4])
    # the pooled evidence is the islands' mean evidence; resamplings add up
    assert math.isclose(pooled.log_evidence, math.log((math.exp(-10.0) + math.exp(-30.0)) / 2), rel_tol=1e-12)
    assert pooled.n_resampled == 2 and np.array_equal(pooled.pushed, a.pushed)


def test_equal_evidence_islands_share_equally_and_underflow_stays_finite():
    pooled = pool_islands([_island(3, -2000.0, 0.0), _island(3, -2000.0, 1.0)])  # exp(-2000) underflows
    assert np.allclose(np.exp(pooled.log_w), 1.0 / 6.0) and math.isclose(pooled.log_evidence, -2000.0)


def test_an_island_without_evidence_gets_no_particles_and_all_without_share_equally():
    some = pool_islands([_island(3, -np.inf, 0.0), _island(2, -5.0, 1.0)])
    assert len(some.poses) == 2 and np.all(some.poses[:, 0] >= 1.0) and np.all(np.isfinite(some.log_w))
    assert math.isclose(some.log_evidence, -5.0 - math.log(2.0))
    none = pool_islands([_island(3, -np.inf, 0.0), _island(2, -np.inf, 1.0)])
    assert len(none.poses) == 5 and np.all(np.isfinite(none.log_w))
    assert math.isclose(float(np.exp(none.log_w[:3]).sum()), 0.5) and none.log_evidence == -math.inf


def test_one_island_is_the_kept_filter():
    a = _still_box_actions()
    p = PushTrackParams(islands=1, motion="push")
    first = run_filter(BOX, a, NO_FREE, p, np.random.default_rng(2))
    assert filter_islands(BOX, a, NO_FREE, p, np.random.default_rng(2), first) is first


def test_islands_draw_their_own_streams_deterministically_without_advancing_the_generator():
    a = _still_box_actions()
    p = PushTrackParams(islands=3, n_particles=64, motion="push")
    rng = np.random.default_rng(5)
    state = rng.bit_generator.state
    first = run_filter(BOX, a, NO_FREE, p, np.random.default_rng(5))
    one = filter_islands(BOX, a, NO_FREE, p, rng, first)
    two = filter_islands(BOX, a, NO_FREE, p, np.random.default_rng(5), first)
    assert rng.bit_generator.state == state
    assert np.array_equal(one.poses, two.poses) and np.array_equal(one.log_w, two.log_w)
    assert len(one.poses) == 3 * 64 and np.array_equal(one.poses[:64], first.poses)
    # islands 1 and 2 are other draws than island 0 and than each other
    assert not np.array_equal(one.poses[64:128], first.poses) and not np.array_equal(one.poses[64:128],
                                                                                      one.poses[128:])


def test_pooled_islands_still_find_a_box_its_contacts_pin():
    # a still box touched on three faces: the pooled islands' estimate is as exact as one filter's
    a = _still_box_actions(9)
    p = replace(PushTrackParams(motion="push"), n_particles=128)
    first = run_filter(BOX, a, NO_FREE, p, np.random.default_rng(1))
    pooled = filter_islands(BOX, a, NO_FREE, p, np.random.default_rng(1), first)
    est = final_pose(BOX, pooled, np.zeros((0, 2)), np.zeros((0, 2)), p, load_scene("FB"))[0]
    assert np.hypot(est[0] - 0.4, est[1]) < 0.002 and abs(est[2] - 0.2) < 0.01
