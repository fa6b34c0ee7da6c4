"""A map learned from a database traverse with an encoder, and read again with its encoder.

:func:`learn` opens the database's sources (a session each), encodes them
(each standardised on its own frames), learns them with a method that runs
online and writes a :class:`vpr.maps.Map`; :func:`load_map` reads it with the encoder rebuilt
from the map (its fitted statistics set). ``vpr learn`` and ``vpr localize``
call them; so does a robot's own code.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from encoders import get
from encoders.base import DescriptorEncoder
from pipelines.extract import extract
from vpr import io, methods
from vpr.groundtruth import GroundTruthSpec, check_rates, prepare_positions
from vpr.methods import Map
from vpr.sources import open_sources

__all__ = ["learn", "load_map", "map_path"]


def map_path(out) -> Path:
    """Where ``vpr learn --out OUT`` writes: ``OUT``, with ``.npz`` added when it has another suffix or none."""
    out = Path(out)
    io.check_writable(out, "--out")
    return out if out.suffix.lower() == ".npz" else out.with_name(out.name + ".npz")


def learn(db, out, encoder: str = "pixel", encoder_conf: dict | None = None, method: str | None = None,
          method_conf: dict | None = None, progress: bool = True, positions: GroundTruthSpec | None = None,
          every: float | None = None, **source) -> Map:
    """Encode and learn the database traverse ``db``; write the map to :func:`map_path` ``(out)`` (atomic).

    ``db``: one source, or a list of sources: the sessions of a multi-session map (each encoded and standardised on
    its own frames, learned one after the other from a fresh context). ``method``: the method that learns it (one
    that runs online; default :func:`vpr.methods.online`) and ``method_conf`` its conf, checked before any work; the
    map keeps them. ``positions``: where the frames' positions are (``--gt-topic``, ``--gt FILE``, ``names``,
    ``exif``): the map keeps them, and ``every`` (metres) keeps one frame per so much travel. ``source``: the frames
    read (``fps``, ``step``, ``max_frames``, a bag's camera ``topic``: :func:`vpr.sources.open_sources`).
    """
    out = map_path(out)
    method = methods.get_online(method or methods.online(), **(method_conf or {}))
    dbs = [db] if isinstance(db, (str, Path)) else list(db)
    srcs = open_sources(dbs, **source)
    roles = ["database"] if len(srcs) == 1 else [f"database session {k + 1}" for k in range(len(srcs))]
    spec = positions or GroundTruthSpec()
    pos = prepare_positions(srcs, roles, spec, every, loops=False, need=bool(spec.topic or spec.files))
    check_rates(srcs, every)
    rates = [r for r in (s.rate() for s in srcs) if r]  # frames per second where the sources have times
    enc = get(encoder, **(encoder_conf or {}))
    chosen = (("--step", source.get("step")), ("--max-frames", source.get("max_frames")))
    enc.check_sources(srcs, roles, " and ".join(f"{f} {v}" for f, v in chosen if v))
    if enc.conf.get("standardise") in ("per_batch", "causal"):
        raise ValueError(f"encoders with standardise={enc.conf['standardise']} cannot encode one query frame at a "
                         "time; use standardise=fit (vpr localize then standardises the query causally, --window)")
    t = time.perf_counter()
    exs = [extract(src, enc, ("sdr",), progress=progress) for src in srcs]  # each session fitted on itself
    t_enc = time.perf_counter() - t
    t = time.perf_counter()
    prefix = len(srcs) > 1
    names = [f"{s.name}/{n}" if prefix else n for s, ex in zip(srcs, exs, strict=True) for n in ex.features.names]
    starts = np.cumsum([0, *[len(ex.features) for ex in exs[:-1]]]).tolist()
    sdr = sp.vstack([ex.features.sdr for ex in exs]).tocsr()
    loc = method.localizer(sdr, names, progress=progress, sessions=starts)
    fitted = isinstance(enc, DescriptorEncoder) and enc.conf.get("standardise") == "fit"
    xy = None
    if pos is not None:  # the positions of the frames learned (skipped ones are not in the map)
        xy = np.concatenate([p[[{k: r for r, k in enumerate(src.indices())}[k] for k in ex.indices]]
                             for src, ex, p in zip(srcs, exs, pos, strict=True)])
    info = {"db": str(db) if not prefix else [str(d) for d in dbs], "db_source": srcs[0].name,
            "db_indices": [] if prefix else list(exs[0].indices or []),
            "skipped": [sk for ex in exs for sk in ex.skipped], "encode_seconds": t_enc,
            "learn_seconds": time.perf_counter() - t, "positions": spec.describe() if pos is not None else None,
            "every": every, "rate": float(np.median(rates)) if rates else None,
            "source_rate": None if prefix else srcs[0].native_rate()}
    stats = enc.statistics() if fitted else []  # the last session's
    origin = None if pos is None else pos.origin
    the_map = Map(method.name, loc, {"name": enc.name, "conf": enc.conf}, stats, xy, origin, info, sdr)
    the_map.save(out)
    return the_map


def load_map(path) -> tuple[Map, object]:
    """(map, encoder with the database's fitted statistics) of a map written by :func:`learn`."""
    the_map = methods.load_map(path)
    enc = get(the_map.encoder["name"], **the_map.encoder["conf"])
    if the_map.statistics:
        enc.set_statistics(the_map.statistics)
    return the_map, enc
