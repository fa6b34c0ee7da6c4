"""``vpr encode SOURCE... --cache DIR``: encode traverses ahead of time, on a Dask cluster.

Each source is split into frame ranges that workers read and describe
themselves; the client joins a source's ranges in order, fits the encoder on
the whole traverse where its conf asks, and writes one cache file per source
(:func:`pipelines.extract.cache_path`), byte for byte what a serial
:func:`pipelines.extract.extract` writes. ``workers=0`` runs here, ``workers=N``
on a local cluster of single-threaded workers, ``scheduler=ADDRESS`` on a
running one; a dead worker's chunks run again elsewhere.
"""
from __future__ import annotations

import argparse
import copy
import json
import os
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from pipelines.args import (
    add_common_arguments,
    add_preset_argument,
    add_source_arguments,
    descriptor_inputs,
    input_encoder,
    input_preset,
    topic_arg,
)
from pipelines.cluster import check_workers, dask_client, default_workers
from pipelines.extract import (
    DEFAULT_CHUNK_FRAMES,
    assemble,
    available_inputs,
    cache_path,
    check_inputs,
    chunk_ranges,
    encode_chunk,
    held_inputs,
    load_cache,
    save_cache,
)
from vpr import presets
from vpr.interrupts import deferred
from vpr.sources import Source, open_source, open_sources
from vpr.types import ENCODER_INPUTS

__all__ = ["COMMANDS", "add_arguments", "run_command", "encode_sources", "Encoded"]

COMMANDS = {"encode": "encode traverses (folders, videos, lists) into a cache for match/compare/loops, on Dask"}


@dataclass
class Encoded:
    """Outcome for one source."""

    source: str
    path: Path
    n_frames: int
    skipped: list = field(default_factory=list)
    cached: bool = False
    seconds: float = 0.0


# one encoder per worker process and conf: the cnn encoder loads its ONNX model once, not per chunk
_WORKER_ENCODERS: dict = {}


def _chunk_task(source: Source, encoder_name: str, conf_json: str, start: int, stop: int, parts, batch_size: int):
    import encoders

    key = (encoder_name, conf_json)
    if key not in _WORKER_ENCODERS:
        _WORKER_ENCODERS[key] = encoders.get(encoder_name, **json.loads(conf_json))
    # a copy: a worker with several threads shares the scattered source, whose ``skipped`` a range resets
    return encode_chunk(copy.copy(source), _WORKER_ENCODERS[key], start, stop, parts, batch_size=batch_size)


