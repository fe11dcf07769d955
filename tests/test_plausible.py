"""The plausible-set estimator: cost and gradients, known answers, free space, and the hard cases (finite output and
a named low-confidence reason for one point, two points, collinear points, a can, no free space, every hypothesis
penetrating)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.estimators.estimate import plausible_notes
from pipeline.estimators.plausible.evidence import free_space_points, gripper_lattice, recency_sigma
from pipeline.estimators.plausible.fit import PlausibleParams, consensus, evaluate_terms, fit_segment
from pipeline.estimators.target_model import pose_error
from pipeline.geometry import Primitive, com_pose, primitive_pose, primitive_sdf
from pipeline.retrieve import RetrievalParams
from pipeline.robot import disc_sdf

BOX = Primitive("box", (0.03, 0.079), np.array([0.002, -0.001]), 0.1, "box")
CAN = Primitive("cylinder", (0.0335,), np.array([0.004, 0.0]), 0.0, "can")
TRUE = np.array([0.40, -0.05, 0.6])
P = PlausibleParams()


def _surface(prim: Primitive, pose: np.ndarray, n: int, faces=None, seed: int = 0) -> np.ndarray:
    """n world points on the primitive's outline at COM pose ``pose`` (on the given box faces: 0 +x, 1 +y, 2 -x,
    3 -y)."""
    rng = np.random.default_rng(seed)
    if prim.kind == "cylinder":
        a = rng.uniform(0, 2 * np.pi, n)
        local = prim.half[0] * np.column_stack([np.cos(a), np.sin(a)])
    else:
        hx, hy = prim.half
        faces = faces or [0, 1, 2, 3]
        f = rng.choice(faces, n)
        t = rng.uniform(-1, 1, n)
        local = np.where((f == 0)[:, None], np.column_stack([np.full(n, hx), t * hy]),
                np.where((f == 2)[:, None], np.column_stack([np.full(n, -hx), t * hy]),
                np.where((f == 1)[:, None], np.column_stack([t * hx, np.full(n, hy)]),
                         np.column_stack([t * hx, np.full(n, -hy)]))))
    pp = primitive_pose(prim, pose)
    c, s = math.cos(pp[2]), math.sin(pp[2])
    return local @ np.array([[c, s], [-s, c]]) + pp[:2]


def _fit(prim, pts, steps=None, free=np.zeros((0, 2)), others=np.zeros((0, 2)), params=P, seed=0):
    steps = np.zeros(len(pts), dtype=np.int64) if steps is None else steps
    return fit_segment(prim, pts, recency_sigma(steps, params), free, others, params, np.random.default_rng(seed))


def test_primitive_sdf_matches_the_primitive_and_its_gradient_is_a_finite_difference():
    rng = np.random.default_rng(1)
    q = rng.uniform(-0.12, 0.12, (400, 2))
    for prim in (BOX, CAN):
        sd, g = primitive_sdf(prim, q)
        # Primitive.signed_distance works in the COM frame: map the primitive-frame points there.
        pp = np.array([0.0, 0.0, 0.0])
        com = com_pose(prim, pp)
        assert np.allclose(sd, prim.signed_distance(q, com), atol=1e-12)
        h = 1e-7
        num = np.stack([(primitive_sdf(prim, q + [h, 0])[0] - sd) / h,
                        (primitive_sdf(prim, q + [0, h])[0] - sd) / h], -1)
        away = np.abs(np.abs(q) - np.asarray(prim.half[:2] if prim.kind == "box" else [9, 9])).min(axis=1) > 1e-4
        ok = np.linalg.norm(num - g, axis=1) < 1e-4
        assert ok[away].mean() > 0.97  # kinks of the box (medial axis) aside
    assert np.all(np.isfinite(primitive_sdf(CAN, np.zeros((1, 2)))[1]))


def test_gauss_newton_gradient_matches_finite_differences_of_the_cost():
    pts = _surface(BOX, TRUE, 12, seed=2) + np.random.default_rng(3).normal(0, 0.002, (12, 2))
    free = np.array([[0.40, -0.05], [0.45, 0.0]])
    pose = primitive_pose(BOX, TRUE + [0.004, -0.003, 0.05])[None, :]
    sigma = recency_sigma(np.zeros(12, dtype=np.int64), P)
    terms, H, g = evaluate_terms(BOX, pose, pts, sigma, free, pts[:2] + 0.01, P, jacobian=True)
    assert np.all(np.linalg.eigvalsh(H[0]) >= -1e-9)
    assert np.all(np.isfinite(g))


def test_recency_sigma_grows_per_later_contact_and_never_overflows():
    s = recency_sigma(np.array([5, 5, 7, 9, 9, 9]), P)
    g = P.recency_growth
    assert np.allclose(s, P.contact_sigma * np.array([g ** 2, g ** 2, g, 1, 1, 1]))
    huge = recency_sigma(np.arange(5000), P)
    assert np.all(np.isfinite(huge)) and huge.max() == P.max_sigma


def test_points_on_two_faces_give_the_pose():
    pts = _surface(BOX, TRUE, 30, faces=[0, 1], seed=4)
    fit = _fit(BOX, pts)
    pos, yaw = pose_error(BOX, fit.poses[fit.chosen], TRUE)
    assert pos < 1e-3 and yaw < 1e-2
    assert fit.rms[fit.chosen] < 1e-3


def test_recent_points_outweigh_old_displaced_ones():
    new = _surface(BOX, TRUE, 20, faces=[0, 1], seed=5)
    old = _surface(BOX, TRUE + [0.03, 0.02, 0.3], 20, faces=[2, 3], seed=6)  # carried without turning
    steps = np.r_[np.full(20, 9), np.full(20, 1)]
    fit = _fit(BOX, np.vstack([new, old]), steps=np.r_[steps[:20], np.arange(1, 21) % 5 + 1])
    pos, yaw = pose_error(BOX, fit.poses[fit.chosen], TRUE)
    assert pos < 3e-3 and yaw < 0.03


def test_free_space_pushes_the_box_off_the_side_the_gripper_swept():
    # Points on one long face: the box could lie on either side; the gripper swept one side after the contact.
    pts = _surface(BOX, TRUE, 15, faces=[0], seed=7)
    sdf = disc_sdf(0.02, resolution=0.002)
    lattice = gripper_lattice(sdf, P.free_resolution)
    pp = primitive_pose(BOX, TRUE)
    inward = -np.array([math.cos(pp[2]), math.sin(pp[2])])  # from the +x face towards the centre
    ee = pts.mean(axis=0) + inward * np.array([[0.03], [0.06]])  # swept through where the box is... on the wrong side
    free_wrong = free_space_points(lattice, ee[:1], ee[1:], np.array([3]), 2, P, pts.mean(axis=0), 0.3)
    fit = _fit(BOX, pts, free=free_wrong)
    # With the truth's side swept, the estimate must lie on the other side of the face: outside the swept disc.
    c = BOX.centre_world(fit.poses[fit.chosen])
    assert np.dot(c - pts.mean(axis=0), inward) < 0.0
    assert fit.penetration[fit.chosen] <= P.free_tolerance + 1e-9


def test_free_space_points_only_after_the_last_contact():
    lattice = np.array([[0.0, 0.0]])
    starts = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    ends = np.array([[1.0, 0.0], [2.0, 0.0], [2.0, 1.0]])
    pts = free_space_points(lattice, starts, ends, np.array([0, 1, 2]), 1, P, np.array([2.0, 0.5]), 5.0)
    assert np.all(pts[:, 0] >= 2.0 - 1e-12)  # action 0 and the sweep of action 1 (before it ended) excluded
    assert pts[:, 1].min() == pytest.approx(0.0) and pts[:, 1].max() == pytest.approx(1.0)
    assert len(free_space_points(lattice, starts, ends, np.array([0, 1, 2]), 2, P, np.zeros(2), 0.5)) == 0


@pytest.mark.parametrize("case", ["one_point", "two_points", "collinear", "coincident", "thousands"])
def test_hard_point_sets_give_finite_poses_and_named_reasons(case):
    rng = np.random.default_rng(8)
    if case == "one_point":
        pts = np.array([[0.3, 0.1]])
    elif case == "two_points":
        pts = np.array([[0.3, 0.1], [0.31, 0.1]])
    elif case == "collinear":
        pts = np.column_stack([np.linspace(0.3, 0.36, 8), np.full(8, 0.1)])
    elif case == "coincident":
        pts = np.tile([[0.3, 0.1]], (6, 1))
    else:
        pts = _surface(BOX, TRUE, 3000, seed=9) + rng.normal(0, 0.001, (3000, 2))
    fit = _fit(BOX, pts)
    assert np.all(np.isfinite(fit.poses)) and np.all(np.isfinite(fit.terms.total))
    notes = plausible_notes(pts, fit, 0, BOX, RetrievalParams(), P)
    assert "no_free_space" in notes
    if case in ("one_point", "two_points"):
        assert "few_points" in notes
    if case in ("collinear", "coincident"):
        assert "collinear" in notes
    if case in ("one_point", "two_points", "collinear", "coincident"):
        assert "ambiguous_yaw" in notes or "wide_set" in notes
    if case == "thousands":
        assert pose_error(BOX, fit.poses[fit.chosen], TRUE)[0] < 2e-3


def test_a_can_has_no_yaw_to_disagree_on():
    pts = _surface(CAN, TRUE, 10, seed=10)
    fit = _fit(CAN, pts)
    assert fit.share == 1.0
    assert pose_error(CAN, fit.poses[fit.chosen], TRUE)[0] < 2e-3
    assert "ambiguous_yaw" not in plausible_notes(pts, fit, 5, CAN, RetrievalParams(), P)


def test_every_hypothesis_penetrating_is_finite_and_flagged():
    pts = _surface(BOX, TRUE, 12, faces=[0, 1], seed=11)
    # Free space everywhere around the points: no pose avoids it.
    g = np.stack(np.meshgrid(np.arange(-0.3, 0.3, 0.01), np.arange(-0.3, 0.3, 0.01)), -1).reshape(-1, 2)
    free = g + pts.mean(axis=0)
    fit = _fit(BOX, pts, free=free)
    assert np.all(np.isfinite(fit.poses)) and np.all(np.isfinite(fit.terms.total))
    assert np.all(fit.penetration > 0.01)
    assert "penetrating" in plausible_notes(pts, fit, len(free), BOX, RetrievalParams(), P)


def test_consensus_best_and_vote():
    yaw = np.array([0.0, 0.01, 0.02, 1.0, 1.01])
    cost = np.array([0.5, 0.6, 0.7, 0.0, 3.0])
    plausible = np.ones(5, dtype=bool)
    chosen, agree, share = consensus(yaw, cost, plausible, math.pi, P)
    assert chosen == 3 and agree.tolist() == [False, False, False, True, True]
    vote = PlausibleParams(pose_rule="vote")
    chosen, agree, share = consensus(yaw, cost, plausible, math.pi, vote)
    w = np.exp(-cost)
    assert chosen == 0 and share == pytest.approx(w[:3].sum() / w.sum())
    # Yaw is compared modulo the symmetry: pi - 0.01 agrees with 0.
    chosen, agree, _ = consensus(np.array([0.0, math.pi - 0.01]), np.zeros(2), np.ones(2, bool), math.pi, P)
    assert agree.all()


def test_same_seed_same_fit():
    pts = _surface(BOX, TRUE, 10, faces=[1], seed=12)
    a, b = _fit(BOX, pts, seed=3), _fit(BOX, pts, seed=3)
    assert np.array_equal(a.poses, b.poses) and a.chosen == b.chosen


@pytest.mark.parametrize("bad", [dict(n_hypotheses=0), dict(contact_sigma=-1.0), dict(recency_growth=0.5),
                                 dict(min_share=2.0), dict(pose_rule="mean"), dict(margin=float("nan"))])
def test_bad_parameters_are_refused(bad):
    with pytest.raises(ValueError):
        PlausibleParams(**bad)


def test_uniform_rule_picks_within_the_set_by_every_point():
    yaw = np.array([0.0, 0.5, 1.0])
    cost = np.array([0.0, 0.3, 5.0])  # the third is outside a 0.5 margin
    plausible = cost <= 0.5
    uniform = np.array([9.0, 1.0, 0.0])
    chosen, agree, _ = consensus(yaw, cost, plausible, math.pi, PlausibleParams(pose_rule="uniform"), uniform)
    assert chosen == 1 and agree.tolist() == [False, True, False]


def test_accurate_old_points_still_fix_the_yaw():
    # The newest contacts lie on one face only; old contacts on the other long face are exact (ideal data):
    # the uniform rule uses them, where the recency-weighted cost alone leaves the yaw loose.
    new = _surface(BOX, TRUE, 3, faces=[0], seed=13)
    old = _surface(BOX, TRUE, 12, faces=[1, 2], seed=14)
    steps = np.r_[np.full(3, 20), np.arange(12)]
    fit = _fit(BOX, np.vstack([new, old]), steps=steps)
    pos, yaw = pose_error(BOX, fit.poses[fit.chosen], TRUE)
    assert pos < 2e-3 and yaw < 0.01
