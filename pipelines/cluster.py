"""The Dask cluster a run uses, and what runs on it: a map sent once, then its tasks.

``workers=N`` starts N single-threaded worker processes on 127.0.0.1 for the
run and stops them after it, Ctrl-C and SIGTERM included; ``scheduler=ADDRESS``
connects to a running cluster and fails in one line within
:data:`CONNECT_TIMEOUT` seconds when nothing there answers as Dask. Dask is
imported only once a cluster is used: serial runs do not need it.

:func:`send_once` puts a learned map on the cluster once, as the one task that
unpacks it (not scattered: the cluster may drop replicas of scattered data, and
data scattered to a worker that dies is lost; a task's result is recomputed).
:func:`split_match` matches one long query in blocks of query frames, each with
:attr:`vpr.methods.Method.block_margin` frames of warm-up on each side
(:meth:`vpr.methods.Fitted.match_part`), after which rSHOSM-seq's evidence has
forgotten what came before to within ``RshosmSeq.BLOCK_TOLERANCE``; the
decision runs over every query in order in the client
(:meth:`vpr.methods.Fitted.combine`). Where the beam's floors bind, a block's
top-K columns approximate the serial ones (``research/benchmarks/bench_split.py``).
"""
from __future__ import annotations

import contextlib
import math
import os
import pickle
import time
import uuid
import warnings
from pathlib import Path

from vpr.interrupts import deferred
from vpr.types import EncodedTraverse, MatchResult

__all__ = ["CONNECT_TIMEOUT", "check_workers", "dask_client", "default_workers", "max_local_workers", "send_once",
           "run_tasks", "block_size", "split_match"]


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
        # closing after a stop races the scheduler's last reports to the client, which it logs at CRITICAL:
        # the run has already said in one line why it ended
        quiet = [logging.getLogger(name) for name in ("distributed", "distributed.scheduler")]
        levels = [q.level for q in quiet]
        for q in quiet:
            q.setLevel(logging.CRITICAL + 1)
        try:
            with deferred():
                stack.close()
        finally:
            for q, level in zip(quiet, levels, strict=True):
                q.setLevel(level)
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


def _unpack(payload: bytes):
    return pickle.loads(payload)


def send_once(client, obj, key: str):
    """(future of ``obj`` on the cluster, its bytes): sent once, as the one task that unpacks it."""
    payload = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Large object")  # on purpose: the map, once
        warnings.filterwarnings("ignore", message="Sending large graph")
        return client.submit(_unpack, payload, key=key, pure=False), len(payload)


def run_tasks(client, fn, shared, jobs: dict, progress=None) -> dict:
    """``fn(shared, *job)`` of every job (name -> arguments) on the cluster, retried where a worker dies; results by
    name; ``progress(name, done, total)`` as they come."""
    from distributed import as_completed

    run = uuid.uuid4().hex[:8]
    futures = {client.submit(fn, shared, *job, key=f"vpr-task-{run}-{n}", pure=False, retries=2): n
               for n, job in jobs.items()}
    out = {}
    try:
        for k, fut in enumerate(as_completed(list(futures))):
            out[futures[fut]] = fut.result()
            fut.release()
            if progress:
                progress(futures[fut], k + 1, len(futures))
    except BaseException:
        client.cancel(list(futures))
        raise
    return out


def block_size(n_q: int, margin: int, workers: int) -> int:
    """Query frames per block: two blocks per worker, but at least eight margins (the warm-up stays under 25 %)."""
    return max(8 * max(margin, 1), math.ceil(n_q / max(2 * workers, 1)))


def _block(fitted, part: bytes, lo: int, hi: int, n_q: int):
    """One block on a worker; ``part``: its query frames, pickled once by the client (their size is reported)."""
    t = time.process_time()
    return fitted.match_part(_unpack(part), lo, hi, n_q), time.process_time() - t


def split_match(fitted, query: EncodedTraverse, client, workers: int, shipped: dict | None = None,
                block_frames: int | None = None) -> MatchResult:
    """``fitted.match(query)`` computed in blocks on ``client``'s workers.

    ``block_frames``: query frames per block (default :func:`block_size`);
    ``shipped`` gets what was sent: the map's bytes once, the largest task's
    bytes, the blocks and their size.
    """
    from distributed import wait

    t = time.perf_counter()
    n_q = len(query)
    margin = fitted.method.block_margin
    size = block_size(n_q, margin, workers) if block_frames is None else int(block_frames)
    if size < 1:
        raise ValueError(f"block_frames must be >= 1, got {block_frames}")
    run = uuid.uuid4().hex[:8]
    shared, map_bytes = send_once(client, fitted, f"vpr-split-map-{run}")
    t_pickle = time.perf_counter() - t
    futures, task_bytes = [], []
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Large object")  # each block's query frames, once
        warnings.filterwarnings("ignore", message="Sending large graph")
        for start in range(0, n_q, size):
            stop = min(start + size, n_q)
            a, b = fitted.block_bounds(start, stop, n_q)
            part = pickle.dumps(query.slice(a, b), protocol=pickle.HIGHEST_PROTOCOL)
            task_bytes.append(len(part))
            futures.append(client.submit(_block, shared, part, start - a, stop - a, n_q, pure=False, retries=2,
                                         key=f"vpr-split-{run}-{start}"))
    try:
        wait(futures)
        done = [f.result() for f in futures]
    except BaseException:
        client.cancel(futures + [shared])
        raise
    t_blocks = time.perf_counter() - t
    result = fitted.combine([d[0] for d in done], time.perf_counter() - t, query)
    if shipped is not None:  # what was sent, and where the time went (a block's CPU seconds on its worker)
        shipped.update(map_bytes=map_bytes, blocks=len(futures), block_frames=size, margin=margin,
                       task_bytes=max(task_bytes), pickle_seconds=round(t_pickle, 3),
                       block_cpu_seconds=[round(d[1], 3) for d in done], blocks_done_seconds=round(t_blocks, 3),
                       combine_seconds=round(time.perf_counter() - t - t_blocks, 3))
    return result
