"""The Dask cluster a run uses: a local one started for the run, or one already running.

``workers=N`` starts N single-threaded worker processes on 127.0.0.1 for the
run and stops them after it, Ctrl-C and SIGTERM included; ``scheduler=ADDRESS``
connects to a running cluster and fails in one line within
:data:`CONNECT_TIMEOUT` seconds when nothing there answers as Dask. Dask is
imported only once a cluster is used: serial runs do not need it.
"""
from __future__ import annotations

import contextlib
import os
from pathlib import Path

from pipelines.interrupts import deferred

__all__ = ["CONNECT_TIMEOUT", "check_workers", "dask_client", "default_workers", "max_local_workers"]


def default_workers() -> int:
    """Cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


#: Seconds to wait for a Dask scheduler to answer (``--scheduler``).
CONNECT_TIMEOUT = 30.0


def max_local_workers() -> int:
    """The most worker processes a local cluster may start: 4 per core (each is a whole Python process)."""
    return 4 * default_workers()


def _connect(scheduler: str, timeout: float | None = None):
    """A Client of the scheduler at ``scheduler``, or one ValueError line within ``timeout`` seconds.

    Distributed's own timeout does not cover a port that accepts the
    connection and then says nothing (an HTTP server), and a port that answers
    something else ends in a long traceback; both are refused here.
    """
    import threading

    from distributed import Client

    timeout = CONNECT_TIMEOUT if timeout is None else float(timeout)
    out: dict = {}

    def connect():
        try:
            out["client"] = Client(scheduler, timeout=f"{timeout}s")
        except BaseException as e:  # noqa: BLE001 - reported in one line below
            out["error"] = e

    t = threading.Thread(target=connect, daemon=True)
    t.start()
    t.join(timeout + 5.0)
    if t.is_alive():
        raise ValueError(f"--scheduler {scheduler}: no Dask scheduler answered within {timeout:g} s")
    if "error" in out:
        e = out["error"]
        raise ValueError(f"--scheduler {scheduler}: not a Dask scheduler, or not reachable "
                         f"({type(e).__name__}: {' '.join(str(e).split())[:120]})") from None
    return out["client"]


@contextlib.contextmanager
def dask_client(workers: int | None, scheduler: str | None, scratch: Path | None = None):
    # dask is imported only when a cluster is used: serial runs and the rest of vpr do not need it
    import logging
    import shutil

    from distributed import Client, LocalCluster

    if scheduler:
        with _connect(scheduler) as client:
            yield client
        return
    # the workers' spill folder goes beside the cache, not into the current folder, and is removed after
    local = None
    if scratch is not None:
        scratch.mkdir(parents=True, exist_ok=True)
        local = str(scratch)
    stack = contextlib.ExitStack()
    try:
        # a Ctrl-C or SIGTERM while the worker processes start or close would leave them (and their
        # semaphores) behind: held until the cluster is up, or down, then raised. The cluster's own log
        # is quiet below CRITICAL: a failed task reaches the client as its exception, and a run stopped
        # mid-task would otherwise print the workers' lost heartbeats as they close
        with deferred():
            cluster = stack.enter_context(LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None,
                silence_logs=logging.CRITICAL, local_directory=local))
            client = stack.enter_context(Client(cluster))
        yield client
    finally:
        with deferred():
            stack.close()
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)


def check_workers(workers, scheduler) -> int | None:
    if scheduler is not None and workers is not None:
        raise ValueError("give either workers (a local cluster, 0 = serial) or scheduler (an existing cluster)")
    if scheduler is not None:
        if not str(scheduler).strip():
            raise ValueError("scheduler address is empty")
        return None
    if workers is None:
        return default_workers()
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
        raise ValueError(f"workers must be an integer >= 0, got {workers!r}")
    if workers > max_local_workers():
        raise ValueError(f"--workers {workers}: a local cluster of at most {max_local_workers()} worker processes "
                         f"on this machine ({default_workers()} cores); use --scheduler for a larger cluster")
    return workers
