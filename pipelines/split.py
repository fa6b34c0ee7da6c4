"""One large match split across Dask workers: blocks of query frames, each with enough warm-up frames.

The map is learned once and sent once; each task computes a block of query
frames with :attr:`vpr.methods.Method.block_margin` frames of warm-up on each
side (:meth:`vpr.methods.Fitted.match_part`), after which rSHOSM-seq's evidence
has forgotten what came before to within ``RshosmSeq.BLOCK_TOLERANCE``; the
decision then runs over every query in order in the client
(:meth:`vpr.methods.Fitted.combine`). Where the beam's floors bind, a block's
top-K columns approximate the serial ones (``benchmarks/bench_split.py``).
"""
from __future__ import annotations

import math
import pickle
import time
import uuid
import warnings

from vpr.types import EncodedTraverse, MatchResult

__all__ = ["split_match", "block_size"]


def block_size(n_q: int, margin: int, workers: int) -> int:
    """Query frames per block: two blocks per worker, but at least eight margins (the warm-up stays under 25 %)."""
    return max(8 * max(margin, 1), math.ceil(n_q / max(2 * workers, 1)))


def _unpack(payload: bytes):
    return pickle.loads(payload)


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
    payload = pickle.dumps(fitted, protocol=pickle.HIGHEST_PROTOCOL)
    t_pickle = time.perf_counter() - t
    futures, task_bytes = [], []
    with warnings.catch_warnings():
        # on purpose: the map once, then each block's query frames (one task each)
        warnings.filterwarnings("ignore", message="Large object")
        warnings.filterwarnings("ignore", message="Sending large graph")
        shared = client.submit(_unpack, payload, key=f"vpr-split-map-{run}", pure=False)
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
    result = fitted.combine([d[0] for d in done], time.perf_counter() - t)
    if shipped is not None:  # what was sent, and where the time went (a block's CPU seconds on its worker)
        shipped.update(map_bytes=len(payload), blocks=len(futures), block_frames=size, margin=margin,
                       task_bytes=max(task_bytes), pickle_seconds=round(t_pickle, 3),
                       block_cpu_seconds=[round(d[1], 3) for d in done], blocks_done_seconds=round(t_blocks, 3),
                       combine_seconds=round(time.perf_counter() - t - t_blocks, 3))
    return result
