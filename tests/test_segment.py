"""Segmentation of tracked points into objects (Alg. 3) and the `segment` stage's table functions."""
from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest
from scipy.sparse.csgraph import connected_components

from pipeline import schema
from pipeline.segment import (
    canonical_labels,
    connection_radius,
    final_estimates,
    segment_points,
    segment_table,
    summarise,
)

L, ALPHA = 0.02, 0.4  # Table I
R = connection_radius(L, ALPHA)  # sqrt(0.02 ln 2.5) = 0.1354 m


def _alg3_reference(points, length, alpha):
    """Alg. 3 as printed: dense A_ij = exp(-d^2/l) > alpha, then connected components."""
    d2 = ((points[:, None, :] - points[None, :, :]) ** 2).sum(-1)
    with np.errstate(under="ignore"):
        adj = np.exp(-d2 / length) > alpha
    return canonical_labels(connected_components(adj, directed=False)[1])


# ------------------------------------------------------------------------------------------------ known answers
def test_connection_radius_matches_the_paper_threshold():
    assert R == pytest.approx(np.sqrt(L * np.log(1 / ALPHA)))
    # at the radius exp(-d^2/l) is alpha itself
    assert np.exp(-R**2 / L) == pytest.approx(ALPHA)
    assert connection_radius(L, 1.0) == 0.0 and connection_radius(L, 2.0) == 0.0
    assert connection_radius(L, 0.0) == np.inf and connection_radius(L, -1.0) == np.inf


def test_two_clusters_farther_than_the_radius_get_two_labels():
    a = np.array([[0.0, 0.0], [0.01, 0.0], [0.0, 0.02]])
    b = a + [R + 0.05, 0.0]
    labels = segment_points(np.vstack([a, b]), L, ALPHA)
    np.testing.assert_array_equal(labels, [0, 0, 0, 1, 1, 1])
    assert labels.dtype == np.int64


def test_chain_within_the_radius_is_one_component_even_out_of_order():
    # A, then C (1.8 R from A: not adjacent), then B between them: a one-pass "join the first group in reach"
    # grouping gives {A, B}, {C}; connected components join all three.
    pts = np.array([[0.0, 0.0], [1.8 * R, 0.0], [0.9 * R, 0.0]])
    np.testing.assert_array_equal(segment_points(pts, L, ALPHA), [0, 0, 0])
    # a long chain of 30 links, shuffled
    chain = np.c_[np.arange(30) * 0.95 * R, np.zeros(30)]
    chain = chain[np.random.default_rng(0).permutation(30)]
    np.testing.assert_array_equal(segment_points(chain, L, ALPHA), np.zeros(30))


def test_threshold_is_strict_a_pair_exactly_at_the_radius_is_not_connected():
    pts = np.array([[0.0, 0.0], [R, 0.0]])
    assert (pts[1, 0] - pts[0, 0]) ** 2 == R * R  # the pair sits exactly on the threshold
    np.testing.assert_array_equal(segment_points(pts, L, ALPHA), [0, 1])
    just_inside = np.array([[0.0, 0.0], [R * (1 - 1e-9), 0.0]])
    np.testing.assert_array_equal(segment_points(just_inside, L, ALPHA), [0, 0])


@pytest.mark.parametrize("alpha", [1.0, 1.5])
def test_alpha_at_least_one_gives_singletons(alpha):
    pts = np.zeros((4, 2))  # even coincident points: exp(0) = 1 is not > 1
    np.testing.assert_array_equal(segment_points(pts, L, alpha), np.arange(4))


@pytest.mark.parametrize("alpha", [0.0, -0.5])
def test_alpha_at_most_zero_gives_one_segment(alpha):
    pts = np.array([[0.0, 0.0], [50.0, -50.0], [-80.0, 3.0]])
    np.testing.assert_array_equal(segment_points(pts, L, alpha), np.zeros(3))


def test_empty_input():
    labels = segment_points(np.zeros((0, 2)), L, ALPHA)
    assert labels.shape == (0,) and labels.dtype == np.int64
    assert canonical_labels(np.array([], dtype=np.int64)).shape == (0,)


def test_single_point_and_coincident_points():
    np.testing.assert_array_equal(segment_points(np.array([[0.3, -0.2]]), L, ALPHA), [0])
    np.testing.assert_array_equal(segment_points(np.full((5, 2), 0.3), L, ALPHA), np.zeros(5))


def test_tiny_length_underflows_to_singletons():
    # exp(-d^2 / 1e-300) underflows to 0 for any distinct pair
    pts = np.array([[0.0, 0.0], [1e-6, 0.0], [0.0, 1e-6], [2e-6, 2e-6]])
    np.testing.assert_array_equal(segment_points(pts, 1e-300, ALPHA), np.arange(4))


def test_canonical_labels_in_order_of_first_appearance():
    np.testing.assert_array_equal(canonical_labels(np.array([7, 7, -1, 3, 7, -1, 9])), [0, 0, 1, 2, 0, 1, 3])
    np.testing.assert_array_equal(canonical_labels(np.array(["b", "a", "b"])), [0, 1, 0])
    assert canonical_labels(np.array([5, 2])).dtype == np.int64


def test_labels_are_canonical_and_match_dense_alg3_over_random_points():
    rng = np.random.default_rng(42)
    for _ in range(40):
        m = int(rng.integers(1, 60))
        pts = rng.uniform(-0.5, 0.5, (m, 2)) * rng.choice([0.2, 1.0, 3.0])
        length = float(rng.choice([0.002, 0.02, 0.2]))
        alpha = float(rng.uniform(0.05, 0.95))
        labels = segment_points(pts, length, alpha)
        np.testing.assert_array_equal(labels, _alg3_reference(pts, length, alpha))
        np.testing.assert_array_equal(labels, canonical_labels(labels))


