"""GM-PHD baseline (paper §V-A): the mixture maths (Vo & Ma 2006, Tables 1-2), the weight-integral target
extraction of the authors' baseline, the filter and its labeller."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.special import logsumexp

from pipeline.track.gaussian_mixture import extract_targets, predict, prune, update
from pipeline.track.gmphd import GMPHDFilter, GMPHDLabeller, GMPHDParams, birth_components, nearest_labels


def _random_mixture(rng: np.random.Generator, j: int, spread: float = 0.5, var: float = 1e-3):
    a = rng.normal(size=(j, 2, 2)) * np.sqrt(var)
    covs = a @ a.transpose(0, 2, 1) + var * 0.1 * np.eye(2)
    return np.log(rng.uniform(1e-4, 1.0, j)), rng.uniform(-spread, spread, (j, 2)), covs


def _gauss(z, m, s):
    d = z - m
    return np.exp(-0.5 * d @ np.linalg.solve(s, d)) / (2 * np.pi * np.sqrt(np.linalg.det(s)))


# ------------------------------------------------------------------------------------------------ model pieces
def test_birth_is_a_20x20_grid_with_total_weight_birth():
    prm = GMPHDParams()
    lw, m, p = birth_components(prm)
    assert lw.shape == (400,) and m.shape == (400, 2) and p.shape == (400, 2, 2)
    assert np.exp(logsumexp(lw)) == pytest.approx(prm.birth)
    np.testing.assert_allclose(m.min(0), [-1, -1])
    np.testing.assert_allclose(m.max(0), [1, 1])
    np.testing.assert_allclose(p, np.broadcast_to(1e-3 * np.eye(2), p.shape))
    assert prm.clutter_intensity == pytest.approx(0.75)


def test_predict_is_static_with_survival_and_process_noise():
    lw, m, p = _random_mixture(np.random.default_rng(0), 5)
    lw2, m2, p2 = predict(lw, m, p, survival=0.95, q=0.01)
    np.testing.assert_allclose(lw2, lw + np.log(0.95))
    np.testing.assert_array_equal(m2, m)
    np.testing.assert_allclose(p2, p + 0.01 * np.eye(2))


def test_single_measurement_on_single_component_matches_hand_kalman_update():
    w0, m0 = 0.4, np.array([0.1, -0.2])
    p0 = np.array([[0.02, 0.005], [0.005, 0.01]])
    z, r, pd, kappa = np.array([0.13, -0.18]), 0.01, 0.3, 0.75
    lw, m, p = update(np.log([w0]), m0[None], p0[None], z[None], pd, r, kappa)
    assert lw.shape == (2,)
    s = p0 + r * np.eye(2)
    gain = p0 @ np.linalg.inv(s)
    like = pd * w0 * _gauss(z, m0, s)
    # missed detection
    assert np.exp(lw[0]) == pytest.approx(w0 * (1 - pd), rel=1e-12)
    np.testing.assert_allclose(m[0], m0)
    np.testing.assert_allclose(p[0], p0)
    # detection
    assert np.exp(lw[1]) == pytest.approx(like / (kappa + like), rel=1e-10)
    np.testing.assert_allclose(m[1], m0 + gain @ (z - m0), rtol=1e-12)
    np.testing.assert_allclose(p[1], (np.eye(2) - gain) @ p0, rtol=1e-10, atol=1e-15)


def test_update_matches_a_naive_loop_over_components_and_measurements():
    rng = np.random.default_rng(1)
    lw, m, p = _random_mixture(rng, 6, spread=0.1)
    z = rng.uniform(-0.1, 0.1, (3, 2))
    pd, r, kappa = 0.6, 2e-3, 0.75
    out_lw, out_m, out_p = update(lw, m, p, z, pd, r, kappa)
    assert out_lw.shape == (24,)
    w = np.exp(lw)
    for k, zk in enumerate(z):
        terms = np.array([pd * w[i] * _gauss(zk, m[i], p[i] + r * np.eye(2)) for i in range(6)])
        block = slice(6 * (k + 1), 6 * (k + 2))
        np.testing.assert_allclose(np.exp(out_lw[block]), terms / (kappa + terms.sum()), rtol=1e-9)
        for i in range(6):
            gain = p[i] @ np.linalg.inv(p[i] + r * np.eye(2))
            np.testing.assert_allclose(out_m[block][i], m[i] + gain @ (zk - m[i]), rtol=1e-10, atol=1e-14)
            np.testing.assert_allclose(out_p[block][i], (np.eye(2) - gain) @ p[i], rtol=1e-8, atol=1e-14)


def test_update_with_certain_detection_drops_missed_terms_and_zero_clutter_stays_finite():
    lw, m, p = _random_mixture(np.random.default_rng(2), 3)
    out_lw, _, _ = update(lw, m, p, np.array([[5.0, 5.0]]), 1.0, 1e-6, 0.0)
    assert np.isfinite(out_lw).all() and len(out_lw) <= 3


# ------------------------------------------------------------------------------------------------ pruning
def test_prune_keeps_total_weight_and_the_cap():
    rng = np.random.default_rng(3)
    for _ in range(20):
        j = int(rng.integers(1, 300))
        lw, m, p = _random_mixture(rng, j, spread=float(rng.choice([0.01, 0.5])))
        lw2, m2, p2 = prune(lw, m, p, truncation=1e-3, merge_threshold=0.5, max_components=10)
        assert 1 <= len(lw2) <= min(j, 10)
        assert logsumexp(lw2) == pytest.approx(logsumexp(lw), abs=1e-12)
        assert np.isfinite(m2).all()
        np.linalg.cholesky(p2)  # positive definite
        np.testing.assert_array_equal(p2, p2.transpose(0, 2, 1))


def test_prune_merges_identical_components_and_keeps_far_ones():
    m = np.array([[0.0, 0.0], [0.0, 0.0], [0.5, 0.5]])
    p = np.broadcast_to(1e-3 * np.eye(2), (3, 2, 2)).copy()
    lw = np.log([0.2, 0.3, 0.1])
    lw2, m2, p2 = prune(lw, m, p, truncation=1e-6, merge_threshold=0.005, max_components=10)
    np.testing.assert_allclose(np.exp(lw2), [0.5, 0.1])
    np.testing.assert_allclose(m2, [[0.0, 0.0], [0.5, 0.5]])
    np.testing.assert_allclose(p2, p[:2])


def test_prune_merge_uses_the_candidates_covariance_and_moment_matches():
    # Seed (heavier) is tight, candidate is broad: the candidate's own covariance decides.
    m = np.array([[0.0, 0.0], [0.003, 0.0]])
    p = np.array([1e-6 * np.eye(2), 1e-2 * np.eye(2)])
    lw = np.log([0.6, 0.4])
    lw2, m2, p2 = prune(lw, m, p, 1e-6, 0.005, 10)
    assert len(lw2) == 1  # 0.003^2 / 1e-2 = 9e-4 <= 0.005, although 0.003^2 / 1e-6 = 9 is not
    mean = 0.6 * m[0] + 0.4 * m[1]
    np.testing.assert_allclose(m2[0], mean)
    expect = sum(w * (pi + np.outer(mean - mi, mean - mi)) for w, mi, pi in zip([0.6, 0.4], m, p))
    np.testing.assert_allclose(p2[0], expect)
    # The other way round (heavier component broad) they stay apart.
    lw3, _, _ = prune(np.log([0.4, 0.6]), m, p, 1e-6, 0.005, 10)
    assert len(lw3) == 2


def test_prune_truncates_light_components_but_never_empties():
    m = np.zeros((3, 2)) + np.arange(3)[:, None]
    p = np.broadcast_to(1e-3 * np.eye(2), (3, 2, 2)).copy()
    lw2, m2, _ = prune(np.log([1e-8, 1e-7, 1e-9]), m, p, 1e-6, 0.005, 10)
    np.testing.assert_allclose(m2, [[1.0, 1.0]])
    assert np.exp(lw2[0]) == pytest.approx(1e-8 + 1e-7 + 1e-9)


# ------------------------------------------------------------------------------------------------ extraction
def test_extraction_by_weight_integral():
    lw = np.log([1.6, 0.9, 0.2])
    # n = round(2.7) = 3: take 0 (1.6 -> 0.6), 1 (0.9 -> -0.1), 0 again -> two distinct targets
    np.testing.assert_array_equal(extract_targets(lw, bias=1.0), [0, 1])
    np.testing.assert_array_equal(extract_targets(lw, bias=0.3), [0])  # n = round(0.81) = 1
    np.testing.assert_array_equal(extract_targets(lw, bias=4.0), [0, 1, 2])


@pytest.mark.parametrize("weights", [[1e-9, 3e-9], [1e-300], [0.0, 0.0]])
def test_extraction_returns_at_least_one_target(weights):
    with np.errstate(divide="ignore"):
        lw = np.log(weights)
    idx = extract_targets(lw, bias=4.0)
    assert len(idx) >= 1 and idx[0] == int(np.argmax(weights))
    assert extract_targets(np.empty(0), 4.0).shape == (0,)


def test_nearest_labels():
    targets = np.array([[0.0, 0.0], [1.0, 0.0]])
    pts = np.array([[0.1, 0.0], [0.9, 0.2], [0.4, 0.0]])
    np.testing.assert_array_equal(nearest_labels(pts, targets), [0, 1, 0])


# ------------------------------------------------------------------------------------------------ filter
def test_repeated_measurement_builds_one_target_there():
    f = GMPHDFilter()
    z = np.array([[0.3, -0.2]])
    for _ in range(6):
        f.step(z)
    assert len(f.log_weights_) <= 10
    np.testing.assert_allclose(f.targets()[0], z[0], atol=1e-3)
    assert np.exp(f.log_weights_).max() > 0.5


def test_near_singular_covariances_stay_finite():
    f = GMPHDFilter(GMPHDParams(q=1e-12, r=1e-12))
    rng = np.random.default_rng(4)
    spots = np.array([[0.2, 0.1], [-0.3, 0.4]])
    for t in range(30):
        z = spots[t % 2][None] + (rng.normal(scale=1e-7, size=(1, 2)) if t % 3 else 0.0)
        f.step(np.concatenate([z, z]))  # two coincident measurements too
        assert np.isfinite(f.log_weights_).all() and np.isfinite(f.means_).all()
        assert np.isfinite(f.covariances_).all()
        np.linalg.cholesky(f.covariances_)
    assert len(f.targets()) >= 1


def test_thousands_of_components_stay_finite():
    # No truncation, no cap: every missed/detected copy of every component survives (400 -> 1600 -> ~7500).
    prm = GMPHDParams(max_components=10**6, truncation=0.0)
    f = GMPHDFilter(prm)
    rng = np.random.default_rng(5)
    for _ in range(2):
        f.step(rng.uniform(-0.9, 0.9, (3, 2)))
    assert len(f.log_weights_) > 5000
    assert np.isfinite(f.log_weights_).all() and np.isfinite(f.means_).all()
    np.linalg.cholesky(f.covariances_)
    assert len(f.targets()) >= 1


def test_labeller_labels_points_by_nearest_target():
    lab = GMPHDLabeller()
    pts = np.empty((0, 2))
    for z in [[0.5, 0.5]] * 4 + [[-0.5, -0.5]] * 4:
        pts = np.concatenate([pts, [z]])
        labels = lab.fit_labels(pts, 1)
    assert labels.dtype == np.int64
    assert len(set(labels[:4])) == 1 and len(set(labels[4:])) == 1 and labels[0] != labels[-1]
    with pytest.raises(ValueError, match="planar"):
        lab.fit_labels(np.zeros((1, 3)), 1)


def test_rank_deficient_covariances_are_repaired_not_propagated_as_nan():
    m = np.array([[0.0, 0.0], [0.2, 0.0]])
    p = np.array([[[1.0, 1.0], [1.0, 1.0]], [[1e-3, 0.0], [0.0, 0.0]]]) * 1e-3  # singular
    lw, m2, p2 = prune(np.log([0.5, 0.5]), m, p, 1e-6, 0.005, 10)
    assert np.isfinite(lw).all() and np.isfinite(m2).all()
    lw3, m3, p3 = update(lw, m2, p2, np.array([[0.01, 0.0]]), 0.3, 0.0 + 1e-12, 0.75)
    assert np.isfinite(lw3).all() and np.isfinite(m3).all() and np.isfinite(p3).all()
