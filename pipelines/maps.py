"""A map learned from a database traverse with an encoder, and read again with its encoder.

:func:`learn` opens the database's sources (a session each), encodes them
(each standardised on its own frames), learns them with a method that runs
online and writes a :class:`vpr.maps.Map`; :func:`load_map` reads it with the encoder rebuilt
from the map (its fitted statistics set). ``vpr learn`` and ``vpr localize``
call them; so does a robot's own code.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from encoders import get
from encoders.base import DescriptorEncoder
from pipelines.extract import extract
from vpr import io, methods
from vpr.groundtruth import GroundTruthSpec, check_rates, prepare_positions
from vpr.methods import Map
from vpr.sources import check_ordered, open_sources

__all__ = ["learn", "load_map", "map_path", "map_encoder", "plan_learn", "learn_plan", "LearnPlan"]


def map_path(out) -> Path:
    """Where ``vpr learn --out OUT`` writes: ``OUT``, with ``.npz`` added when it has another suffix or none."""
    out = Path(out)
    io.check_writable(out, "--out")
    return out if out.suffix.lower() == ".npz" else out.with_name(out.name + ".npz")


@dataclass
class LearnPlan:
    """A database checked and opened for learning, before any frame is read (:func:`plan_learn`).

    ``srcs`` and ``roles``: its sessions; ``positions``: their frames' positions (or None); ``names`` and ``indices``:
    the frames to read (prefixed by the session where there are several); ``encoder`` and ``method``: what encodes
    and learns them.
    """

    db: object
    srcs: list
    roles: list
    spec: GroundTruthSpec
    positions: list | None
    every: float | None
    encoder: object
    method: object

    def names(self) -> list[str]:
        prefix = len(self.srcs) > 1
        return [f"{s.name}/{n}" if prefix else n for s in self.srcs for n in s.names()]

    def indices(self) -> list[int]:
        """The frame numbers of a single database (several sessions: their frames counted across them)."""
        return list(self.srcs[0].indices()) if len(self.srcs) == 1 else list(range(len(self.names())))

    def origin(self):
        return None if self.positions is None else self.positions.origin


def plan_learn(db, encoder: str = "pixel", encoder_conf: dict | None = None, method: str | None = None,
               method_conf: dict | None = None, positions: GroundTruthSpec | None = None, every: float | None = None,
               prefix: str | None = None, **source) -> LearnPlan:
    """Check and open the database ``db`` for :func:`learn_plan`: every refusal of :func:`learn` before a frame is
    read (its keywords as :func:`learn`'s)."""
    enc = get(encoder, **(encoder_conf or {}))
    method = methods.get_online(method or methods.online(), sdr_bits=enc.n_bits, encoder=f"--encoder {enc.name}",
                                **(method_conf or {}))
    dbs = [db] if isinstance(db, (str, Path)) else list(db)
    srcs = open_sources(dbs, prefix=[prefix] * len(dbs) if prefix else None, prefix_flags=["--db-prefix"] * len(dbs),
                        **source)
    roles = ["database"] if len(srcs) == 1 else [f"database session {k + 1}" for k in range(len(srcs))]
    check_ordered(srcs, roles, [method.name] if method.reads_order else [])
    spec = positions or GroundTruthSpec()
    pos = prepare_positions(srcs, roles, spec, every, loops=False, need=bool(spec.topic or spec.files))
    check_rates(srcs, every)
    chosen = (("--step", source.get("step")), ("--max-frames", source.get("max_frames")))
    enc.check_sources(srcs, roles, " and ".join(f"{f} {v}" for f, v in chosen if v))
    if enc.conf.get("standardise") in ("per_batch", "causal"):
        raise ValueError(f"encoders with standardise={enc.conf['standardise']} cannot encode one query frame at a "
                         "time; use standardise=fit (vpr localize then standardises the query causally, --window)")
    return LearnPlan(db, srcs, roles, spec, pos, every, enc, method)


def learn_plan(plan: LearnPlan, progress: bool = True) -> Map:
    """Encode and learn the database of ``plan`` (:func:`plan_learn`); return its map, not written."""
    srcs, enc, method = plan.srcs, plan.encoder, plan.method
    dbs = [plan.db] if isinstance(plan.db, (str, Path)) else list(plan.db)
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
    if plan.positions is not None:  # the positions of the frames learned (skipped ones are not in the map)
        xy = np.concatenate([p[[{k: r for r, k in enumerate(src.indices())}[k] for k in ex.indices]]
                             for src, ex, p in zip(srcs, exs, plan.positions, strict=True)])
    rates = [r for r in (s.rate() for s in srcs) if r]  # frames per second where the sources have times
    info = {"db": str(plan.db) if not prefix else [str(d) for d in dbs], "db_source": srcs[0].name,
            "db_indices": [] if prefix else list(exs[0].indices or []),
            "skipped": [sk for ex in exs for sk in ex.skipped], "encode_seconds": t_enc,
            "learn_seconds": time.perf_counter() - t,
            "positions": plan.spec.describe() if plan.positions is not None else None,
            "every": plan.every, "rate": float(np.median(rates)) if rates else None,
            "source_rate": None if prefix else srcs[0].native_rate()}
    stats = enc.statistics() if fitted else []  # the last session's
    return Map(method.name, loc, {"name": enc.name, "conf": enc.conf}, stats, xy, plan.origin(), info, sdr)


def learn(db, out, encoder: str = "pixel", encoder_conf: dict | None = None, method: str | None = None,
          method_conf: dict | None = None, progress: bool = True, positions: GroundTruthSpec | None = None,
          every: float | None = None, prefix: str | None = None, **source) -> Map:
    """Encode and learn the database traverse ``db``; write the map to :func:`map_path` ``(out)`` (atomic).

    ``db``: one source, or a list of sources: the sessions of a multi-session map (each encoded and standardised on
    its own frames, learned one after the other from a fresh context). ``method``: the method that learns it (one
    that runs online; default :func:`vpr.methods.online`) and ``method_conf`` its conf, checked before any work; the
    map keeps them. ``positions``: where the frames' positions are (``--gt-topic``, ``--gt FILE``, ``names``,
    ``exif``): the map keeps them, and ``every`` (metres) keeps one frame per so much travel. ``source``: the frames
    read (``fps``, ``step``, ``max_frames``, a bag's camera ``topic``: :func:`vpr.sources.open_sources`); ``prefix``:
    an hloc ``.h5``'s frames whose names begin with it.
    """
    out = map_path(out)
    plan = plan_learn(db, encoder, encoder_conf, method, method_conf, positions, every, prefix, **source)
    the_map = learn_plan(plan, progress)
    the_map.save(out)
    return the_map


def map_encoder(the_map: Map):
    """The encoder of ``the_map``, with what it fitted on the database set."""
    enc = get(the_map.encoder["name"], **the_map.encoder["conf"])
    if the_map.statistics:
        enc.set_statistics(the_map.statistics)
    return enc


def load_map(path) -> tuple[Map, object]:
    """(map, encoder with the database's fitted statistics) of a map written by :func:`learn`."""
    the_map = methods.load_map(path)
    return the_map, map_encoder(the_map)
