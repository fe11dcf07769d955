"""The pushtrack estimator: the pushing model's known answers, and the hard cases of the filter and the estimator
(never touched, touched once, pushed against a wall, a target that only slides, a still target, pushed through
another object, a segment that begins on another object, two segments that both fit, every particle inconsistent,
the same seed twice)."""
from __future__ import annotations

import math

import numpy as np
import pyarrow.parquet as pq
import pytest

from pipeline.estimators.estimate import Segment, estimate
from pipeline.estimators.plausible.evidence import cached_gripper_lattice, target_reach
from pipeline.estimators.pushtrack.estimator import (
    filter_from_best_start,
    final_pose,
    free_space_of,
    held_mean,
    observed_actions,
)
from pipeline.estimators.pushtrack.filter import (
    Actions,
    FilterResult,
    PushTrackParams,
    contact_loglik,
    free_loglik,
    initial_particles,
    push,
    run_filter,
)
from pipeline.estimators.pushtrack.quasistatic import limit_surface_length, push_step
from pipeline.estimators.pushtrack.slice_pusher import gripper_slice, sweep_push, target_outline
from pipeline.estimators.run_info import load_run, retrieval_rng
from pipeline.estimators.target_model import pose_error
from pipeline.geometry import Primitive, apply_pose
from pipeline.grasp_rule import own_grasp_shares
from pipeline.retrieve import RetrievalParams
from pipeline.robot import disc_sdf, load_robot
from pipeline.scenes import load_scene

BOX = Primitive("box", (0.03, 0.08), np.array([0.0, 0.0]), 0.0, "box")
C = limit_surface_length(BOX)
#: The filter's mechanics with the point pusher; the hard cases also with the default "tip", the gripper a disc of
#: 5 cm (``_pushes`` stands it 5 cm outside each contact).
P = PushTrackParams(motion="push")
TIP = PushTrackParams()
DISC5 = gripper_slice(disc_sdf(0.05))
BOTH = pytest.mark.parametrize("params", [P, TIP], ids=["push", "tip"])
NO_FREE = lambda rows, centre: np.zeros((0, 2))  # noqa: E731
#: A box task whose grasp plan ``select="mode"`` and ``"grasp"`` aim with (FB's, pipeline.grasp.PLANS).
SCENE = load_scene("FB")


def test_a_push_through_the_centre_translates_without_turning():
    pose = np.array([[0.5, 0.0, 0.0]])
    out = push_step(BOX, pose, np.array([0.5 - 0.03, 0.0]), np.array([0.01, 0.0]), C, 0.5)
    assert np.allclose(out, [[0.51, 0.0, 0.0]], atol=1e-12)


def test_an_off_centre_push_turns_the_box_away_from_the_pusher():
    # pushing the -x face at y = +6 cm in +x: the moment about the COM is negative, the box turns clockwise
    pose = np.array([[0.5, 0.0, 0.0]])
    out = push_step(BOX, pose, np.array([0.47, 0.06]), np.array([0.005, 0.0]), C, 0.5)
    assert out[0, 2] < -0.01 and 0.0 < out[0, 0] - 0.5 < 0.005
    # the contact point on the box moves with the pusher along the push (sticking): its x advances by the push
    before = apply_pose(pose[0], np.array([[-0.03, 0.06]]))[0]
    after = apply_pose(out[0], np.array([[-0.03, 0.06]]))[0]
    assert after[0] - before[0] == pytest.approx(0.005, abs=2e-4)


def test_a_pusher_moving_away_leaves_the_target():
    pose = np.array([[0.5, 0.0, 0.3]])
    out = push_step(BOX, pose, np.array([0.47, 0.0]), np.array([-0.01, 0.0]), C, 0.5)
    assert np.array_equal(out, pose)


def test_a_frictionless_pusher_only_pushes_along_the_normal():
    pose = np.array([[0.5, 0.0, 0.0]])
    out = push_step(BOX, pose, np.array([0.47, 0.0]), np.array([0.01, 0.01]), C, 0.0)
    assert out[0, 1] == pytest.approx(0.0, abs=1e-12) and out[0, 0] == pytest.approx(0.51, abs=1e-12)


def test_limit_surface_length_of_a_disc_is_two_thirds_of_its_radius():
    can = Primitive("cylinder", (0.03,), np.array([0.0, 0.0]), 0.0, "can")
    assert limit_surface_length(can, 200) == pytest.approx(0.02, rel=0.01)


