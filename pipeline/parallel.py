"""Independent calls over processes: the one joblib loop of the pipeline (runs, seeds, jobs, figures), and one
thread per numeric library inside a call (:func:`single_threaded`).

With ``jobs`` > 1 and more than one call, the calls run in joblib worker processes (loky, or the active joblib
backend, e.g. a Dask cluster, with ``jobs == -1``); otherwise in this process, one after the other. Either way a
call's result does not depend on ``jobs``: every random draw comes from the run's own stream (pipeline/seeds.py).
"""
from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager

from joblib import Parallel, delayed

__all__ = ["run_calls", "in_process", "map_jobs", "single_threaded"]


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


@contextmanager
def single_threaded():
    """Run the job's numeric libraries on one thread each (numba, OpenMP, BLAS), restoring them afterwards.

    Parallelism is over jobs. The tracker's numba kernels and scikit-learn's k-means parallelise problems of a
    few hundred points, where OpenMP threads only spin (docs/evaluation.md, "Parallelism", has the times).
    ``threadpool_limits`` only reaches libraries already loaded, hence the imports first. k-means' OpenMP reduction
    order depends on the thread count, so one thread also keeps its labels the same whatever ``jobs`` is
    (docs/evaluation.md, "Same numbers on every machine"). No stage runs Open3D inside a job any more (the ICP is
    the project's own), so it is not imported here.
    """
    import numba

    # numba's threading layer first: started after Open3D has loaded its older TBB (a Panda grid built on a cache
    # miss), numba warns that it cannot use TBB (and falls back to OpenMP anyway).
    prev = numba.get_num_threads()
    import sklearn.cluster  # noqa: F401  (scikit-learn's OpenMP runtime)
    from threadpoolctl import threadpool_limits

    numba.set_num_threads(1)
    try:
        with threadpool_limits(1):
            yield
    finally:
        numba.set_num_threads(prev)
