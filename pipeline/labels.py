"""Label arrays renumbered 0..K-1 in order of first appearance, so that equal partitions give equal arrays."""
from __future__ import annotations

import numpy as np


def canonical_labels(labels: np.ndarray) -> np.ndarray:
    """Relabel to 0..k-1 in order of first appearance (so equal segmentations give equal label arrays).

    labels (M,) of any sortable dtype -> (M,) int64; every distinct value (-1 included) is one label.
    """
    labels = np.asarray(labels)
    if labels.size == 0:
        return np.zeros(0, dtype=np.int64)
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    rank = np.empty(first.size, dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(first.size)
    return rank[inverse.ravel()]