def encode_sources(sources, cache_dir, encoder_name: str = "pixel", encoder_conf: dict | None = None,
                   chunk_frames: int = DEFAULT_CHUNK_FRAMES, parts=None, overwrite: bool = False,
                   batch_size: int = 64, progress=True, **cluster) -> list[Encoded]:
    """Encode ``sources`` into ``cache_dir``, one cache file per source.

    Parameters
    ----------
    sources : list of :class:`vpr.sources.Source` or paths (opened with default options)
        Frame selection (``fps``, ``step``, ``max_frames``) is part of the cache
        key: open the sources as the later ``vpr match`` will.
    cache_dir : folder of the cache files (created if needed).
    encoder_name, encoder_conf : as :func:`encoders.get`.
    chunk_frames : frames per task.
    parts : the inputs to store, a subset of :func:`pipelines.extract.available_inputs`
        (default all: ``sdr``, ``desc`` and every method's image inputs, so any
        later method finds what it needs).
    overwrite : encode again even when a cache file with these parts exists.
    batch_size : frames per encoder call inside a task.
    progress : True for a progress bar, False for none, or a callable receiving
        ``(source_position, start, stop, chunks_done, chunks_total)`` after each chunk.
    cluster : ``workers``, local worker processes (1 thread each; 0 runs serially in
        this process; None, the default, the number of cores), or ``scheduler``, the
        address of a running Dask scheduler (``tcp://host:port``); not both.

    Returns
    -------
    list of :class:`Encoded`, in the order of ``sources``.

    Raises
    ------
    ValueError
        Bad arguments, an unknown encoder or conf key, or a source without a readable frame.
    """
    import encoders

    unknown = sorted(set(cluster) - {"workers", "scheduler"})
    if unknown:
        raise TypeError(f"encode_sources: unknown option {', '.join(unknown)}")
    workers, scheduler = cluster.get("workers"), cluster.get("scheduler")
    n_workers = check_workers(workers, scheduler)
    parts = available_inputs() if parts is None else check_inputs(parts, "part")
    if not parts:
        raise ValueError(f"parts is empty; choose from {', '.join(available_inputs())}")
    srcs = [s if isinstance(s, Source) else open_source(s) for s in sources]
    if not srcs:
        raise ValueError("no sources given")
    encoder = encoders.get(encoder_name, **dict(encoder_conf or {}))
    encoder.check_memory(max(len(s.indices()) for s in srcs))
    # the merged conf goes to the workers, so that they build exactly the encoder keyed in the cache
    conf_json = json.dumps(encoder.conf, sort_keys=True)
    cache_dir = Path(cache_dir)
    t0 = time.perf_counter()
    results: list[Encoded | None] = [None] * len(srcs)
    plan = {}  # source position -> chunk ranges
    for i, src in enumerate(srcs):
        path = cache_path(cache_dir, src, encoder)
        hit = None if overwrite or not path.is_file() else load_cache(path)
        if hit is not None and set(parts) <= set(held_inputs(hit)):
            results[i] = Encoded(str(src.path), path, len(hit.features), hit.skipped, True, 0.0)
            continue
        ranges = chunk_ranges(len(src.names()), chunk_frames)
        if not ranges:
            raise ValueError(f"{src.path}: no frames selected")
        plan[i] = ranges
    jobs = [(i, a, b) for i, ranges in plan.items() for a, b in ranges]
    if not jobs:
        return results
    done: dict = {i: [] for i in plan}
    report = _reporter(progress, srcs, jobs)

    def finished(i, chunk):
        done[i].append(chunk)
        report(i, chunk.start, chunk.stop)
        if len(done[i]) == len(plan[i]):
            # a fresh encoder per source: fitting must not carry over from one traverse to the next
            enc = encoders.get(encoder_name, **json.loads(conf_json))
            ex = assemble(srcs[i], enc, done.pop(i), parts)
            path = save_cache(cache_path(cache_dir, srcs[i], enc), ex, srcs[i], enc)
            results[i] = Encoded(str(srcs[i].path), path, len(ex.features), ex.skipped, False,
                                 time.perf_counter() - t0)

    try:
        if n_workers == 0:
            for i, a, b in jobs:
                finished(i, _chunk_task(srcs[i], encoder_name, conf_json, a, b, parts, batch_size))
        else:
            # no more local workers than tasks; their scratch space under the cache folder
            n_local = None if n_workers is None else min(n_workers, len(jobs))
            _run_on_dask(n_local, scheduler, srcs, jobs, encoder_name, conf_json, parts, batch_size, finished,
                         cache_dir / f".dask-scratch-{os.getpid()}")
    finally:
        report.close()
    return results


def _run_on_dask(n_workers, scheduler, srcs, jobs, encoder_name, conf_json, parts, batch_size, finished,
                 scratch: Path | None = None) -> None:
    from distributed import as_completed

    run = uuid.uuid4().hex[:8]
    with dask_client(n_workers, scheduler, scratch) as client:
        # each source goes to every worker once, not with every task (a folder lists all its files);
        # replicas on every worker survive the death of one of them; a stop during the (short) scatter
        # would close the cluster under the scheduler's replication, which then logs errors
        with deferred():
            client.wait_for_workers(1, timeout=60)
            shared = {i: client.scatter([srcs[i]], broadcast=True, hash=False)[0]
                      for i in sorted({i for i, _, _ in jobs})}
        futures = {}
        for i, a, b in jobs:
            fut = client.submit(_chunk_task, shared[i], encoder_name, conf_json, a, b, parts, batch_size,
                                key=f"vpr-encode-{run}-{i}-{a}", pure=False)
            futures[fut] = i
        try:
            for fut in as_completed(list(futures)):
                chunk = fut.result()
                fut.release()
                finished(futures[fut], chunk)
        except BaseException:
            client.cancel(list(futures))
            raise