def test_segmentation_is_invariant_to_translation_and_point_order():
    rng = np.random.default_rng(7)
    for _ in range(20):
        pts = rng.uniform(-0.4, 0.4, (40, 2))
        base = segment_points(pts, L, ALPHA)
        moved = segment_points(pts + [3.25, -1.5], L, ALPHA)
        perm = rng.permutation(40)
        shuffled = segment_points(pts[perm], L, ALPHA)
        # same partition: equal up to renaming
        np.testing.assert_array_equal(canonical_labels(moved), base)
        np.testing.assert_array_equal(canonical_labels(base[perm]), shuffled)


# ------------------------------------------------------------------------------------------------ segment_table
def _tracks(rows):
    """rows: (run, step, contact_index, estimate_step, x, y, tracker_label[, object_id])."""
    cols = ["run", "step", "contact_index", "estimate_step", "x_m", "y_m", "tracker_label", "object_id"]
    data = {c: [r[i] for r in rows] for i, c in enumerate(cols[: len(rows[0])])}
    types = dict(run=pa.string(), x_m=pa.float64(), y_m=pa.float64())
    return schema.validate_tracks(pa.table({c: pa.array(v, types.get(c, pa.int64())) for c, v in data.items()}))


@pytest.fixture
def small_tracks():
    """Run "a": three points in two far clusters at estimate 5, whose tracker labels say *one* object; run "b":
    two close points whose tracker labels say two objects. Run "a" also has an earlier estimate (step 2)."""
    far = R + 0.1
    return _tracks([
        ("a", 1, 0, 2, 0.0, 0.0, 0, 0),
        ("a", 1, 0, 5, 0.0, 0.0, 4, 0),
        ("a", 3, 0, 5, 0.01, 0.0, 4, 0),
        ("a", 4, 0, 5, far, 0.0, 4, 1),
        ("b", 0, 0, 0, 0.5, 0.5, 9, 2),
        ("b", 0, 1, 0, 0.5, 0.51, 3, 3),
    ])


def test_segment_table_by_components(small_tracks):
    out = segment_table(small_tracks, length=L, alpha=ALPHA, by="components")
    assert out.column_names == small_tracks.column_names + ["segment"]
    assert out.slice(0, 6).drop_columns(["segment"]).equals(small_tracks)
    np.testing.assert_array_equal(out.column("segment").to_numpy(), [0, 0, 0, 1, 0, 0])
    schema.validate_segments(out)


def test_segment_table_by_tracker(small_tracks):
    out = segment_table(small_tracks, length=L, alpha=ALPHA, by="tracker")
    # tracker labels renumbered per (run, estimate) in order of first appearance
    np.testing.assert_array_equal(out.column("segment").to_numpy(), [0, 0, 0, 0, 0, 1])


@pytest.mark.parametrize("method, expect", [("stucco", [0, 0, 0, 1, 0, 0]), ("dbscan", [0, 0, 0, 0, 0, 1]),
                                            ("gmphd", [0, 0, 0, 0, 0, 1])])
def test_segment_table_auto_uses_components_for_stucco_and_tracker_labels_for_baselines(small_tracks, method,
                                                                                        expect):
    out = segment_table(small_tracks, length=L, alpha=ALPHA, by="auto", method=method)
    np.testing.assert_array_equal(out.column("segment").to_numpy(), expect)


def test_segment_table_segments_each_estimate_separately_even_when_rows_interleave():
    # rows of two runs and two estimates interleaved: each (run, estimate_step) is its own graph
    t = _tracks([
        ("a", 0, 0, 1, 0.0, 0.0, 0),
        ("b", 0, 0, 1, 0.0, 0.0, 0),
        ("a", 0, 0, 2, 0.0, 0.0, 0),
        ("a", 1, 0, 1, 0.05, 0.0, 0),
        ("b", 1, 0, 1, 0.9, 0.0, 0),
        ("a", 1, 0, 2, 0.9, 0.0, 0),
    ])
    out = segment_table(t, length=L, alpha=ALPHA, by="components")
    np.testing.assert_array_equal(out.column("segment").to_numpy(), [0, 0, 0, 0, 1, 1])


def test_segment_table_empty_and_bad_by(small_tracks):
    empty = small_tracks.slice(0, 0)
    out = segment_table(empty, length=L, alpha=ALPHA)
    assert out.num_rows == 0 and "segment" in out.column_names
    with pytest.raises(ValueError, match="by must be one of auto, components, tracker"):
        segment_table(small_tracks, length=L, alpha=ALPHA, by="kmeans")


def test_final_estimates_and_summarise(small_tracks):
    seg = segment_table(small_tracks, length=L, alpha=ALPHA, by="components")
    final = final_estimates(seg)
    np.testing.assert_array_equal(final.column("estimate_step").to_numpy(), [5, 5, 5, 0, 0])
    rows = summarise(seg)
    assert [(r["run"], r["segment"], r["n_points"]) for r in rows] == [("a", 0, 2), ("a", 1, 1), ("b", 0, 2)]
    assert rows[0]["centroid_x_m"] == pytest.approx(0.005) and rows[0]["run_fmi"] == pytest.approx(1.0)
    # run "b": truth says two objects, segmentation says one -> FMI 0
    assert rows[2]["run_fmi"] == pytest.approx(0.0)


def test_plot_segments_writes_a_png_atomically(small_tracks, tmp_path):
    from pipeline.segment import plot_segments

    seg = segment_table(small_tracks, length=L, alpha=ALPHA, by="components")
    out = tmp_path / "seg.png"
    plot_segments(seg, out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seg.png"]