def test_initial_particles_lie_on_the_contact():
    rng = np.random.default_rng(0)
    pose = initial_particles(BOX, np.array([0.3, 0.1]), np.array([0.0, 0.0]), 64, rng)
    sd = np.array([BOX.signed_distance(np.array([[0.3, 0.1]]), p)[0] for p in pose])
    assert np.allclose(sd, 0.0, atol=1e-12)


def _pushes(truth: np.ndarray, local: np.ndarray, push: np.ndarray, beyond: bool = False) -> Actions:
    """Actions whose contacts are the body-frame points ``local`` (K, 2) on the target at poses ``truth``
    (K, 3), each pushed by ``push`` (K, 2); the gripper (``DISC5``) stands 5 cm outside the contact, or with
    ``beyond`` ``push`` further on (its slice then pushes a target that had stayed where it was touched)."""
    contact = apply_pose(truth, local[:, None, :])[:, 0, :]
    ee = contact - 0.05 * push / np.maximum(np.hypot(*push.T), 1e-12)[:, None] + (push if beyond else 0.0)
    return Actions(ee_start=ee - push, ee_end=ee, touch=np.ones(len(local), dtype=bool), contact=contact,
                   push=push, gripper=DISC5)


def test_mode_returns_the_pose_whose_grasp_holds_the_most_of_the_set():
    # three particles 0.045 rad apart and one a quarter turn off; the most probable (0) is at one end of the three:
    # the grasp aimed at the middle one holds all three, the grasp aimed at 0 only two. "mode" returns the middle
    # one; "grasp" (the default) returns 0, the most probable particle the middle one's grasp holds, whose own
    # grasp holds less
    poses = np.array([[0.4, 0.0, 0.30], [0.4, 0.0, 0.345], [0.4, 0.0, 0.39], [0.4, 0.0, 0.30 + np.pi / 2]])
    log_w = np.log([0.30, 0.22, 0.20, 0.28])
    share, held = own_grasp_shares(SCENE, BOX, poses, np.exp(log_w))
    assert held[1, :3].all() and not held[0, 2] and np.argmax(share) == 1  # the case as described
    result = FilterResult(poses=poses, log_w=log_w, local=np.tile([[[0.03, 0.0]]], (4, 1, 1)), choice=np.zeros(4),
                          pushed=np.zeros(1), n_pushes=1, n_resampled=0)
    none = np.zeros((0, 2))
    mode = PushTrackParams(select="mode", motion="push")
    est, k = final_pose(BOX, result, none, none, mode, SCENE)
    assert k == 1 and pose_error(BOX, est, poses[1])[1] < 1e-6
    assert final_pose(BOX, result, none, none, PushTrackParams(select="grasp"), SCENE)[1] == 0
    # the default, "held_mean": the posterior mean of those the middle grasp holds within 0.05 rad of particle 0
    # (0 and 1; 2 is 0.09 rad away, 3 a quarter turn)
    assert P.select == "held_mean"
    est, k = final_pose(BOX, result, none, none, P, SCENE)
    w = np.array([0.30, 0.22])
    assert k == 0 and est[2] == pytest.approx(np.sum(w * poses[:2, 2]) / np.sum(w), abs=1e-9)
    with pytest.raises(ValueError, match="scene"):
        final_pose(BOX, result, none, none, mode)


def test_held_mean_aims_between_two_groups_at_equal_cost_and_ignores_the_rest():
    # The position class of BC's losses: refined particles split a grasp-width apart across the box at equal cost.
    # The mean of the two groups lies between them; a particle out of the yaw window or not held has no weight.
    across = np.array([np.cos(0.3 + np.pi / 2), np.sin(0.3 + np.pi / 2)])
    poses = np.array([[0.4, 0.0, 0.3], [0.4, 0.0, 0.3], [*(np.array([0.4, 0.0]) + 0.02 * across), 0.3],
                      [*(np.array([0.4, 0.0]) + 0.02 * across), 0.3], [0.5, 0.1, 0.3 + 0.1], [0.3, -0.1, 0.3]])
    post = np.array([0.4, 0.4, 0.4, 0.4, 0.0, 0.0])  # the two outsiders cost least: they must still not count
    held = np.array([True, True, True, True, True, False])
    est = held_mean(BOX, poses, post, held, 0, 0.05)
    assert np.allclose(est, [*(np.array([0.4, 0.0]) + 0.01 * across), 0.3], atol=1e-12)
    # costs thousands of nats apart: no underflow, the cheaper group alone
    far = held_mean(BOX, poses, np.array([1e4, 1e4, 0.0, 0.0, 0.0, 0.0]), held, 2, 0.05)
    assert np.all(np.isfinite(far)) and np.allclose(far, poses[2], atol=1e-12)
    # one particle: itself
    assert np.allclose(held_mean(BOX, poses[:1], post[:1], held[:1], 0, 0.05), poses[0], atol=1e-12)


