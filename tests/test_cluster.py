"""Hard-tracking baselines (paper §V-A): BIRCH, DBSCAN, growing k-means, and GM-PHD through the wrapper."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from sklearn.metrics import fowlkes_mallows_score

from pipeline import registry
from pipeline.parallel import single_threaded
from pipeline.track.base import ContactTracker, StepResult
from pipeline.track.cluster import (
    BirchParams,
    DBSCANParams,
    GMPHDParams,
    HardTrackingWrapper,
    KMeansParams,
    compact_labels,
)
from pipeline.track.stage import build_tracker

#: The hard-tracking baselines of this module (the registered methods built by pipeline/track/cluster.py).
BASELINES = tuple(s.name for s in registry.trackers() if str(s.factory).startswith("pipeline.track.cluster:"))


@pytest.fixture(autouse=True, scope="module")
def _one_thread_per_library():
    """Run the baselines as every evaluation job runs them: one thread per numeric library
    (:func:`pipeline.parallel.single_threaded`). Under ``make test`` this process is one of two busy xdist workers
    on two cores, where scikit-learn's OpenMP threads only spin: a k-means fit of a dozen points took 160 ms on
    two threads and 6 ms on one, and this module's k-means tests 40 s instead of 2 (docs/evaluation.md,
    "Parallelism")."""
    with single_threaded():
        yield


def make_baseline(name, params, rng):
    return build_tracker(name, params, None, rng)

CLUSTERERS = ("birch", "dbscan", "kmeans")
HALF = 0.05  # half side of the square objects, m
FREE = np.array([0.0, 0.5])


def _two_box_stream(step: float, offsets: tuple[float, ...], n_push: int = 5, shift=(0.0, 0.0)):
    """Box A at (-0.5, 0) pushed n_push times in +x on its left face, then box B at (0.5, 0) pushed in +y on its
    bottom face, with free-space steps in between.

    Returns (steps, obj, gt): steps = [(x, dx, p)], obj (M,) ground-truth object of each contact, gt (M, 2) true
    final position of each contact point (it moves with every later push of its object).
    """
    shift = np.asarray(shift, dtype=float)
    centres = {0: np.array([-0.5, 0.0]), 1: np.array([0.5, 0.0])}
    pushes = {0: np.array([step, 0.0]), 1: np.array([0.0, step])}
    steps, obj, disp, gt = [], [], [], []
    for o in (0, 1):
        steps.append((FREE + shift, None, None))
        for i in range(n_push):
            d = pushes[o]
            centres[o] = centres[o] + d
            off = offsets[i % len(offsets)]
            face = np.array([-HALF, off]) if o == 0 else np.array([off, -HALF])
            p = centres[o] + face + shift
            steps.append((p - 0.4 * face, d[None], p[None]))
            obj.append(o)
            disp.append(d)
            gt.append(p)
        steps.append((FREE + shift, None, None))
    obj, disp, gt = np.array(obj), np.array(disp), np.array(gt)
    for i in range(len(gt)):
        later = (np.arange(len(gt)) > i) & (obj == obj[i])
        gt[i] = gt[i] + disp[later].sum(axis=0)
    return steps, obj, gt


@pytest.fixture
def poke_stream():
    """Each box poked 5 times at one spot of its face, 1 mm per push: every baseline (GM-PHD included) segments it."""
    return _two_box_stream(0.001, (0.0,))


@pytest.fixture
def spread_stream():
    """Each box pushed 5 times by 1 cm at contacts spread over 4 cm of its face."""
    return _two_box_stream(0.01, (-0.02, 0.0, 0.02, -0.01, 0.01))


def _run(tracker, steps):
    for x, dx, p in steps:
        tracker.update(x, dx, p)
    return tracker


def _make(name, seed=0, params=None):
    return make_baseline(name, params, np.random.default_rng(seed))


# ------------------------------------------------------------------------------------------------ known answers
@pytest.mark.parametrize("name", BASELINES)
def test_two_poked_boxes_segmented_and_tracked(name, poke_stream):
    steps, obj, gt = poke_stream
    tracker = _run(_make(name), steps)
    assert isinstance(tracker, ContactTracker)
    labels = tracker.labels()
    assert labels.dtype == np.int64 and labels.shape == obj.shape
    assert fowlkes_mallows_score(obj, labels) == 1.0
    np.testing.assert_allclose(tracker.points_, gt, atol=3e-3)


@pytest.mark.parametrize("name", CLUSTERERS)
def test_two_pushed_boxes_spread_contacts_segmented_and_tracked(name, spread_stream):
    steps, obj, gt = spread_stream
    tracker = _run(_make(name), steps)
    assert fowlkes_mallows_score(obj, tracker.labels()) == 1.0
    np.testing.assert_allclose(tracker.points_, gt, atol=1e-9)


@pytest.mark.parametrize("name", BASELINES)
def test_untouched_box_points_do_not_move(name, poke_stream):
    steps, obj, _ = poke_stream
    first_b = 1 + np.flatnonzero(obj == 0).size + 1  # free step, pushes on A, free step
    tracker = _run(_make(name), steps[:first_b])
    before = tracker.points_
    _run(tracker, steps[first_b:])
    np.testing.assert_array_equal(tracker.points_[: len(before)], before)


@pytest.mark.parametrize("name", BASELINES)
def test_translating_every_input_translates_every_output(name):
    shift = np.array([0.013, -0.021])
    base = _run(_make(name), _two_box_stream(0.001, (0.0,))[0])
    moved = _run(_make(name), _two_box_stream(0.001, (0.0,), shift=shift)[0])
    np.testing.assert_allclose(moved.points_, base.points_ + shift, atol=1e-9)
    np.testing.assert_array_equal(moved.labels(), base.labels())


@pytest.mark.parametrize("name", BASELINES)
def test_same_seed_gives_identical_outputs(name, spread_stream):
    steps, _, _ = spread_stream
    a = _run(_make(name, seed=7), steps)
    b = _run(_make(name, seed=7), steps)
    np.testing.assert_array_equal(a.points_, b.points_)
    np.testing.assert_array_equal(a.labels(), b.labels())


# ------------------------------------------------------------------------------------------------ wrapper logic
@pytest.mark.parametrize("name", BASELINES)
def test_free_space_steps_change_nothing(name):
    tracker = _make(name)
    tracker.update(FREE, None, None)
    assert tracker.points_.shape == (0, 2) and tracker.labels().shape == (0,)
    tracker.update(FREE, np.array([[0.01, 0.0]]), np.array([[-0.4, 0.0]]))
    before = tracker.points_
    for _ in range(3):
        tracker.update(FREE, None, None)
    np.testing.assert_array_equal(tracker.points_, before)


@pytest.mark.parametrize("name", BASELINES)
def test_single_contact_enters_at_pre_motion_and_moves_with_push(name):
    tracker = _make(name)
    tracker.update(FREE, np.array([[0.01, 0.0]]), np.array([[-0.4, 0.0]]))
    np.testing.assert_allclose(tracker.points_, [[-0.4, 0.0]])
    np.testing.assert_array_equal(tracker.labels(), [0])


@pytest.mark.parametrize("name", BASELINES)
def test_coincident_points_do_not_crash(name):
    tracker = _make(name)
    for _ in range(8):
        tracker.update(FREE, np.zeros((2, 2)), np.full((2, 2), 0.2))
    assert np.isfinite(tracker.points_).all() and tracker.points_.shape == (16, 2)
    np.testing.assert_array_equal(tracker.labels(), np.zeros(16))


@pytest.mark.parametrize("name", CLUSTERERS)
def test_several_contacts_move_each_cluster_by_mean_dx_of_its_new_points(name):
    steps, _, _ = _two_box_stream(0.01, (-0.02, 0.0, 0.02, -0.01, 0.01))
    tracker = _run(_make(name), steps)
    before, lab = tracker.points_, tracker.labels()
    a, b = before[0], before[-1]  # a point of each box
    dx = np.array([[0.01, 0.0], [0.02, 0.0], [0.0, 0.01]])
    p = np.array([a + [0.0, 0.005], a + [0.0, -0.005], b + [0.005, 0.0]]) + dx
    tracker.update(FREE, dx, p)
    after = tracker.points_
    np.testing.assert_allclose(after[: len(before)][lab == lab[0]], before[lab == lab[0]] + [0.015, 0.0])
    np.testing.assert_allclose(after[: len(before)][lab == lab[-1]], before[lab == lab[-1]] + [0.0, 0.01])
    np.testing.assert_allclose(after[len(before):], p - dx + [[0.015, 0.0], [0.015, 0.0], [0.0, 0.01]])


def test_dbscan_noise_points_are_never_moved_and_become_singletons():
    tracker = _make("dbscan", params={"eps": 0.05, "min_samples": 2})
    d = np.array([[0.01, 0.0]])
    tracker.update(FREE, d, np.array([[-0.5, 0.0]]) + d)  # alone: noise
    assert (tracker.labeller.final_labels(tracker.points_) == -1).all()
    np.testing.assert_allclose(tracker.points_, [[-0.5, 0.0]])  # not moved by its own push
    for y in (0.0, 0.01, 0.02):  # a dense group far away
        tracker.update(FREE, d, np.array([[0.5, y]]) + d)
    tracker.update(FREE, d, np.array([[0.0, 0.6]]) + d)  # another isolated point: noise
    pts = tracker.points_
    np.testing.assert_allclose(pts[0], [-0.5, 0.0])
    np.testing.assert_allclose(pts[-1], [0.0, 0.6])
    assert (tracker.labeller.final_labels(pts) == -1).sum() == 2
    labels = tracker.labels()
    assert len(set(labels[[0, 4]])) == 2 and labels[0] not in labels[1:4] and labels[4] not in labels[1:4]
    np.testing.assert_array_equal(np.sort(np.unique(labels)), np.arange(labels.max() + 1))


def test_kmeans_grows_k_only_with_enough_points():
    tracker = _make("kmeans")
    far = [(-0.5, 0.0), (-0.5, 0.01), (0.5, 0.0), (0.5, 0.01)]
    for q in far:  # two well separated pairs, but only 4 points
        tracker.update(FREE, np.zeros((1, 2)), np.array([q]))
    assert tracker.labeller.n_clusters_ == 1
    tracker.update(FREE, np.zeros((1, 2)), np.array([[0.5, 0.02]]))  # 5th point: growth allowed
    assert tracker.labeller.n_clusters_ == 2
    assert fowlkes_mallows_score([0, 0, 1, 1, 1], tracker.labels()) == 1.0


def test_kmeans_does_not_grow_without_a_5x_inertia_drop():
    # Evenly spaced points on a line: inertia(2) / inertia(1) tends to 1/4 > 0.2.
    tracker = _make("kmeans")
    for xq in np.linspace(-0.3, 0.3, 12):
        tracker.update(FREE, np.zeros((1, 2)), np.array([[xq, 0.0]]))
    assert tracker.labeller.n_clusters_ == 1
    # ...but it does with a looser ratio, and k never decreases afterwards.
    loose = _make("kmeans", params={"inertia_ratio": 0.3})
    for xq in np.linspace(-0.3, 0.3, 12):
        loose.update(FREE, np.zeros((1, 2)), np.array([[xq, 0.0]]))
    k = loose.labeller.n_clusters_
    assert k >= 2
    for _ in range(3):
        loose.update(FREE, np.zeros((1, 2)), np.array([[0.0, 0.0]]))
    assert loose.labeller.n_clusters_ >= k


# ------------------------------------------------------------------------------------------------ factory, errors
def test_baselines_are_the_four_of_the_paper():
    assert BASELINES == ("birch", "dbscan", "kmeans", "gmphd")


def test_make_baseline_unknown_name_lists_accepted_values():
    with pytest.raises(ValueError, match=r"unknown method 'hdbscan'; expected one of stucco, birch, dbscan, kmeans, "
                                         r"gmphd"):
        make_baseline("hdbscan", None, np.random.default_rng(0))


@pytest.mark.parametrize("name, fields", [
    ("birch", "threshold, branching_factor"),
    ("dbscan", "eps, min_samples"),
    ("kmeans", "inertia_ratio, min_points_to_grow, n_init, min_inertia"),
    ("gmphd", "birth, detection, q, r, bias"),
])
def test_make_baseline_unknown_parameter_lists_accepted_fields(name, fields):
    with pytest.raises(ValueError, match=rf"unknown parameter\(s\) 'foo' for method '{name}'; accepted: {fields}"):
        make_baseline(name, {"foo": 1}, np.random.default_rng(0))


def test_make_baseline_applies_overrides_and_dataclasses():
    t = make_baseline("dbscan", {"eps": 0.1}, np.random.default_rng(0))
    assert isinstance(t, HardTrackingWrapper)
    t.update(FREE, np.zeros((2, 2)), np.array([[0.0, 0.0], [0.08, 0.0]]))
    np.testing.assert_array_equal(t.labels(), [0, 0])
    g = make_baseline("gmphd", GMPHDParams.training_set(), np.random.default_rng(0))
    assert g.labeller.params.q == 0.1 and g.labeller.params.bias == 1.0
    assert dataclasses.asdict(t.params) == {"eps": 0.1, "min_samples": 1}  # full set, for output metadata


@pytest.mark.parametrize("cls, kwargs, match", [
    (BirchParams, {"threshold": 0.0}, "BirchParams.threshold"),
    (DBSCANParams, {"min_samples": 0}, "DBSCANParams.min_samples"),
    (KMeansParams, {"inertia_ratio": 1.5}, "KMeansParams.inertia_ratio"),
    (GMPHDParams, {"detection": 0.0}, "GMPHDParams.detection"),
])
def test_out_of_range_parameters_rejected(cls, kwargs, match):
    with pytest.raises(ValueError, match=match):
        cls(**kwargs)


def test_make_baseline_requires_a_generator():
    with pytest.raises(TypeError, match="numpy.random.Generator"):
        make_baseline("kmeans", None, 0)


def test_update_rejects_mismatched_inputs():
    t = _make("birch")
    with pytest.raises(ValueError, match="both be None"):
        t.update(FREE, None, np.zeros((1, 2)))
    with pytest.raises(ValueError, match=r"shape \(K, 2\)"):
        t.update(FREE, np.zeros((1, 2)), np.zeros((2, 2)))


def test_compact_labels_turns_noise_into_singletons_in_order_of_appearance():
    np.testing.assert_array_equal(compact_labels(np.array([3, -1, 3, 0, -1])), [0, 1, 0, 2, 3])
    assert compact_labels(np.array([], dtype=int)).shape == (0,)


@pytest.mark.parametrize("name", BASELINES)
def test_update_returns_the_step_result_of_a_tracker_without_particles(name):
    t = _make(name)
    assert t.update(FREE, None, None) == StepResult(ess=1.0, resampled=False, n_replaced=0)
    assert t.update(FREE, np.array([[0.01, 0.0]]), np.array([[-0.4, 0.0]])) == StepResult()
