"""STUCCO soft tracking (pipeline/track/soft.py, pipeline/track/kernels.py): known answers, invariants, hard cases."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.special import logsumexp
from sklearn.metrics import fowlkes_mallows_score

from pipeline.track.base import ContactTracker, StepResult
from pipeline.track.kernels import free_space_penetration, penetration_bruteforce
from pipeline.track.soft import SoftTracker, SoftTrackingParams

RADIUS = 0.05  # disc robot, m
HALF = 0.05  # half side of the boxes, m
TOL = SoftTrackingParams().tolerance
FREE = np.array([0.0, 0.4])  # a free-space pose far from both boxes


def two_box_stream(step=0.01, offsets=(-0.01, 0.0, 0.01, 0.005), n_push=4, shift=(0.0, 0.0)):
    """Box A (0.1 m square centred at (-0.3, 0)) pushed n_push times in +x on its left face, then box B (centred at
    (0.3, 0), 0.6 m away) pushed in +y on its bottom face, with free-space steps before and after each.

    The disc touches the face at ``p = x + RADIUS * u`` (u the push direction) and the box moves with it by
    ``dx = step * u``; contacts are spread along the face by ``offsets``.

    Returns
    -------
    steps : list of (x, dx (1, 2) or None, p (1, 2) or None)
    obj : ndarray, shape (M,)
        True object of each contact.
    truth : ndarray, shape (M, 2)
        Where each contact point is at the end (it moves with every later push of its box).
    """
    shift = np.asarray(shift, dtype=float)
    centres = {0: np.array([-0.3, 0.0]), 1: np.array([0.3, 0.0])}
    dirs = {0: np.array([1.0, 0.0]), 1: np.array([0.0, 1.0])}
    steps, obj, disp, truth = [], [], [], []
    for o in (0, 1):
        steps.append((FREE + shift, None, None))
        u = dirs[o]
        tangent = np.array([-u[1], u[0]])
        for i in range(n_push):
            d = step * u
            centres[o] = centres[o] + d
            p = centres[o] - HALF * u + offsets[i % len(offsets)] * tangent + shift
            steps.append((p - RADIUS * u, d[None], p[None]))
            obj.append(o)
            disp.append(d)
            truth.append(p)
        steps.append((FREE + shift, None, None))
    obj, disp, truth = np.array(obj), np.array(disp), np.array(truth)
    for i in range(len(truth)):
        later = (np.arange(len(truth)) > i) & (obj == obj[i])
        truth[i] = truth[i] + disp[later].sum(axis=0)
    return steps, obj, truth


def make(robot, seed=0, **params):
    return SoftTracker(robot, SoftTrackingParams(**params), rng=np.random.default_rng(seed))


def assert_weights_sane(tracker):
    lw = tracker.log_weights_
    assert lw.shape == (tracker.params.n_particles,)
    assert np.all(np.isfinite(lw)), lw
    assert logsumexp(lw) == pytest.approx(0.0, abs=1e-9)
    assert np.all(np.isfinite(tracker.penetration_())) and np.all(tracker.penetration_() <= 0.0)
    assert 0.0 < tracker.last_step_.ess <= 1.0


def assert_labels_sane(tracker):
    labels = tracker.labels()
    assert labels.shape == (tracker.n_points_,) and labels.dtype == np.int64
    if labels.size:
        # canonical: 0..k-1 in order of first appearance
        first = np.unique(labels, return_index=True)[1]
        np.testing.assert_array_equal(labels[np.sort(first)], np.arange(labels.max() + 1))


def run(tracker, steps, check=None):
    for x, dx, p in steps:
        tracker.update(x, dx, p)
        assert_weights_sane(tracker)
        if check is not None:
            check(tracker)
    return tracker


def assert_bookkeeping_exact(tracker):
    """The incremental per-point penetration equals a from-scratch evaluation through GridSDF.query."""
    m = tracker.n_points_
    colpen, npen = penetration_bruteforce(tracker._P, tracker._C, m, tracker.robot.query, tracker.params.tolerance)
    np.testing.assert_array_equal(tracker._npen[:, :m], npen)
    np.testing.assert_allclose(tracker._colpen[:, :m], colpen, rtol=0, atol=1e-12)


# ------------------------------------------------------------------------------------------------ known answers
def test_implements_the_tracker_interface(disc):
    tracker = make(disc, n_particles=4)
    assert isinstance(tracker, ContactTracker)
    info = tracker.update(FREE)
    assert isinstance(info, StepResult) and tracker.points_.shape == (0, 2) and tracker.labels().shape == (0,)


@pytest.mark.parametrize("weighting", ["reference", "paper"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_two_pushed_boxes_segmented_and_tracked(disc, seed, weighting):
    steps, obj, truth = two_box_stream()
    tracker = run(make(disc, seed, n_particles=50, weighting=weighting), steps)
    assert fowlkes_mallows_score(obj, tracker.labels()) == 1.0
    # within 5 mm of where the true contact points are now (untracked, the first contacts would be 3 cm off)
    assert np.linalg.norm(tracker.points_ - truth, axis=1).max() < 5e-3
    assert tracker.points_.shape == (len(obj), 2) and tracker.particle_points_.shape == (50, len(obj), 2)


def test_new_contact_enters_at_its_pre_motion_location_and_moves_with_its_push(disc):
    tracker = make(disc, n_particles=8)
    x, dx, p = np.array([0.1, 0.0]), np.array([[0.01, 0.0]]), np.array([[0.15, 0.0]])
    tracker.update(x, dx, p)
    np.testing.assert_array_equal(tracker.particle_points_, np.broadcast_to(p, (8, 1, 2)))
    np.testing.assert_array_equal(tracker.particle_configs_, np.broadcast_to(x, (8, 1, 2)))
    np.testing.assert_array_equal(tracker.labels(), [0])


def test_point_the_robot_later_sweeps_through_is_moved_away(disc):
    """A and B on one object 0.1 m apart; pushing the object 6 cm at B moves A along only in the particles that
    connect them (p = exp(-0.01/0.02) = 0.61). The robot centre then visits A's old location in free space, which
    the push emptied: particles that left A behind penetrate 4.8 cm and lose, so the MAP particle has no point
    there."""
    sweep = np.array([0.0, 0.0])  # A's old place; A's new place (0.06, 0) and B (0.06, 0.1) are outside the disc
    for seed in range(6):
        tracker = make(disc, seed, n_particles=40)
        tracker.update([-RADIUS, 0.0], [[0.0, 0.0]], [[0.0, 0.0]])  # touch A at (0, 0)
        tracker.update([0.01, 0.1], [[0.06, 0.0]], [[0.06, 0.1]])  # push the object 6 cm in +x at B
        a = tracker.particle_points_[:, 0]
        left_behind = np.all(a == 0.0, axis=1)
        assert np.all(left_behind | np.all(a == [0.06, 0.0], axis=1))
        assert left_behind.any(), "the scenario must start with particles that left A behind"
        for _ in range(5):
            tracker.update(sweep)
            assert_weights_sane(tracker)
        assert np.all(disc.query(tracker.points_ - sweep) + TOL >= 0.0), "MAP point still inside the swept robot"
        np.testing.assert_array_equal(tracker.points_[0], [0.06, 0.0])
        # and the posterior as a whole left the swept place (before the sweeps: 25-55 % of the particles)
        still_behind = np.all(tracker.particle_points_[:, 0] == 0.0, axis=1)
        assert np.exp(tracker.log_weights_)[still_behind].sum() < 0.01


def test_point_inside_a_later_contact_config_is_replaced(disc):
    """A at (0, 0); then a contact whose robot body covers A (config 2 cm from A). With l tiny A never moves with
    it, so A is inconsistent in every particle and Alg. 2 (run every step, as printed in Alg. 1) replaces it by the
    nearest consistent point, configuration included."""
    tracker = make(disc, n_particles=6, length=1e-4, replace="every-step")
    tracker.update([-RADIUS, 0.0], [[0.0, 0.0]], [[0.0, 0.0]])
    x2, p2 = np.array([0.02, 0.0]), np.array([0.07, 0.0])
    assert disc.query(np.array([0.0, 0.0]) - x2) + TOL < 0  # A is 3 cm inside the robot at x2
    tracker.update(x2, [[0.001, 0.0]], [p2])
    # points_ is the MAP particle as weighted, before replacement (the authors' convention); the particles
    # themselves carry the replacement into the next step.
    assert disc.query(tracker.points_ - x2).min() + TOL < 0.0
    assert disc.query(tracker.particle_points_[0] - x2).min() + TOL >= 0.0
    assert tracker.last_step_.n_replaced == 6  # one point in each particle
    np.testing.assert_array_equal(tracker.particle_points_, np.broadcast_to(p2, (6, 2, 2)))
    np.testing.assert_array_equal(tracker.particle_configs_, np.broadcast_to(x2, (6, 2, 2)))
    assert np.all(tracker._npen[:, :2] == 0) and np.all(tracker.penetration_() == 0.0)
    assert_bookkeeping_exact(tracker)


def test_replace_never_keeps_inconsistent_points(disc):
    tracker = make(disc, n_particles=6, length=1e-4, replace="never", ess_threshold=1.0)
    tracker.update([-RADIUS, 0.0], [[0.0, 0.0]], [[0.0, 0.0]])
    tracker.update([0.02, 0.0], [[0.001, 0.0]], [[0.07, 0.0]])
    assert tracker.last_step_.n_replaced == 0
    np.testing.assert_array_equal(tracker.points_[0], [0.0, 0.0])
    assert np.all(tracker._npen[:, 0] == 1)
    assert_bookkeeping_exact(tracker)


# ------------------------------------------------------------------------------------------------ invariants
@pytest.mark.parametrize("seed", [0, 5])
def test_translating_every_input_translates_every_output(disc, seed):
    # A whole number of grid cells (1 mm): the two-box stream's point-to-config offsets are whole cells too, so
    # the shift keeps every nearest-cell lookup far from a rounding boundary and no penetration term can flip;
    # an arbitrary shift could move an offset across a half-cell and legitimately change a weight.
    shift = np.array([0.137, -0.042])
    steps, _, _ = two_box_stream(n_push=5)
    moved_steps, _, _ = two_box_stream(n_push=5, shift=shift)
    params = dict(n_particles=30, ess_threshold=0.95)
    base = run(make(disc, seed, **params), steps)
    moved = run(make(disc, seed, **params), moved_steps)
    np.testing.assert_allclose(moved.points_, base.points_ + shift, rtol=0, atol=1e-9)
    np.testing.assert_allclose(moved.particle_points_, base.particle_points_ + shift, rtol=0, atol=1e-9)
    np.testing.assert_allclose(moved.particle_configs_, base.particle_configs_ + shift, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(moved.labels(), base.labels())
    np.testing.assert_allclose(moved.log_weights_, base.log_weights_, atol=1e-9)


def _random_stream(rng, n_steps, spread=0.1, max_k=3, p_free=0.3):
    """Steps with 1..max_k contacts on the disc's surface (one shared pose per step), random in-contact
    displacements up to 2 cm, and free-space steps, all inside a `spread`-wide square so points and configs
    overlap often."""
    steps = []
    for _ in range(n_steps):
        x = rng.uniform(-spread, spread, 2)
        if rng.random() < p_free:
            steps.append((x, None, None))
            continue
        k = int(rng.integers(1, max_k + 1))
        ang = rng.uniform(0, 2 * np.pi, k)
        p = x + RADIUS * np.c_[np.cos(ang), np.sin(ang)]
        steps.append((x, rng.uniform(-0.02, 0.02, (k, 2)), p))
    return steps


@pytest.mark.parametrize("replace, ess_threshold", [("after-resample", 1.0), ("every-step", 0.8),
                                                    ("every-step", 1.0), ("never", 0.8)])
def test_incremental_penetration_equals_brute_force(disc, replace, ess_threshold):
    seen = dict(pen=0, resampled=0, replaced=0)

    def check(tracker):
        assert_bookkeeping_exact(tracker)
        np.testing.assert_allclose(tracker.penetration_(), tracker._colpen[:, : tracker.n_points_].sum(axis=1))
        seen["pen"] += int(tracker._npen[:, : tracker.n_points_].sum())
        seen["resampled"] += tracker.last_step_.resampled
        seen["replaced"] += tracker.last_step_.n_replaced

    for seed in range(3):
        rng = np.random.default_rng(seed)
        tracker = make(disc, seed, n_particles=12, replace=replace, ess_threshold=ess_threshold)
        run(tracker, _random_stream(rng, 25), check)
    # the bookkeeping was exercised, not vacuous
    assert seen["resampled"] > 0
    if replace == "never":
        assert seen["pen"] > 0 and seen["replaced"] == 0
    else:
        assert seen["replaced"] > 0


def test_free_space_penetration_kernel_equals_brute_force(disc):
    rng = np.random.default_rng(3)
    tracker = run(make(disc, 3, n_particles=10, replace="never"), _random_stream(rng, 15, p_free=0.0))
    m = tracker.n_points_
    for _ in range(30):
        x = rng.uniform(-0.12, 0.12, 2)
        eps = free_space_penetration(tracker._P, m, x, *tracker._grid, tracker._lo, tracker._hi, TOL)
        expect = np.minimum(disc.query(tracker.particle_points_ - x) + TOL, 0.0).sum(axis=1)
        np.testing.assert_allclose(eps, expect, rtol=0, atol=1e-12)


def test_incremental_penetration_equals_brute_force_on_half_cell_offsets(disc):
    # contact data on a 0.5 mm lattice (e.g. rounded sensor output) puts point-to-config offsets on cell edges
    tracker = make(disc, n_particles=2, replace="never")
    tracker.update([0.0, 0.0], [[0.0, 0.0]], [[0.0065, 0.0]])
    assert_bookkeeping_exact(tracker)


# ------------------------------------------------------------------------------------------------ hard cases
@pytest.mark.parametrize("weighting, weight_floor", [("reference", 1e-15), ("paper", 1e-15), ("paper", 0.0),
                                                     ("reference", 0.0)])
def test_all_particles_penetrating_deeply_stays_finite(disc, weighting, weight_floor):
    # each config sits on the previous contact point: every point is 5 cm deep inside the next config, in every
    # particle, whatever the sampled connections; small pushes make the particles differ
    rng = np.random.default_rng(0)
    tracker = make(disc, 0, n_particles=20, weighting=weighting, weight_floor=weight_floor, replace="every-step")
    x = np.zeros(2)
    for i in range(16):
        u = np.array([1.0, 0.0]) if i % 2 == 0 else np.array([-1.0, 0.0])
        p = x + RADIUS * u
        tracker.update(x, rng.uniform(-0.003, 0.003, (1, 2)), p[None])
        assert_weights_sane(tracker)
        assert_labels_sane(tracker)
        x = p
    assert np.all(tracker.penetration_() < -0.04 * 8)
    assert np.all(tracker._npen[:, : tracker.n_points_] > 0), "every point penetrates in every particle"
    assert np.all(np.isfinite(tracker.points_))


def test_tiny_length_underflows_but_weights_stay_finite(disc):
    # exp(-d^2 / 1e-300) underflows to 0: no point ever connects to another, and Alg. 3 gives singletons
    steps, obj, _ = two_box_stream()
    tracker = run(make(disc, n_particles=10, length=1e-300), steps)
    np.testing.assert_array_equal(tracker.labels(), np.arange(len(obj)))
    assert np.all(np.isfinite(tracker.points_))


@pytest.mark.parametrize("weighting", ["reference", "paper"])
def test_coincident_points_from_repeated_zero_displacement_contact(disc, weighting):
    tracker = make(disc, n_particles=10, weighting=weighting)
    p = np.array([[0.05, 0.0]])
    for _ in range(12):
        tracker.update([0.0, 0.0], np.zeros((1, 2)), p)
        assert_weights_sane(tracker)
    np.testing.assert_array_equal(tracker.points_, np.repeat(p, 12, axis=0))
    np.testing.assert_array_equal(tracker.labels(), np.zeros(12))
    assert np.all(tracker.penetration_() == 0.0)


def test_several_coincident_contacts_in_one_step(disc):
    tracker = make(disc, n_particles=5)
    tracker.update([0.0, 0.0], np.zeros((4, 2)), np.full((4, 2), 0.05 / np.sqrt(2)))
    assert_weights_sane(tracker)
    np.testing.assert_array_equal(tracker.labels(), np.zeros(4))


def test_single_point(disc):
    tracker = make(disc, n_particles=3)
    tracker.update([0.0, 0.0], [[0.0, 0.002]], [[0.0, 0.05]])
    assert_weights_sane(tracker)
    np.testing.assert_array_equal(tracker.points_, [[0.0, 0.05]])
    np.testing.assert_array_equal(tracker.labels(), [0])
    tracker.update(FREE)
    np.testing.assert_array_equal(tracker.points_, [[0.0, 0.05]])


def test_two_thousand_points(disc):
    rng = np.random.default_rng(1)
    tracker = make(disc, 1, n_particles=5)
    for _ in range(2):
        x = rng.uniform(-0.3, 0.3, 2)
        ang = rng.uniform(0, 2 * np.pi, 1000)
        p = rng.uniform(-0.5, 0.5, (1000, 2))
        p[:10] = x + RADIUS * np.c_[np.cos(ang[:10]), np.sin(ang[:10])]
        tracker.update(x, rng.uniform(-0.01, 0.01, (1000, 2)), p)
        assert_weights_sane(tracker)
    assert tracker.points_.shape == (2000, 2) and np.all(np.isfinite(tracker.points_))
    assert_labels_sane(tracker)


@pytest.mark.parametrize("weighting", ["reference", "paper"])
def test_zero_displacement_contacts_move_nothing(disc, weighting):
    steps, _, _ = two_box_stream()
    tracker = make(disc, n_particles=10, weighting=weighting)
    observed = []
    for x, dx, p in steps:
        if dx is not None:
            dx = np.zeros_like(dx)
            observed.append(p[0])
        tracker.update(x, dx, p)
        assert_weights_sane(tracker)
    np.testing.assert_array_equal(tracker.points_, observed)


@pytest.mark.parametrize("weighting", ["reference", "paper"])
@pytest.mark.parametrize("replace", ["after-resample", "every-step", "never"])
def test_weights_finite_and_normalised_after_every_update(disc, weighting, replace):
    rng = np.random.default_rng(8)
    tracker = make(disc, 8, n_particles=15, weighting=weighting, replace=replace)
    run(tracker, _random_stream(rng, 30), assert_labels_sane)


def test_free_space_before_any_contact_and_empty_contact_arrays(disc):
    tracker = make(disc, n_particles=4)
    info = tracker.update(FREE)
    assert info == StepResult(ess=1.0, resampled=False, n_replaced=0)
    tracker.update(FREE, np.zeros((0, 2)), np.zeros((0, 2)))  # K = 0 is free space
    assert tracker.n_points_ == 0
    np.testing.assert_array_equal(tracker.log_weights_, np.full(4, -np.log(4)))


@pytest.mark.parametrize("dx, p, match", [
    ([[0.0, 0.0]], None, "both be given"),
    (None, [[0.0, 0.0]], "both be given"),
    ([[0.0, 0.0]], [[0.0, 0.0], [1.0, 0.0]], "same shape"),
    ([[np.nan, 0.0]], [[0.0, 0.0]], "finite"),
    ([[0.0, 0.0]], [[np.inf, 0.0]], "finite"),
])
def test_update_rejects_bad_observations(disc, dx, p, match):
    with pytest.raises(ValueError, match=match):
        make(disc, n_particles=2).update([0.0, 0.0], dx, p)


def test_update_rejects_nan_pose_in_free_space(disc):
    tracker = make(disc, n_particles=3)
    tracker.update([0.0, 0.0], [[0.0, 0.0]], [[0.05, 0.0]])
    with pytest.raises(ValueError, match="finite"):
        tracker.update([np.nan, 0.0])


def test_rng_must_be_a_generator(disc):
    with pytest.raises(TypeError, match="numpy.random.Generator"):
        SoftTracker(disc, SoftTrackingParams(), rng=0)


# ------------------------------------------------------------------------------------------------ determinism
def test_same_seed_gives_identical_outputs(disc):
    rng_a, rng_b = np.random.default_rng(4), np.random.default_rng(4)
    a = run(make(disc, 11, n_particles=20), _random_stream(rng_a, 20))
    b = run(make(disc, 11, n_particles=20), _random_stream(rng_b, 20))
    np.testing.assert_array_equal(a.points_, b.points_)
    np.testing.assert_array_equal(a.particle_points_, b.particle_points_)
    np.testing.assert_array_equal(a.log_weights_, b.log_weights_)
    c = run(make(disc, 12, n_particles=20), _random_stream(np.random.default_rng(4), 20))
    assert not np.array_equal(a.particle_points_, c.particle_points_), "the seed must matter"


# ------------------------------------------------------------------------------------------------ parameters
def test_defaults_are_table_one():
    p = SoftTrackingParams()
    assert (p.length, p.penetration_length, p.alpha, p.n_particles) == (0.02, 0.002, 0.4, 100)
    assert p.to_dict()["weighting"] == "reference"
    with pytest.raises(AttributeError):
        p.length = 1.0  # frozen


@pytest.mark.parametrize("kwargs, match", [
    (dict(length=0.0), "length must be a positive finite number"),
    (dict(length=-1.0), "length must be a positive finite number"),
    (dict(length=float("nan")), "length must be a positive finite number"),
    (dict(penetration_length=float("inf")), "penetration_length must be a positive finite number"),
    (dict(n_particles=0), "n_particles must be a positive integer"),
    (dict(n_particles=2.0), "n_particles must be a positive integer"),
    (dict(tolerance=-0.001), "tolerance must be a non-negative finite number"),
    (dict(tolerance=float("nan")), "tolerance must be a non-negative finite number"),
    (dict(ess_threshold=1.5), r"ess_threshold must be in \[0, 1\]"),
    (dict(ess_threshold=float("nan")), r"ess_threshold must be in \[0, 1\]"),
    (dict(weight_floor=0.5, n_particles=2), r"weight_floor must be in \[0, 1/N\)"),
    (dict(weight_floor=-1e-3), r"weight_floor must be in \[0, 1/N\)"),
    (dict(weighting="raw"), "weighting must be one of reference, paper"),
    (dict(replace="always"), "replace must be one of after-resample, every-step, never"),
])
def test_params_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SoftTrackingParams(**kwargs)


def test_equal_weights_do_not_resample_at_threshold_one(disc):
    tracker = make(disc, n_particles=7, ess_threshold=1.0)
    tracker.update([0.0, 0.0], [[0.0, 0.0]], [[0.05, 0.0]])  # one consistent point: every particle identical
    assert tracker.last_step_.ess == 1.0
    assert not tracker.last_step_.resampled


def test_warm_up_without_contacts_takes_the_free_space_resampling_and_replacement_paths(disc):
    # make setup compiles these kernels in a second process beside the contact step's: the warm-up must reach
    # each of them (free space with points, a resampling step, Alg. 2 after it) with the weights left sane.
    tracker = make(disc, n_particles=4)
    tracker.warm_up_without_contacts(n_points=8)
    assert tracker.n_points_ == 8
    assert tracker.last_step_.resampled
    assert_weights_sane(tracker)