def _best(result) -> np.ndarray:
    """The estimate the estimator returns: the refined particles' choice (no free space, no other points)."""
    return final_pose(BOX, result, np.zeros((0, 2)), np.zeros((0, 2)), P, SCENE)[0]


def test_a_flat_posterior_gives_the_pose_of_the_mode_the_grasp_holds():
    # three particles within 0.02 rad and one a quarter turn off, slightly heavier, each with one contact on its
    # own surface (every refined cost 0): the lowest posterior cost is the lone one, but the grasp aimed at any
    # of the three holds three quarters of the set ("grasp", the default), and the estimate is the most probable
    # of those three
    poses = np.array([[0.4, 0.0, 0.30], [0.4, 0.0, 0.31], [0.4, 0.0, 0.29], [0.4, 0.0, 0.30 + np.pi / 2]])
    log_w = np.log([0.24, 0.25, 0.23, 0.28])
    result = FilterResult(poses=poses, log_w=log_w, local=np.tile([[[0.03, 0.0]]], (4, 1, 1)), choice=np.zeros(4),
                          pushed=np.zeros(1), n_pushes=1, n_resampled=0)
    none = np.zeros((0, 2))
    est, k = final_pose(BOX, result, none, none, PushTrackParams(select="grasp"), SCENE)
    assert k == 1 and pose_error(BOX, est, poses[1])[1] < 1e-6
    est, k = final_pose(BOX, result, none, none, P, SCENE)  # "held_mean" (the default): the mean of the three
    w = np.array([0.24, 0.25, 0.23])
    assert k == 1 and est[2] == pytest.approx(np.sum(w * poses[:3, 2]) / np.sum(w), abs=1e-9)
    assert final_pose(BOX, result, none, none, PushTrackParams(select="mode"), SCENE)[1] == 1  # the same here
    assert final_pose(BOX, result, none, none, PushTrackParams(select="posterior"), SCENE)[1] == 3
    with pytest.raises(ValueError, match="scene"):
        final_pose(BOX, result, none, none, P)


def test_never_touched_gives_no_filter():
    a = Actions(ee_start=np.zeros((3, 2)), ee_end=np.ones((3, 2)), touch=np.zeros(3, dtype=bool),
                contact=np.full((3, 2), np.nan), push=np.zeros((3, 2)))
    assert run_filter(BOX, a, NO_FREE, P, np.random.default_rng(0)) is None


@BOTH
def test_touched_once_is_finite_and_on_the_contact(params):
    truth = np.array([[0.4, 0.0, 0.2]])
    a = _pushes(truth, np.array([[-0.03, 0.01]]), np.array([[0.0, 0.0]]))
    r = run_filter(BOX, a, NO_FREE, params, np.random.default_rng(0))
    assert np.all(np.isfinite(r.poses)) and np.all(np.isfinite(r.log_w))
    grasp = final_pose(BOX, r, np.zeros((0, 2)), np.zeros((0, 2)), PushTrackParams(select="grasp"), SCENE)[0]
    assert abs(BOX.signed_distance(a.contact, grasp)[0]) < 0.002  # one of the particles: on the contact
    # the default is the mean of the particles that grasp holds, which slide along the contact: near it, finite
    assert np.all(np.isfinite(_best(r))) and abs(BOX.signed_distance(a.contact, _best(r))[0]) < 0.01


def _faces(k: int) -> tuple[np.ndarray, np.ndarray]:
    """k contacts (body frame) walking round three faces of the box, so the pose is observable, and the outward
    normal (body frame) of each one's face."""
    s = np.linspace(-0.06, 0.06, k)
    f = np.arange(k) % 3
    local = np.where((f == 0)[:, None], np.column_stack([np.full(k, -0.03), s]),
                     np.where((f == 1)[:, None], np.column_stack([s / 3, np.full(k, -0.08)]),
                              np.column_stack([s / 3, np.full(k, 0.08)])))
    normal = np.where((f == 0)[:, None], [-1.0, 0.0], np.where((f == 1)[:, None], [0.0, -1.0], [0.0, 1.0]))
    return local, normal


