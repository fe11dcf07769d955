"""Independent calls over processes: the one joblib loop of the pipeline (runs, seeds, jobs, figures).

With ``jobs`` > 1 and more than one call, the calls run in joblib worker processes (loky, or the active joblib
backend, e.g. a Dask cluster, with ``jobs == -1``); otherwise in this process, one after the other. Either way a
call's result does not depend on ``jobs``: every random draw comes from the run's own stream (pipeline/seeds.py).
"""
from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence

from joblib import Parallel, delayed

__all__ = ["run_calls", "in_process", "map_jobs"]


def in_process(jobs: int, n_calls: int) -> bool:
    """Whether :func:`run_calls` runs ``n_calls`` calls in this process (so a caller can load shared inputs once)."""
    return not ((jobs > 1 or jobs == -1) and n_calls > 1)


def run_calls(fn: Callable, args: Sequence[tuple], jobs: int, *, ordered: bool = True) -> Iterator:
    """``fn(*a)`` for every ``a`` in ``args``, lazily: in ``args`` order, or in completion order when not
    ``ordered`` (the caller sorts). ``jobs == -1`` lets the active joblib backend choose the workers."""
    if not in_process(jobs, len(args)):
        n_jobs = -1 if jobs == -1 else min(jobs, len(args))
        calls: Iterable = (delayed(fn)(*a) for a in args)
        return iter(Parallel(n_jobs=n_jobs, return_as="generator" if ordered else "generator_unordered")(calls))
    return (fn(*a) for a in args)


def map_jobs(fn: Callable, args: Sequence[tuple], jobs: int, bar) -> list:
    """``fn(*a)`` for every ``a`` (:func:`run_calls`), results in completion order; ``bar`` (a tqdm bar) advances
    by one per finished call. ``jobs == -1``: the active joblib backend decides (e.g. a Dask cluster's workers,
    :func:`pipeline.evaluate.parallel_backend`)."""
    out = []
    for r in run_calls(fn, args, jobs, ordered=False):
        out.append(r)
        bar.update()
    return out
