"""Independent calls over processes: the one joblib loop of the pipeline (runs, seeds, jobs, figures), and one
thread per numeric library inside a call (:func:`single_threaded`).

With ``jobs`` > 1 and more than one call, the calls run in joblib worker processes (loky, or the active joblib
backend, e.g. a Dask cluster, with ``jobs == -1``); otherwise in this process, one after the other. Either way a
call's result does not depend on ``jobs``: every random draw comes from the run's own stream (pipeline/seeds.py).
"""
from __future__ import annotations

import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager

from joblib import Parallel, delayed

from pipeline.atomic import guard_writes, held_lock

__all__ = ["run_calls", "in_process", "map_jobs", "single_threaded"]


def in_process(jobs: int, n_calls: int) -> bool:
    """Whether :func:`run_calls` runs ``n_calls`` calls in this process (so a caller can load shared inputs once)."""
    return not ((jobs > 1 or jobs == -1) and n_calls > 1)


def run_calls(fn: Callable, args: Sequence[tuple], jobs: int, *, ordered: bool = True) -> Iterator:
    """``fn(*a)`` for every ``a`` in ``args``, lazily: in ``args`` order, or in completion order when not
    ``ordered`` (the caller sorts). ``jobs == -1`` lets the active joblib backend choose the workers.

    Local workers (loky) end with this process: each watches its parent (:func:`_in_worker`) and exits when it is
    gone (killed, even with SIGKILL); a SIGTERM or SIGINT here, or any error, kills them before it propagates
    (:func:`_stopping_workers`); and while this process holds a folder's lock (:func:`pipeline.atomic.exclusive`)
    a worker renames an output into place only while the lock still names this process
    (:func:`pipeline.atomic.guard_writes`), so nothing is written into the folder once it is released."""
    if not in_process(jobs, len(args)):
        n_jobs = -1 if jobs == -1 else min(jobs, len(args))
        # A cluster's workers (jobs == -1) are not this process's children: no parent to watch.
        watch = None if jobs == -1 else (os.getpid(), held_lock())
        calls: Iterable = (delayed(_in_worker)(watch, fn, *a) for a in args)
        return _stopping_workers(
            Parallel(n_jobs=n_jobs, return_as="generator" if ordered else "generator_unordered")(calls))
    return (fn(*a) for a in args)


#: Seconds between a worker's checks that its parent is alive.
PARENT_POLL_S = 0.2
_WATCHING: list[int] = []


def _in_worker(watch: tuple[int, tuple[str, int] | None] | None, fn: Callable, *a):
    """``fn(*a)`` in a worker process: first (once per process and parent) a daemon thread that ends the process
    when its parent ``watch[0]`` is gone, and the write guard of the parent's folder lock ``watch[1]``."""
    if watch is not None and os.getpid() != watch[0]:
        parent, held = watch
        guard_writes(held)
        if _WATCHING != [parent]:
            _WATCHING[:] = [parent]
            threading.Thread(target=_watch_parent, args=(parent,), daemon=True, name="stucco-parent-watch").start()
    return fn(*a)


def _watch_parent(parent: int) -> None:
    """End this process (no clean-up, no more writes) as soon as ``parent`` is no longer its parent."""
    while os.getppid() == parent:
        time.sleep(PARENT_POLL_S)
    os._exit(1)


def _stopping_workers(results: Iterator) -> Iterator:
    """``results``, with SIGTERM raising KeyboardInterrupt meanwhile (in the main thread), and the local workers
    killed when anything interrupts the iteration (an error, SIGINT, SIGTERM)."""
    previous = _raise_on_sigterm()
    try:
        yield from results
    except BaseException:
        _kill_local_workers()
        raise
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _raise_on_sigterm():
    """Turn SIGTERM into KeyboardInterrupt (so the workers are stopped on the way out); returns the previous
    handler, or None off the main thread (where handlers cannot be set)."""
    if threading.current_thread() is not threading.main_thread():
        return None

    def interrupt(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")

    return signal.signal(signal.SIGTERM, interrupt)


def _kill_local_workers() -> None:
    """Kill the loky worker processes joblib keeps for reuse (without waiting for them)."""
    executor = getattr(sys.modules.get("joblib.externals.loky.reusable_executor"), "_executor", None)
    if executor is not None:
        executor.shutdown(wait=False, kill_workers=True)


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
