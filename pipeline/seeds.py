"""Run keys and random streams: every random draw of a stage derives from the root seed and the run's name.

A run's stream is independent of the other runs and of the order (or process) they are handled in, so a stage
rerun alone on one run draws exactly what it drew inside ``stucco evaluate`` (docs/architecture.md).
"""
from __future__ import annotations

import hashlib

import numpy as np

__all__ = ["run_key", "run_rng"]


def run_key(run: str) -> int:
    """Stable 64-bit integer of a run name (Python's ``hash()`` is salted per process)."""
    return int.from_bytes(hashlib.sha256(run.encode("utf-8")).digest()[:8], "little")


def run_rng(seed: int, run: str) -> np.random.Generator:
    """The tracker's random stream of one run: ``SeedSequence([root seed, run_key(run)])``."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), run_key(run)]))