def _world(v: np.ndarray, yaw: float) -> np.ndarray:
    return np.column_stack([math.cos(yaw) * v[:, 0] - math.sin(yaw) * v[:, 1],
                            math.sin(yaw) * v[:, 0] + math.cos(yaw) * v[:, 1]])


@BOTH
def test_pushed_against_a_wall_the_contacts_win(params):
    # every third action pushes the -x face 1 cm, 5 cm off-centre: the model predicts the box moves and turns; a
    # wall held it still. The others touch all four faces at eight places, so that the contacts fix the pose (with
    # three places repeated, near two corners and one face, a pose 0.45 rad off fits all twelve within 3 mm: no
    # estimate can tell it from the truth; docs/estimators.md, "The estimate: the posterior mean of what the grasp
    # holds"). The
    # estimate follows the contacts, not the model: far closer to the truth than the model's own prediction from
    # the true start, and the last contacts lie on its surface.
    k = 12
    truth = np.tile([0.4, 0.0, 0.3], (k, 1))
    local = np.array([[-0.03, 0.05], [0.0, 0.08], [0.03, -0.04], [-0.03, 0.05], [0.03, 0.05], [0.0, -0.08],
                      [-0.03, 0.05], [-0.03, -0.05], [0.02, 0.08], [-0.03, 0.05], [0.03, 0.0], [-0.01, -0.08]])
    pushing = np.arange(k) % 3 == 0
    a = _pushes(truth, local, np.where(pushing[:, None], 0.01 * _world(np.array([[1.0, 0.0]] * k), 0.3), 0.0),
                beyond=params.motion == "tip")
    model = truth[:1].copy()
    for t in range(k):
        if params.motion == "tip":
            model = sweep_push(BOX, model, DISC5, target_outline(BOX), a.ee_end[t] - a.push[t], a.ee_end[t],
                               params.sweep_substeps, C * params.sweep_limit_scale, params.friction,
                               tip=(params.tip_spread, params.tip_reach))
        else:
            model = push(BOX, model, a.contact[t] - a.push[t], a.push[t], C, params)
    est = _best(run_filter(BOX, a, NO_FREE, params, np.random.default_rng(1)))
    pos_model, yaw_model = pose_error(BOX, model[0], truth[-1])
    pos, yaw = pose_error(BOX, est, truth[-1])
    # (the tipped box turns about its far corner: 6 mm and 0.07 rad from the truth; the point pusher 2 cm, 0.4 rad)
    assert pos_model > 0.005 and yaw_model > 0.05
    assert pos < pos_model / 3 and yaw < yaw_model / 2
    assert np.median(np.abs(BOX.signed_distance(a.contact[-4:], est))) < 0.005


