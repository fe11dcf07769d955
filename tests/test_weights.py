"""The compiled weight kernels (pipeline/track/weights.py) give numpy's results to the last bit: numpy's pairwise
sum, logsumexp, normalisation, ESS, argmax and systematic resampling's searchsorted
(docs/experiments/tracker-speed.md)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.pairwise_sum import pairwise_sum
from pipeline.portable import logsumexp
from pipeline.track import weights
from pipeline.track.resampling import effective_sample_size, normalise, systematic

SIZES = list(range(1, 300)) + [487, 488, 489, 511, 512, 968, 969, 1000, 1023, 4097, 7688, 7689, 8192, 8193, 20000]


def _vector(rng, n):
    # magnitudes over 16 decades, so a different summation order shows in the last bits
    return rng.standard_normal(n) * 10.0 ** rng.integers(-8, 8, n)


def test_pairwise_sum_is_numpys_sum_to_the_bit():
    """Every branch of :func:`pipeline.pairwise_sum.pairwise_sum`: one block, each per-depth function's range and
    the stack beyond 7688 values, at an offset too; ``0.0 +`` it (as the tracker adds it) is np.sum's +0 for a
    sum of negative zeros."""
    rng = np.random.default_rng(0)
    for n in SIZES:
        a = _vector(rng, n)
        assert np.float64(pairwise_sum(a, 0, n)).view(np.int64) == np.sum(a).view(np.int64), n
        b = np.concatenate([_vector(rng, 5), a])
        assert np.float64(pairwise_sum(b, 5, n)).view(np.int64) == np.sum(a).view(np.int64), n
    for n in (1, 7, 8, 200):
        z = np.full(n, -0.0)
        assert np.float64(0.0 + pairwise_sum(z, 0, n)).view(np.int64) == np.sum(z).view(np.int64), n


def test_logsumexp_and_normalise_are_the_numpy_ones():
    rng = np.random.default_rng(1)
    for n in SIZES:
        a = rng.standard_normal(n) * 30.0
        assert weights.logsumexp(a) == logsumexp(a)
        np.testing.assert_array_equal(weights._normalise(a), normalise(a))
    a = np.array([-np.inf, 0.5, -np.inf])
    np.testing.assert_array_equal(weights._normalise(a), normalise(a))
    with pytest.raises(ValueError):
        weights._normalise(np.full(3, -np.inf))


def _reweight_numpy(log_weights, eps, reference, lp, floor):
    if reference:
        eps = eps - eps.max()
    log_w = normalise(log_weights + -(eps * eps) / lp)
    if floor > 0:
        log_w = normalise(np.maximum(log_w, math.log(floor)))
    return log_w, effective_sample_size(log_w), int(np.argmax(log_w))


@pytest.mark.parametrize("reference", [True, False])
@pytest.mark.parametrize("floor", [0.0, 1e-15])
def test_reweight_gives_the_numpy_weights_ess_and_map(reference, floor):
    rng = np.random.default_rng(2)
    for n in (1, 2, 7, 16, 100, 129, 500, 3000):
        for _ in range(20):
            log_weights = normalise(rng.standard_normal(n) * rng.choice([0.0, 1.0, 20.0]))
            eps = -np.abs(rng.standard_normal(n)) * rng.choice([1e-4, 1e-2, 1.0])
            eps[rng.random(n) < 0.3] = 0.0
            skipped, log_w, ess, index = weights.reweight(log_weights, eps, False, reference, 0.002, floor,
                                                          math.log(floor) if floor > 0 else 0.0)
            want = _reweight_numpy(log_weights, eps, reference, 0.002, floor)
            assert not skipped
            np.testing.assert_array_equal(log_w, want[0])
            assert ess == want[1] and index == want[2]


def test_reweight_skips_an_even_step_only_when_allowed():
    log_weights = normalise(np.array([0.0, -1.0, 0.5]))
    eps = np.full(3, -0.25)
    skipped, log_w, _, index = weights.reweight(log_weights, eps, True, True, 0.002, 1e-15, math.log(1e-15))
    assert skipped and index == 2 and log_w is not None
    np.testing.assert_array_equal(log_w, log_weights)
    assert not weights.reweight(log_weights, eps, False, True, 0.002, 1e-15, math.log(1e-15))[0]


def test_systematic_ancestors_are_numpys():
    rng = np.random.default_rng(3)
    for n in (1, 2, 5, 100, 128, 500, 2000):
        for _ in range(30):
            log_w = rng.standard_normal(n) * rng.choice([0.0, 1.0, 10.0, 200.0])
            state = rng.bit_generator.state
            want = systematic(log_w, rng)
            rng.bit_generator.state = state
            ancestors, distinct = weights.systematic_ancestors(log_w, rng.random())
            np.testing.assert_array_equal(ancestors, want)
            np.testing.assert_array_equal(distinct, np.unique(want))
    # offsets next to 1, where a position rounds to 1.0 and meets a cumulative sum that overshoots 1
    for offset in (0.0, 1.0 - 2.0 ** -53, 1.0 - 2.0 ** -40):
        log_w = np.log(np.full(100, 0.01))
        lw = normalise(log_w)
        cdf = np.cumsum(np.exp(lw))
        cdf[-1] = 1.0
        want = np.minimum(np.searchsorted(cdf, (offset + np.arange(100)) / 100, side="right"), 99)
        np.testing.assert_array_equal(weights.systematic_ancestors(log_w, offset)[0], want)


def test_argmax_is_numpys():
    for a in ([1.0, 3.0, 3.0], [np.nan, 1.0], [1.0, np.nan, 5.0], [-np.inf, -np.inf], [2.0]):
        assert weights._argmax(np.array(a)) == np.argmax(np.array(a))
