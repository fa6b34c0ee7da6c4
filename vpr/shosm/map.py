"""A learned map, one file: the :class:`~vpr.shosm.Localizer`, the encoder that made its SDRs, where its frames were."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.sparse as sp

from vpr import io

from .localizer import Localizer
from .memory import SequenceMemory
from .state import read_file, write_file

__all__ = ["Map"]

_FORMAT = "vpr.Map"
_FORMAT_VERSION = 2


class Map:
    """A localizer with what a robot needs to use it again.

    Attributes
    ----------
    localizer : Localizer
    encoder : dict
        ``{"name", "conf"}`` of the encoder that made the database's SDRs.
    statistics : list of (mean, std) arrays
        What it fitted on the database, per part.
    positions, origin
        Each database frame's position (n_db, 2) and their GPS origin (latitude, longitude), or None.
    query_state : dict of arrays
        The query encoder's state so far.
    info : dict
        What the map was learned from (sources, frames, skipped, seconds, ``every``).
    sdr : csr matrix (n_db x bits) or None
        The database's SDRs, which :meth:`subset` learns again.
    follow_state : (header, arrays) or None
        The state of what follows the query's speed over the localizer (:class:`vpr.methods.SpeedFollower`).
    """

    def __init__(self, localizer: Localizer, encoder: dict, statistics=(), positions=None, origin=None,
                 info: dict | None = None, sdr=None):
        self.localizer, self.encoder = localizer, {"name": encoder["name"], "conf": dict(encoder["conf"])}
        self.statistics = [(np.asarray(m), np.asarray(s)) for m, s in statistics]
        self.positions = None if positions is None else np.asarray(positions, np.float64)
        if self.positions is not None and self.positions.shape[0] != localizer.n_db:
            raise ValueError(f"{self.positions.shape[0]} positions for a map of {localizer.n_db} frames")
        self.origin = None if origin is None else tuple(float(v) for v in origin)
        self.query_state: dict = {}
        self.follow_state: tuple[dict, dict] | None = None
        self.info = dict(info or {})
        self.sdr = None if sdr is None else sp.csr_matrix(sdr, dtype=bool)
        if self.sdr is not None and self.sdr.shape[0] != localizer.n_db:
            raise ValueError(f"{self.sdr.shape[0]} SDRs for a map of {localizer.n_db} frames")

    def spacing(self) -> float | None:
        """The median travel between consecutive frames of a session, metres (None without positions)."""
        if self.positions is None or self.positions.shape[0] < 2:
            return None
        step = np.linalg.norm(np.diff(self.positions, axis=0), axis=1)
        step[np.asarray(self.localizer.sessions[1:], np.int64) - 1] = np.nan  # no step across a session start
        moving = step[np.isfinite(step) & (step > 0)]
        return float(np.median(moving)) if moving.size else None

    def subset(self, keep, progress: bool = False) -> Map:
        """The map learned again from the frames numbered ``keep`` alone (e.g. one per so many metres, to follow a
        query sampled so: the sequence memory learns each kept frame as the successor of the one kept before).

        Raises
        ------
        ValueError
            The map holds no SDRs: learn it again.
        """
        if self.sdr is None:
            raise ValueError("the map holds no SDRs of its frames to learn again at another sampling; learn it again "
                             "with vpr learn")
        keep = np.asarray(sorted(set(int(k) for k in keep)), np.int64)
        new = self.localizer.relearned(self.sdr, keep, progress)
        out = Map(new, self.encoder, self.statistics, None if self.positions is None else self.positions[keep],
                  self.origin, {**self.info, "subset_of": self.localizer.n_db}, self.sdr[keep])
        out.query_state = self.query_state
        return out

    @staticmethod
    def is_map(path) -> bool:
        """Whether ``path`` is a map file (read by content, whatever its name)."""
        return io.is_versioned_npz(path, _FORMAT)

    def save(self, path) -> Path:
        """Write the map (atomic ``.npz``)."""
        loc = self.localizer
        mem_header, mem_arrays = loc.memory.state()
        q_header, q_arrays = loc.state()
        header = {"conf": loc.seq.flat(), "memory": mem_header, "query": q_header, "encoder": self.encoder,
                  "n_statistics": len(self.statistics), "db_shape": list(loc.db_codes.shape),
                  "sessions": loc.sessions.tolist(), "origin": self.origin, "info": self.info}
        stats = {}
        for i, (m, s) in enumerate(self.statistics):
            stats[f"mean{i}"], stats[f"std{i}"] = m, s
        db = {"indptr": loc.db_codes.indptr.astype(np.int64), "indices": loc.db_codes.indices.astype(np.int64)}
        if self.positions is not None:
            db["xy"] = self.positions
        if self.sdr is not None:
            db["sdr_indptr"], db["sdr_indices"] = self.sdr.indptr.astype(np.int64), self.sdr.indices.astype(np.int64)
            header["sdr_width"] = int(self.sdr.shape[1])
        parts = {"mem": mem_arrays, "query": q_arrays, "enc": stats, "qenc": self.query_state, "db": db}
        if self.follow_state is not None:
            header["follow"], parts["follow"] = self.follow_state
        return write_file(path, _FORMAT, _FORMAT_VERSION, header, parts, names=loc.names)

    @classmethod
    def load(cls, path) -> Map:
        """Read a file written by :meth:`save`; its localizer continues where it was saved.

        Raises
        ------
        MemoryFileError
            Missing, corrupt or foreign file (a map is written by ``vpr learn``), or another format version.
        """
        with read_file(path, _FORMAT, _FORMAT_VERSION, "map", " (written by `vpr learn` / Map.save)",
                       ("mem", "query", "enc", "qenc", "db", "follow")) as (header, parts, names):
            mem_h = header["memory"]
            mem = SequenceMemory(**mem_h["params"]).load_state(mem_h, parts["mem"])
            n_db, width = header["db_shape"]
            idx = parts["db"]["indices"]
            codes = sp.csr_matrix((np.ones(idx.size, bool), idx, parts["db"]["indptr"]), shape=(n_db, width))
            loc = Localizer(mem, codes, names, sessions=header["sessions"], **header["conf"])
            loc.load_state(header["query"], parts["query"])
            enc = parts["enc"]
            stats = [(enc[f"mean{i}"], enc[f"std{i}"]) for i in range(int(header["n_statistics"]))]
            db = parts["db"]
            sdr = None
            if "sdr_indptr" in db:
                sdr = sp.csr_matrix((np.ones(db["sdr_indices"].size, bool), db["sdr_indices"], db["sdr_indptr"]),
                                    shape=(n_db, int(header["sdr_width"])))
            out = cls(loc, header["encoder"], stats, db.get("xy"), header.get("origin"), header["info"], sdr)
            out.query_state = parts["qenc"]
            if header.get("follow") is not None:
                out.follow_state = (header["follow"], parts["follow"])
        return out

    def __repr__(self) -> str:
        return f"Map({self.encoder['name']}, {self.localizer!r})"