@BOTH
def test_a_target_that_only_slides_keeps_its_yaw(params):
    # every third action pushes the centre of the -x face 1 cm along +x (body frame): the box slides, never
    # turns; the others touch the -x face off-centre and the +y face near its ends without pushing
    k = 12
    pattern = np.array([[-0.03, 0.0], [-0.03, 0.06], [0.025, 0.08], [-0.03, 0.0], [-0.03, -0.06], [-0.025, 0.08]])
    local = np.tile(pattern, (k // 6, 1))
    pushing = np.arange(k) % 3 == 0
    truth = np.column_stack([0.4 + 0.01 * math.cos(-0.4) * np.cumsum(pushing),
                             0.01 * math.sin(-0.4) * np.cumsum(pushing), np.full(k, -0.4)])
    push = np.where(pushing[:, None], 0.01 * _world(np.array([[1.0, 0.0]] * k), -0.4), 0.0)
    r = run_filter(BOX, _pushes(truth, local, push), NO_FREE, params, np.random.default_rng(2))
    pos, yaw = pose_error(BOX, _best(r), truth[-1])
    assert pos < 0.01 and yaw < 0.05


def test_a_still_target_keeps_its_contacts_where_they_were_observed():
    # twelve touches without a push round three faces: the noise floors keep the particles diverse but do not carry
    # the contacts, and no push grows their sigma, so the refinement fits all twelve where they were observed
    local, _ = _faces(12)
    truth = np.array([[0.43, 0.0, 0.2]] * 12)
    r = run_filter(BOX, _pushes(truth, local, np.zeros((12, 2))), NO_FREE, P, np.random.default_rng(6))
    assert np.all(r.pushed == 0.0)
    seen = apply_pose(r.poses, r.local)  # (N, T, 2): every particle's contacts in world coordinates
    assert np.allclose(seen, apply_pose(truth, local[:, None, :])[:, 0, :][None], atol=1e-12)
    pos, yaw = pose_error(BOX, _best(r), truth[-1])
    assert pos < 0.001 and yaw < 0.005


def test_pushed_through_another_object_the_filter_follows():
    # six contacts round three faces of a still box, then an action that touches another object 1 cm off the
    # box's -x face and pushes 3 cm along +x (the gap closes, the box slides 2 cm; no contact of the target's),
    # then six contacts at the new pose: the particles pushed from that contact follow
    local, _ = _faces(12)
    before, after = np.array([0.4, 0.0, 0.0]), np.array([0.42, 0.0, 0.0])
    truth = np.array([before] * 6 + [after] * 7)
    contact = np.vstack([apply_pose(truth[:6], local[:6, None, :])[:, 0, :], [[0.36, 0.0]],
                         apply_pose(truth[7:], local[6:, None, :])[:, 0, :]])
    push = np.zeros((13, 2))
    push[6] = [0.03, 0.0]
    touch = np.ones(13, dtype=bool)
    touch[6] = False
    a = Actions(ee_start=contact - push, ee_end=contact, touch=touch, contact=contact, push=push)
    on = PushTrackParams(other_push=0.5, motion="push")  # off by default (docs/experiments/pushtrack-carrying.md)
    est = final_pose(BOX, run_filter(BOX, a, NO_FREE, on, np.random.default_rng(4)), np.zeros((0, 2)),
                     np.zeros((0, 2)), on, SCENE)[0]
    pos, yaw = pose_error(BOX, est, after)
    assert pos < 0.003 and yaw < 0.03
    # a quarter of the particles near that contact are pushed (the prior; the far ones and those injected later
    # have no choice), but the contacts after the push keep almost only those
    quarter = PushTrackParams(other_push=0.25, motion="push")
    r = run_filter(BOX, a, NO_FREE, quarter, np.random.default_rng(5))
    assert np.all(np.isin(r.choice, [0.0, math.log(0.25), math.log(0.75)]))
    assert np.sum(np.exp(r.log_w)[r.choice == math.log(0.25)]) > 0.9
    # no push without another segment's contact near the particles, or with other_push 0
    assert np.all(run_filter(BOX, a, NO_FREE, P, np.random.default_rng(5)).choice == 0.0)


@pytest.fixture(scope="module")
def begins_on_the_can():
    """BC-000's box with a segment that begins with the three contacts on the master chef can just before the
    box's first (the tracker merges them so in BC runs): (run, actions, free_points, contacts on the can)."""
    info = load_run("data/regression/BC-000.parquet")
    oid = pq.read_table(info.path, columns=["object_id"]).column("object_id").to_numpy()
    sdf = load_robot("panda")
    contact, push = observed_actions(info, sdf)
    seen = np.all(np.isfinite(contact), axis=1)
    box = np.flatnonzero(seen & (oid == info.target_id))
    can = np.flatnonzero(seen & (oid == info.scene.body_names.index("master_chef_can")))
    touch = np.zeros(len(seen), dtype=bool)
    touch[np.r_[can[can < box[0]][-3:], box]] = True
    a = Actions(ee_start=info.ee[:-1], ee_end=info.ee[1:], touch=touch, contact=contact, push=push)
    _, radius = target_reach(info.target, contact[touch])
    return info, a, free_space_of(a, cached_gripper_lattice(sdf, P.free_resolution), P, radius), 3


def test_a_segment_that_begins_on_another_object_starts_on_the_target(begins_on_the_can):
    info, a, free_points, elsewhere = begins_on_the_can
    for seed in range(3):
        result, kept = filter_from_best_start(info.target, a, free_points, P, np.random.default_rng(seed))
        # the first start on the box wins by far more than the can's contacts' charge and the margin: from the
        # first contact on, the particles follow the can and the gripper later sweeps where they are
        assert np.array_equal(kept.touch, a.touch & (np.arange(len(a.touch)) > np.flatnonzero(a.touch)[elsewhere - 1]))
        first = run_filter(info.target, a, free_points, P, np.random.default_rng(seed))
        assert result.log_evidence - 0.5 * P.outlier_sigmas ** 2 * elsewhere - P.start_margin > first.log_evidence
        assert np.isfinite(result.log_evidence) and np.all(np.isfinite(result.poses))
        est = final_pose(info.target, result, np.zeros((0, 2)), np.zeros((0, 2)), P, info.scene)[0]
        assert pose_error(info.target, est, info.true_pose)[0] < 0.015


def test_a_segment_that_begins_on_the_target_loses_nothing_by_the_starts():
    # the still box of twelve contacts: the kept filter's score is at least the first start's (a later start wins
    # only by more than the filter's evidence varies between seeds), and the pose is as exact as from the first
    local, _ = _faces(12)
    truth = np.array([[0.43, 0.0, 0.2]] * 12)
    a = _pushes(truth, local, np.zeros((12, 2)))
    for seed in (6, 7):
        result, kept = filter_from_best_start(BOX, a, NO_FREE, P, np.random.default_rng(seed))
        first = run_filter(BOX, a, NO_FREE, P, np.random.default_rng(seed))
        skipped = int(a.touch.sum() - kept.touch.sum())
        margin = P.start_margin if skipped else 0.0
        assert result.log_evidence - 0.5 * P.outlier_sigmas ** 2 * skipped - margin >= first.log_evidence
        pos, yaw = pose_error(BOX, _best(result), truth[-1])
        assert pos < 0.001 and yaw < 0.005


def test_one_start_is_the_filter_itself(begins_on_the_can):
    info, a, free_points, _ = begins_on_the_can
    one = PushTrackParams(starts=1, motion="push")
    result, kept = filter_from_best_start(info.target, a, free_points, one, np.random.default_rng(7))
    plain = run_filter(info.target, a, free_points, one, np.random.default_rng(7))
    assert kept is a and np.array_equal(result.poses, plain.poses) and np.array_equal(result.log_w, plain.log_w)
    assert result.log_evidence == plain.log_evidence
    none = Actions(ee_start=np.zeros((2, 2)), ee_end=np.ones((2, 2)), touch=np.zeros(2, dtype=bool),
                   contact=np.full((2, 2), np.nan), push=np.zeros((2, 2)))
    assert filter_from_best_start(BOX, none, NO_FREE, P, np.random.default_rng(0)) == (None, none)


@BOTH
def test_every_particle_inconsistent_stays_finite(params):
    truth = np.array([[0.4, 0.0, 0.0]] * 3)
    a = _pushes(truth, np.array([[-0.03, 0.0]] * 3), np.zeros((3, 2)))
    # free space covering the whole neighbourhood: no pose is outside it
    grid = np.stack(np.meshgrid(np.linspace(0.2, 0.6, 41), np.linspace(-0.2, 0.2, 41)), -1).reshape(-1, 2)
    r = run_filter(BOX, a, lambda rows, centre: grid, params, np.random.default_rng(3))
    assert np.all(np.isfinite(r.poses)) and np.all(np.isfinite(r.log_w))
    assert math.isclose(float(np.sum(np.exp(r.log_w))), 1.0, rel_tol=1e-9)
    assert np.all(free_loglik(BOX, r.poses, grid, P) < -100.0)
    assert np.isfinite(r.log_evidence) and r.log_evidence < -100.0
    best, _ = filter_from_best_start(BOX, a, lambda rows, centre: grid, params, np.random.default_rng(3))
    assert np.all(np.isfinite(best.poses)) and np.isfinite(best.log_evidence)


def test_likelihoods_peak_on_the_surface():
    pose = np.array([[0.4, 0.0, 0.0], [0.41, 0.0, 0.0]])
    ll = contact_loglik(BOX, pose, np.array([0.37, 0.0]), P)
    assert ll[0] == pytest.approx(0.0, abs=1e-12) and ll[1] < -1.0


@pytest.fixture(scope="module")
def fb_run():
    info = load_run("data/regression/FB-000.parquet")
    oid = pq.read_table(info.path, columns=["object_id"]).column("object_id").to_numpy()
    contact, _ = observed_actions(info, load_robot("panda"))
    mine = np.flatnonzero((oid == info.target_id) & np.all(np.isfinite(contact), axis=1))
    return info, contact, mine


def test_estimator_without_segments_is_finite_and_flagged(fb_run):
    info, _, _ = fb_run
    est = estimate("pushtrack", [], info, load_robot("panda"), retrieval_rng(0, info.run), RetrievalParams())
    assert est.segment == -1 and np.all(np.isfinite(est.pose)) and "no_points" in est.notes


def test_two_segments_that_both_fit_follow_the_choice(fb_run):
    # the target's contacts split in two segments: both are on the target's shape; the estimate takes the
    # chosen one's contacts and lies on them
    info, contact, mine = fb_run
    assert len(mine) >= 6
    halves = (mine[: len(mine) // 2], mine[len(mine) // 2:])
    segs = [Segment(i, contact[h], info.steps[h]) for i, h in enumerate(halves)]
    sdf = load_robot("panda")
    est = estimate("pushtrack", segs, info, sdf, retrieval_rng(0, info.run), RetrievalParams())
    again = estimate("pushtrack", segs, info, sdf, retrieval_rng(0, info.run), RetrievalParams())
    assert est.segment in (0, 1) and np.all(np.isfinite(est.pose))
    assert np.array_equal(est.pose, again.pose)  # the same seed, the same estimate
    assert set(est.candidates["segment"]) == {est.segment}
    last = contact[halves[est.segment][-1]]
    assert abs(info.target.signed_distance(last[None, :], est.pose)[0]) < 0.01


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError):
        PushTrackParams(motion="teleport")
    with pytest.raises(ValueError):
        PushTrackParams(tip_reach=0.9)  # the centre of rotation within the edge
    with pytest.raises(ValueError):
        PushTrackParams(tip_spread=-0.1)
    with pytest.raises(ValueError):
        PushTrackParams(n_particles=0)
    with pytest.raises(ValueError):
        PushTrackParams(starts=0)
    with pytest.raises(ValueError):
        PushTrackParams(start_margin=-1.0)


def _with_passes(a: Actions, after: int, passes: int, start: np.ndarray, end: np.ndarray) -> Actions:
    """``a`` with ``passes`` actions inserted after action ``after``, each moving the gripper from ``start`` to
    ``end`` (2,) without touching anything."""
    k = after + 1
    ins = lambda x, v: np.concatenate([x[:k], np.repeat(np.asarray(v)[None], passes, axis=0), x[k:]])  # noqa: E731
    return Actions(ee_start=ins(a.ee_start, start), ee_end=ins(a.ee_end, end), touch=ins(a.touch, False),
                   contact=ins(a.contact, [np.nan, np.nan]), push=ins(a.push, [0.0, 0.0]), gripper=a.gripper)


def test_free_space_between_two_touches_counts_once_per_cell():
    # Between two touches the gripper passes the same way across the box's near side, once or three times: the
    # particles stay where they are, so with free_stretches three passes weigh as one; counted per action they
    # weigh three times as much
    local, _ = _faces(6)
    truth = np.array([[0.43, 0.0, 0.2]] * 6)
    a = _pushes(truth, local, np.zeros((6, 2)))
    lattice = np.array([[x, y] for x in np.arange(-0.02, 0.021, 0.01) for y in np.arange(-0.02, 0.021, 0.01)])
    start, end = np.array([0.37, -0.12]), np.array([0.37, 0.12])

    def filtered(passes, params):
        b = _with_passes(a, 2, passes, start, end)
        _, radius = target_reach(BOX, b.contact[b.touch])
        return run_filter(BOX, b, free_space_of(b, lattice, params, radius), params, np.random.default_rng(2))

    stretches = PushTrackParams(motion="push", free_stretches=True)
    once, thrice = filtered(1, stretches), filtered(3, stretches)
    assert thrice.log_evidence == once.log_evidence
    np.testing.assert_array_equal(thrice.poses, once.poses)
    np.testing.assert_array_equal(thrice.log_w, once.log_w)
    per_action = PushTrackParams(motion="push", free_stretches=False)
    assert filtered(1, per_action).log_evidence == once.log_evidence  # one action: the same observation
    assert filtered(3, per_action).log_evidence < once.log_evidence  # the passes cut into some particles
    none = filtered(0, stretches)
    assert none.log_evidence > once.log_evidence and np.all(np.isfinite(once.log_w))
