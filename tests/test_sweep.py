"""The gripper's slice as the pusher (pipeline/estimators/pushtrack/slice_pusher.py) and the pushtrack filter's
"sweep" motion."""
import math

import numpy as np
import pytest

from pipeline.estimators.pushtrack.filter import Actions, PushTrackParams, run_filter
from pipeline.estimators.pushtrack.quasistatic import limit_surface_length
from pipeline.estimators.pushtrack.slice_pusher import cached_gripper_slice, gripper_slice, sweep_push, target_outline
from pipeline.geometry import Primitive
from pipeline.robot import disc_sdf, panda_sdf

BOX = Primitive(kind="box", half=(0.03, 0.08), centre=np.zeros(2), yaw=0.0, name="box")
CAN = Primitive(kind="cylinder", half=(0.04,), centre=np.zeros(2), yaw=0.0, name="can")
DISC_R = 0.02
TIP = (PushTrackParams.tip_spread, PushTrackParams.tip_reach)


@pytest.fixture(scope="module")
def disc():
    return gripper_slice(disc_sdf(DISC_R))


def _push(prim, pose, grip, g0, g1, substeps=15, mu=0.5):
    return sweep_push(prim, np.atleast_2d(np.asarray(pose, dtype=float)), grip, target_outline(prim),
                      np.asarray(g0, dtype=float), np.asarray(g1, dtype=float), substeps,
                      1.5 * limit_surface_length(prim), mu)


def test_the_slice_is_its_outline(disc):
    # a disc's simplified zero contour: vertices on the circle, normals pointing out
    r = np.hypot(disc.points[:, 0], disc.points[:, 1])
    assert len(disc.points) >= 8 and np.all(np.abs(r - DISC_R) < 0.002)
    assert np.all(np.sum(disc.points * disc.normals, axis=1) > 0.0)


def test_a_head_on_push_translates_by_what_follows_the_touch(disc):
    # The disc starts 1 cm short of the box's face and moves 3 cm through its centre line: the box moves about 2 cm
    # along the push and does not turn.
    face = 0.0 - BOX.half[0]
    g0 = np.array([face - DISC_R - 0.01, 0.0])
    out = _push(BOX, [0.0, 0.0, 0.0], disc, g0, g0 + [0.03, 0.0])[0]
    assert out[0] == pytest.approx(0.02, abs=0.0025)
    assert abs(out[1]) < 1e-6 and abs(out[2]) < 1e-6


def test_a_box_out_of_reach_stays_where_it_is(disc):
    # the sweep ends 1 cm short of the face: nothing moves, to the bit
    pose = np.array([[0.0, 0.0, 0.3], [0.5, 0.5, -1.0]])
    g0 = np.array([-0.2, 0.0])
    out = sweep_push(BOX, pose, disc, target_outline(BOX), g0, g0 + [0.03, 0.0], 15, 0.05, 0.5)
    assert np.array_equal(out, pose)


def test_an_off_centre_push_turns_the_box_away_from_the_pusher(disc):
    # pushing the face at x = -hx in +x above the centre (y > 0) turns the box clockwise (negative yaw)
    g0 = np.array([-BOX.half[0] - DISC_R - 0.002, 0.06])
    out = _push(BOX, [0.0, 0.0, 0.0], disc, g0, g0 + [0.03, 0.0])[0]
    assert out[2] < -0.05 and out[0] > 0.005


def test_a_cylinder_is_pushed_along_the_line_through_its_centre(disc):
    g0 = np.array([-CAN.half[0] - DISC_R - 0.005, 0.0])
    out = _push(CAN, [0.0, 0.0, 0.0], disc, g0, g0 + [0.03, 0.0])[0]
    assert out[0] == pytest.approx(0.025, abs=0.0025) and abs(out[1]) < 1e-6


def test_a_pusher_moving_away_pushes_nothing(disc):
    g0 = np.array([-BOX.half[0] - DISC_R + 0.001, 0.0])  # touching, then backing off
    out = _push(BOX, [0.0, 0.0, 0.0], disc, g0, g0 - [0.03, 0.0])[0]
    assert np.array_equal(out, np.zeros(3))