class _reporter:
    """Progress as a tqdm bar over frames, a user callable, or nothing."""

    def __init__(self, progress, srcs, jobs):
        self.total, self.n = len(jobs), 0
        self.callback = progress if callable(progress) else None
        self.bar = None
        if progress is True:
            from tqdm import tqdm  # optional module, only for the bar

            self.bar = tqdm(total=sum(b - a for _, a, b in jobs), unit="frame", desc="encode", leave=False)

    def __call__(self, i, start, stop):
        self.n += 1
        if self.bar is not None:
            self.bar.update(stop - start)
        if self.callback is not None:
            self.callback(i, start, stop, self.n, self.total)

    def close(self):
        if self.bar is not None:
            self.bar.close()


# ------------------------------------------------------------------ command line
def add_arguments(ap: argparse.ArgumentParser, command: str = "encode") -> None:
    import encoders

    ap.add_argument("sources", metavar="SOURCE", nargs="+", help="image folders, videos, image lists, ROS bags "
                    "or descriptor files (.npy, hloc .h5)")
    ap.add_argument("--cache", required=True, metavar="DIR",
                    help="cache folder; give the same to match/compare/loops/localize --cache")
    # the preset's encoder unless --encoder is given, so that `vpr compare --cache DIR` with the same preset hits
    add_preset_argument(ap)
    encoders.add_arguments(ap, default=None)
    add_source_arguments(ap)  # as later for match: the frame selection is part of the cache key
    where = ap.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, metavar="N",
                       help=f"local Dask worker processes, 1 thread each (default: the number of cores, "
                            f"{default_workers()}); 0 runs serially in this process")
    where.add_argument("--scheduler", metavar="ADDRESS", help="use a running Dask cluster, e.g. tcp://host:8786")
    ap.add_argument("--chunk-frames", type=int, default=DEFAULT_CHUNK_FRAMES,
                    help=f"frames per task (default {DEFAULT_CHUNK_FRAMES})")
    ap.add_argument("--parts", default=None,
                    help=f"what to store, comma-separated subset of {','.join(available_inputs())} (default: all; "
                         f"descriptor files: {','.join(ENCODER_INPUTS)})")
    ap.add_argument("--overwrite", action="store_true", help="encode again even when the cache has the result")
    add_common_arguments(ap)


def run_command(args) -> int:
    import encoders

    if args.every:
        raise ValueError("vpr encode: --every needs the frames' positions, which vpr encode does not read; encode "
                         "without it (vpr match / compare / loops --every then encode what they keep)")
    srcs = open_sources(args.sources, topic_arg(args.topic), False, fps=args.fps, step=args.step,
                        max_frames=args.max_frames)
    given = descriptor_inputs(args)  # descriptor files: their sparsifier and preset, as vpr compare reads them
    if args.parts is None:
        parts = list(ENCODER_INPUTS if given else available_inputs())
    else:
        parts = [p.strip() for p in args.parts.split(",") if p.strip()]
        images = [p for p in parts if p not in ENCODER_INPUTS]
        if given and images:
            raise ValueError(f"--parts {','.join(images)}: read from images, and {given[0]} holds descriptors; "
                             f"the parts of descriptor files: {','.join(ENCODER_INPUTS)}")
    s = presets.resolve(input_preset(args, given), encoder=input_encoder(args, given),
                        encoder_conf=encoders.parse_conf(args.encoder_conf))
    out = encode_sources(srcs, args.cache, s["encoder"], s["encoder_conf"],
                         workers=args.workers, scheduler=args.scheduler, chunk_frames=args.chunk_frames,
                         parts=parts, overwrite=args.overwrite, progress=not args.no_progress)
    width = max(len(r.source) for r in out)
    for r in out:
        state = "cached" if r.cached else f"{r.seconds:.1f} s"
        print(f"{r.source:<{width}}  {r.n_frames:7d} frames  {len(r.skipped):4d} skipped  {state:>9}  {r.path}")
    return 0
