"""Where jobs run: local processes (joblib/loky) or a Dask cluster across jobs, one thread per library inside one.

Parallelism is over jobs (docs/evaluation.md, "Parallelism"; docs/studies.md, "Beyond one machine"); the studies
(:mod:`pipeline.studies`) use the same :func:`pipeline.parallel.map_jobs` and
:func:`pipeline.parallel.single_threaded` (re-exported here).
"""
from __future__ import annotations

from contextlib import contextmanager

from joblib import parallel_config

from pipeline.parallel import single_threaded

__all__ = ["BACKENDS", "parallel_backend", "single_threaded"]

#: Values of ``--backend``.
BACKENDS = ("loky", "dask")


@contextmanager
def parallel_backend(backend: str = "loky", scheduler: str | None = None):
    """Where :func:`~pipeline.parallel.map_jobs` runs jobs: ``"loky"`` (local processes) or ``"dask"`` (joblib's
    Dask backend on the ``distributed`` scheduler at ``scheduler``, e.g. ``tcp://10.0.0.5:8786``; the optional extra
    ``stucco[dask]``). Job functions write their own files under the evaluation directory, so Dask workers
    must see the same filesystem path. Yields the ``jobs`` value to pass to :func:`~pipeline.parallel.map_jobs` for
    Dask (-1: every worker of the cluster), or None for loky."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; expected one of {', '.join(BACKENDS)}")
    if backend == "loky":
        if scheduler is not None:
            raise ValueError("--scheduler applies to --backend dask only")
        yield None
        return
    if not scheduler:
        raise ValueError("--backend dask needs --scheduler ADDRESS (e.g. tcp://127.0.0.1:8786)")
    try:
        # Imported here: an optional extra, needed only with --backend dask.
        from distributed import Client
    except ImportError:
        raise ValueError("--backend dask needs the optional extra: pip install 'stucco[dask]'") from None

    _check_listening(scheduler)
    with Client(scheduler) as client, parallel_config(backend="dask", wait_for_workers_timeout=60):
        client.wait_for_workers(1, timeout=60)
        yield -1


def _check_listening(scheduler: str) -> None:
    """ValueError (one line) at once when the scheduler's TCP port refuses connections or its host is unknown;
    an address that does not answer is left to the Client's own (longer) connect timeout."""
    # distributed retries a refused connection until its timeout (30 s): a closed port is known in microseconds.
    import socket

    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, location = parse_address(scheduler)
        if scheme not in ("tcp", "tls"):
            return
        host, port = parse_host_port(location)
    except (ValueError, TypeError) as e:
        raise ValueError(f"--scheduler {scheduler}: not a scheduler address ({e}); expected tcp://HOST:PORT") from None
    try:
        with socket.create_connection((host, int(port)), timeout=_PROBE_TIMEOUT_S):
            return
    except ConnectionRefusedError:
        raise ValueError(f"--scheduler {scheduler}: connection refused (no Dask scheduler listens on {host}:{port}); "
                         f"start one with `dask scheduler --port {port}` or fix the address") from None
    except socket.gaierror as e:
        raise ValueError(f"--scheduler {scheduler}: unknown host {host!r} ({e.strerror})") from None
    except OSError:  # no answer within the probe (firewall, busy host): the Client decides, with its timeout
        return


#: Seconds the probe of :func:`_check_listening` waits for an answer.
_PROBE_TIMEOUT_S = 3.0