def test_hard_poses_stay_finite_and_a_zero_move_is_a_no_op(disc):
    # the gripper starting deep inside the box, on its centre, on a corner; and no motion at all
    poses = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [-0.03, 0.08, 0.0], [0.0, 0.0, math.pi / 4]])
    for g1 in ([0.03, 0.0], [0.0, 0.0]):
        out = sweep_push(BOX, poses, disc, target_outline(BOX), np.zeros(2), np.asarray(g1, dtype=float), 15,
                         0.05, 0.5)
        assert np.all(np.isfinite(out))
    assert np.array_equal(out, poses)


def test_the_panda_slice_pushes_a_box_with_its_flat_face():
    # The Panda hand's slice is wide (about 20 cm across y): a box in front of its +x fingers' face, pushed
    # straight, moves along +x and barely turns.
    grip = cached_gripper_slice(panda_sdf())
    assert cached_gripper_slice(panda_sdf()) is grip and len(grip.points) > 8
    front = float(np.max(grip.points[:, 0]))
    pose = [front + BOX.half[0] + 0.005, 0.0, 0.0]
    out = _push(BOX, pose, grip, np.zeros(2), np.array([0.03, 0.0]))[0]
    assert out[0] - pose[0] == pytest.approx(0.025, abs=0.004) and abs(out[2]) < 0.05


def test_the_filter_needs_the_gripper_for_the_sweep():
    contact = np.array([[0.0, 0.0], [0.01, 0.0]])
    a = Actions(ee_start=contact - 0.02, ee_end=contact, touch=np.ones(2, dtype=bool), contact=contact,
                push=np.full((2, 2), 0.005))
    with pytest.raises(ValueError, match="gripper"):
        run_filter(BOX, a, lambda rows, centre: np.zeros((0, 2)), PushTrackParams(motion="sweep", n_particles=16),
                   np.random.default_rng(0))


def test_the_filter_tracks_a_box_the_slice_pushed(disc):
    # Three pushes of the disc against a box: the filter with the sweep motion gives finite normalised weights and
    # its best particles' surface passes through the last contact.
    rng = np.random.default_rng(3)
    truth = np.array([0.0, 0.0, 0.0])
    ee_start, ee_end, contact, push = [], [], [], []
    g = np.array([-BOX.half[0] - DISC_R - 0.005, 0.02])
    for _ in range(3):
        g1 = g + [0.02, 0.0]
        after = _push(BOX, truth, disc, g, g1)[0]
        ee_start.append(g), ee_end.append(g1)
        contact.append(g1 + [DISC_R, 0.0])
        push.append(g1 - g - [0.005 if not ee_start[:-1] else 0.0, 0.0])
        truth, g = after, g1
    a = Actions(ee_start=np.array(ee_start), ee_end=np.array(ee_end), touch=np.ones(3, dtype=bool),
                contact=np.array(contact), push=np.array(push), gripper=disc)
    res = run_filter(BOX, a, lambda rows, centre: np.zeros((0, 2)), PushTrackParams(motion="sweep", n_particles=256),
                     rng)
    assert res is not None and np.all(np.isfinite(res.log_w)) and np.all(np.isfinite(res.poses))
    assert float(np.sum(np.exp(res.log_w))) == pytest.approx(1.0)
    best = res.poses[np.argsort(res.log_w)[-10:]]
    sd = [BOX.signed_distance(a.contact[-1][None], p)[0] for p in best]
    assert np.median(np.abs(sd)) < 0.01


def _corner_world(pose, corner):
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return np.array([pose[0] + c * corner[0] - s * corner[1], pose[1] + s * corner[0] + c * corner[1]])


