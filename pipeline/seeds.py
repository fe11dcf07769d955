"""Run keys and random streams: every random draw of a stage derives from the root seed and the run's name.

A run's stream is independent of the other runs and of the order (or process) they are handled in, so a stage
rerun alone on one run draws exactly what it drew inside ``stucco evaluate`` (docs/architecture.md).
"""
from __future__ import annotations

import hashlib
import operator

import numpy as np

__all__ = ["run_key", "run_rng", "check_stream", "check_root_seed"]


def check_stream(stream, name: str = "stream") -> int:
    """``stream`` as a plain int: a non-negative integer (numpy's included, ``bool`` not); ValueError naming
    ``name`` otherwise. The pose estimators' random stream (:func:`pipeline.estimators.run_info.retrieval_rng`)."""
    try:
        value = operator.index(stream) if not isinstance(stream, (bool, np.bool_)) else -1
    except TypeError:
        value = -1
    if value < 0:
        raise ValueError(f"{name} must be a non-negative integer, got {stream!r}")
    return int(value)


def check_root_seed(path, meta: dict, root_seed: int, then: str) -> None:
    """ValueError (one line naming the file ``path``) when its decoded metadata ``meta`` records another root
    seed (``stucco.seed``) than ``root_seed``: every stage after it would draw from another stream. ``then`` ends
    the message with what to do; ``{seed}`` in it stands for the recorded root seed, ``{root}`` for ``root_seed``.
    A file that records no root seed passes."""
    recorded = meta.get("seed")
    if isinstance(recorded, int) and recorded != root_seed:
        raise ValueError(f"{path}: collected with root seed {recorded}" + then.format(seed=recorded, root=root_seed))


def run_key(run: str) -> int:
    """Stable 64-bit integer of a run name (Python's ``hash()`` is salted per process)."""
    return int.from_bytes(hashlib.sha256(run.encode("utf-8")).digest()[:8], "little")


def run_rng(seed: int, run: str) -> np.random.Generator:
    """The tracker's random stream of one run: ``SeedSequence([root seed, run_key(run)])``."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), run_key(run)]))
