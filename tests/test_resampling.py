"""Log-weight normalisation, effective sample size and systematic resampling (pipeline/track/resampling.py)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.special import logsumexp

from pipeline.track.resampling import effective_sample_size, normalise, systematic


# ------------------------------------------------------------------------------------------------ normalise
def test_normalise_sums_to_one_in_linear_space():
    lw = normalise(np.array([0.0, np.log(3.0), -np.inf]))
    np.testing.assert_allclose(np.exp(lw), [0.25, 0.75, 0.0], atol=1e-15)
    assert logsumexp(lw) == pytest.approx(0.0, abs=1e-15)


def test_normalise_all_minus_inf_raises():
    with pytest.raises(ValueError, match="no particle has a finite weight"):
        normalise(np.full(4, -np.inf))


def test_normalise_huge_negative_log_weights_stay_finite():
    # exp(-1e300) underflows to 0; the log-space shift must keep the finite entries exact
    lw = normalise(np.array([-1e300, 0.0, 0.0, -1e300]))
    assert np.all(np.isfinite(lw))
    np.testing.assert_allclose(lw[[1, 2]], np.log(0.5), rtol=0, atol=1e-15)
    assert lw[0] == pytest.approx(-1e300)


def test_normalise_is_invariant_to_a_common_shift():
    rng = np.random.default_rng(11)
    for _ in range(20):
        lw = rng.normal(size=7) * 50
        shift = rng.uniform(-1e4, 1e4)
        np.testing.assert_allclose(normalise(lw + shift), normalise(lw), atol=1e-9)


# ------------------------------------------------------------------------------------------------ ESS
@pytest.mark.parametrize("n", [1, 2, 7, 100])
def test_ess_is_one_for_equal_weights(n):
    # exact equality is pinned (and currently fails) in test_ess_is_exactly_one_for_equal_weights
    assert effective_sample_size(np.zeros(n)) == pytest.approx(1.0, abs=1e-12)
    assert effective_sample_size(np.full(n, -123.4)) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("lw", [np.zeros(7), np.full(5, -np.log(5)), np.full(7, -np.log(7)),
                                np.full(7, -123.4)],
                         ids=["zeros7", "uniform5", "uniform7", "const7"])
def test_ess_is_exactly_one_for_equal_weights(lw):
    # -log(N) is exactly the state SoftTracker stores after resampling
    assert effective_sample_size(lw) == 1.0


@pytest.mark.parametrize("n", [2, 7, 100])
def test_ess_is_one_over_n_for_a_single_live_particle(n):
    lw = np.full(n, -np.inf)
    lw[n // 2] = 0.0
    assert effective_sample_size(lw) == pytest.approx(1.0 / n, rel=1e-12)


def test_ess_in_unit_interval_over_random_weights():
    rng = np.random.default_rng(5)
    for _ in range(200):
        n = int(rng.integers(1, 60))
        lw = rng.normal(size=n) * rng.choice([0.01, 1.0, 30.0, 1e3])
        ess = effective_sample_size(lw)
        assert 1.0 / n - 1e-12 <= ess <= 1.0


def test_ess_with_huge_negative_log_weights():
    # two live particles out of three: 1 / sum(w^2) = 2, i.e. 2/3 of N
    assert effective_sample_size(np.array([-1e300, 0.0, 0.0])) == pytest.approx(2.0 / 3.0, rel=1e-12)


def test_ess_all_minus_inf_raises():
    with pytest.raises(ValueError, match="no particle has a finite weight"):
        effective_sample_size(np.full(3, -np.inf))


# ------------------------------------------------------------------------------------------------ systematic
@pytest.mark.parametrize("n", [1, 3, 64, 100])
def test_equal_weights_keep_every_particle_exactly_once(n):
    rng = np.random.default_rng(0)
    for _ in range(25):
        anc = systematic(np.full(n, -2.5), rng)
        np.testing.assert_array_equal(anc, np.arange(n))


@pytest.mark.parametrize("n", [2, 5, 100])
def test_single_nonzero_weight_collapses_all_particles_onto_it(n):
    rng = np.random.default_rng(1)
    for live in {0, n // 2, n - 1}:
        lw = np.full(n, -np.inf)
        lw[live] = -7.0
        for _ in range(10):
            np.testing.assert_array_equal(systematic(lw, rng), np.full(n, live))


def test_counts_are_floor_or_ceil_of_n_w():
    rng = np.random.default_rng(2024)
    for _ in range(300):
        n = int(rng.integers(1, 50))
        lw = rng.normal(size=n) * rng.choice([0.1, 2.0, 20.0])
        lw[rng.random(n) < 0.2] = -np.inf
        if not np.isfinite(lw).any():
            lw[0] = 0.0
        anc = systematic(lw, rng)
        assert anc.shape == (n,) and anc.dtype == np.int64
        assert np.all(np.diff(anc) >= 0), "ancestors are returned sorted"
        counts = np.bincount(anc, minlength=n)
        expect = n * np.exp(normalise(lw))
        # 1e-9 slack: N * w may be an integer up to round-off
        assert np.all(counts >= np.floor(expect - 1e-9)) and np.all(counts <= np.ceil(expect + 1e-9))
        assert counts.sum() == n
        assert np.all(counts[~np.isfinite(lw)] == 0), "a particle of weight zero has no descendant"


def test_systematic_with_huge_negative_log_weights():
    rng = np.random.default_rng(3)
    for _ in range(10):
        anc = systematic(np.array([-1e300, 0.0, 0.0, -1e300]), rng)
        assert sorted(anc.tolist()) == [1, 1, 2, 2]


def test_systematic_does_not_depend_on_normalisation():
    lw = np.array([0.3, -1.2, 2.0, -0.5, 0.0])
    a = systematic(lw, np.random.default_rng(9))
    b = systematic(lw + 1234.5, np.random.default_rng(9))
    np.testing.assert_array_equal(a, b)


def test_systematic_all_minus_inf_raises():
    with pytest.raises(ValueError, match="no particle has a finite weight"):
        systematic(np.full(3, -np.inf), np.random.default_rng(0))
