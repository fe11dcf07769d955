"""Particle weights in log space: normalisation, effective sample size, systematic resampling.

Resampling returns ancestor *indices* and never touches what is resampled, so the same indices select points,
configs and every per-particle cache.
"""
from __future__ import annotations

import math

import numpy as np

from pipeline.portable import exp, logsumexp


def normalise(log_w: np.ndarray) -> np.ndarray:
    """Return log-weights that sum to one in linear space.

    Parameters
    ----------
    log_w : ndarray, shape (N,)
        Unnormalised log-weights; ``-inf`` entries are allowed as long as one entry is finite.

    Raises
    ------
    ValueError
        If no entry is finite (there is nothing to normalise against).
    """
    log_w = np.asarray(log_w, dtype=np.float64)
    total = float(logsumexp(log_w))
    if not np.isfinite(total):
        raise ValueError("cannot normalise log-weights: no particle has a finite weight")
    return log_w - total


def effective_sample_size(log_w: np.ndarray) -> float:
    """ESS = 1 / sum(w^2) of normalised weights, as a fraction of the number of particles, in (0, 1]."""
    lw = normalise(log_w)
    ess = float(math.exp(-float(logsumexp(2.0 * lw))) / lw.size)
    # Round-off puts a perfectly even set of weights a hair above or below 1; "all particles equal" must read
    # as exactly 1 so that a threshold of 1 does not resample identical weights.
    return 1.0 if abs(ess - 1.0) < 1e-12 else min(ess, 1.0)


def systematic(log_w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Systematic resampling: one uniform offset, N evenly spaced positions against the cumulative weights.

    Parameters
    ----------
    log_w : ndarray, shape (N,)
        Log-weights (normalised or not).
    rng : numpy.random.Generator

    Returns
    -------
    ancestors : ndarray, shape (N,), int64
        Sorted ancestor index of each new particle; particle j appears floor(N w_j) or ceil(N w_j) times.
    """
    lw = normalise(log_w)
    n = lw.size
    cdf = np.cumsum(exp(lw))
    cdf[-1] = 1.0  # round-off must not leave the last positions without an ancestor
    positions = (rng.random() + np.arange(n)) / n
    return np.minimum(np.searchsorted(cdf, positions, side="right"), n - 1).astype(np.int64)