@pytest.mark.parametrize("offset, spread, reach, far", [
    (0.04, 0.08, 1.27, 0.08 * (1 + 0.08 * 0.08 / 0.04)),  # near an end: just beyond the far corner
    (0.012, 0.08, 1.27, 0.08 * 1.27),  # nearer the middle: at reach * hy
    (0.04, 0.0, 1.0, 0.08),  # the far corner itself
])
def test_tip_turns_a_box_pushed_on_its_long_face_about_a_point_of_the_leading_edge(disc, offset, spread, reach, far):
    # The -x long face pushed in +x at y = +offset: the leading edge is x = +hx, and the centre of rotation is
    # hy * min(1 + spread * hy / offset, reach) along it on the far side (-y). The slice's contact moves a little
    # along the face as the box turns, so the point is checked where the turn starts: the first of 15 steps.
    hx, hy = BOX.half
    g0 = np.array([-hx - DISC_R - 0.0001, offset])
    step = sweep_push(BOX, np.zeros((1, 3)), disc, target_outline(BOX), g0, g0 + [0.002, 0.0], 1, 0.05, 0.5,
                      tip=(spread, reach))[0]
    assert step[2] < 0.0  # pushed above the centre in +x: it turns clockwise
    assert np.hypot(*(_corner_world(step, (hx, -far)) - [hx, -far])) < 1e-6
    # a whole 2 cm push turns it by about 2 cm over the contact's distance from that point
    out = sweep_push(BOX, np.zeros((1, 3)), disc, target_outline(BOX), g0, g0 + [0.02, 0.0], 15, 0.05, 0.5,
                     tip=(spread, reach))[0]
    assert -out[2] == pytest.approx(0.02 / (offset + far), rel=0.2)


def test_tip_mirrored_turns_the_other_way_about_the_other_corner(disc):
    # The +x long face pushed in -x at y = -4 cm: the leading edge is x = -hx, the far side +y; still clockwise
    hx, hy = BOX.half
    far = hy * min(1 + TIP[0] * hy / 0.04, TIP[1])
    g0 = np.array([hx + DISC_R + 0.0001, -0.04])
    step = sweep_push(BOX, np.zeros((1, 3)), disc, target_outline(BOX), g0, g0 - [0.002, 0.0], 1, 0.05, 0.5,
                      tip=TIP)[0]
    assert step[2] < 0.0
    assert np.hypot(*(_corner_world(step, (-hx, far)) - [-hx, far])) < 1e-6


def test_tip_is_a_pair_or_none_not_a_flag(disc):
    args = (target_outline(BOX), np.zeros(2), np.array([0.01, 0.0]), 15, 0.05, 0.5)
    with pytest.raises(TypeError, match="tip"):
        sweep_push(BOX, np.zeros((1, 3)), disc, *args, tip=True)


def test_tip_leaves_end_faces_and_cans_to_the_limit_surface(disc):
    hx, hy = BOX.half
    g0 = np.array([0.01, -hy - DISC_R - 0.001])  # the -y end face, pushed in +y
    args = (target_outline(BOX), g0, g0 + [0.0, 0.02], 15, 0.05, 0.5)
    assert np.array_equal(sweep_push(BOX, np.zeros((1, 3)), disc, *args, tip=TIP),
                          sweep_push(BOX, np.zeros((1, 3)), disc, *args))
    g0 = np.array([-CAN.half[0] - DISC_R - 0.001, 0.01])
    args = (target_outline(CAN), g0, g0 + [0.02, 0.0], 15, 0.05, 0.5)
    assert np.array_equal(sweep_push(CAN, np.zeros((1, 3)), disc, *args, tip=TIP),
                          sweep_push(CAN, np.zeros((1, 3)), disc, *args))


def test_tip_pushes_a_centred_long_face_straight(disc):
    hx, _ = BOX.half
    g0 = np.array([-hx - DISC_R - 0.001, 0.0])
    out = sweep_push(BOX, np.zeros((1, 3)), disc, target_outline(BOX), g0, g0 + [0.02, 0.0], 15, 0.05, 0.5,
                     tip=TIP)[0]
    assert np.all(np.isfinite(out)) and abs(out[2]) < 1e-3 and out[0] == pytest.approx(0.019, abs=0.002)
