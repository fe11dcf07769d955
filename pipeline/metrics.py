"""Segmentation quality: the Fowlkes-Mallows index of segments against ground-truth objects (paper §III).

One implementation for the scores table (:mod:`pipeline.score`) and the segment summary (``stucco segment
--print``), so both treat unassigned points (segment -1) alike.
"""
from __future__ import annotations

import numpy as np

__all__ = ["fmi"]


def fmi(truth: np.ndarray, segment: np.ndarray) -> float | None:
    """Fowlkes-Mallows index over points with a known object (truth >= 0); None if there are none.

    Unassigned points (segment -1) are each given a cluster of their own.
    """
    # Imported here: sklearn.metrics takes 0.8 s to import (measured), which only scoring and summaries pay.
    from sklearn.metrics import fowlkes_mallows_score

    truth = np.asarray(truth, dtype=np.int64)
    seg = np.asarray(segment, dtype=np.int64).copy()
    lone = seg < 0
    seg[lone] = seg.max(initial=0) + 1 + np.arange(int(lone.sum()))
    known = truth >= 0
    if not known.any():
        return None
    return float(fowlkes_mallows_score(truth[known], seg[known]))
