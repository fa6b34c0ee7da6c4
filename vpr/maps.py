"""A learned map, one file: a method's :class:`~vpr.types.MapLocalizer`, the encoder that made its SDRs, where its
frames were."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.sparse as sp

from vpr import io
from vpr.statefile import read_file, write_file
from vpr.types import MapLocalizer

__all__ = ["Map"]

_FORMAT = "vpr.Map"
_FORMAT_VERSION = 3
_HINT = " (written by `vpr learn` / Map.save)"


class Map:
    """A localizer with what a robot needs to use it again.

    Attributes
    ----------
    method : str
        The method that learned it (the name :mod:`vpr.methods` finds it by).
    localizer : MapLocalizer
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
        The state of what follows the query's speed over the localizer (:class:`~vpr.types.FollowingLocalizer`).
    late_state : (header, arrays) or None
        The state of what answers the query frames late (:class:`~vpr.types.LateLocalizer`): the frames waiting.
    """

    def __init__(self, method: str, localizer: MapLocalizer, encoder: dict, statistics=(), positions=None,
                 origin=None, info: dict | None = None, sdr=None):
        self.method = str(method)
        self.localizer, self.encoder = localizer, {"name": encoder["name"], "conf": dict(encoder["conf"])}
        self.statistics = [(np.asarray(m), np.asarray(s)) for m, s in statistics]
        self.positions = None if positions is None else np.asarray(positions, np.float64)
        if self.positions is not None and self.positions.shape[0] != localizer.n_db:
            raise ValueError(f"{self.positions.shape[0]} positions for a map of {localizer.n_db} frames")
        self.origin = None if origin is None else tuple(float(v) for v in origin)
        self.query_state: dict = {}
        self.follow_state: tuple[dict, dict] | None = None
        self.late_state: tuple[dict, dict] | None = None
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
        xy = None if self.positions is None else self.positions[keep]
        info = {**self.info, "subset_of": self.localizer.n_db}
        out = Map(self.method, new, self.encoder, self.statistics, xy, self.origin, info, self.sdr[keep])
        out.query_state = self.query_state
        return out

    @staticmethod
    def is_map(path) -> bool:
        """Whether ``path`` is a map file (read by content, whatever its name)."""
        return io.is_versioned_npz(path, _FORMAT)

    def save(self, path) -> Path:
        """Write the map (atomic ``.npz``)."""
        loc_header, loc_parts = self.localizer.map_state()
        header = {"method": self.method, "localizer": loc_header, "encoder": self.encoder,
                  "n_statistics": len(self.statistics), "n_db": self.localizer.n_db, "origin": self.origin,
                  "info": self.info}
        stats = {}
        for i, (m, s) in enumerate(self.statistics):
            stats[f"mean{i}"], stats[f"std{i}"] = m, s
        db = {}
        if self.positions is not None:
            db["xy"] = self.positions
        if self.sdr is not None:
            db["sdr_indptr"], db["sdr_indices"] = self.sdr.indptr.astype(np.int64), self.sdr.indices.astype(np.int64)
            header["sdr_width"] = int(self.sdr.shape[1])
        parts = {**loc_parts, "enc": stats, "qenc": self.query_state, "db": db}
        if self.follow_state is not None:
            header["follow"], parts["follow"] = self.follow_state
        if self.late_state is not None:
            header["late"], parts["late"] = self.late_state
        return write_file(path, _FORMAT, _FORMAT_VERSION, header, parts, names=self.localizer.names)

    @classmethod
    def load(cls, path, restore) -> Map:
        """Read a file written by :meth:`save`; its localizer continues where it was saved.

        ``restore(method, header, parts, names)``: the localizer of the map's method (its name) from what its
        :meth:`~vpr.types.MapLocalizer.map_state` wrote (``vpr.methods.load_map`` hands it to the method).

        Raises
        ------
        MemoryFileError
            Missing, corrupt or foreign file (a map is written by ``vpr learn``), or another format version.
        """
        with read_file(path, _FORMAT, _FORMAT_VERSION, "map", _HINT) as (header, parts, names):
            loc = restore(header["method"], header["localizer"], parts, names)
            enc = parts.get("enc", {})
            stats = [(enc[f"mean{i}"], enc[f"std{i}"]) for i in range(int(header["n_statistics"]))]
            db = parts.get("db", {})
            sdr = None
            if "sdr_indptr" in db:
                sdr = sp.csr_matrix((np.ones(db["sdr_indices"].size, bool), db["sdr_indices"], db["sdr_indptr"]),
                                    shape=(loc.n_db, int(header["sdr_width"])))
            out = cls(header["method"], loc, header["encoder"], stats, db.get("xy"), header.get("origin"),
                      header["info"], sdr)
            out.query_state = parts.get("qenc", {})
            if header.get("follow") is not None:
                out.follow_state = (header["follow"], parts.get("follow", {}))
            if header.get("late") is not None:
                out.late_state = (header["late"], parts.get("late", {}))
        return out

    def __repr__(self) -> str:
        return f"Map({self.method}, {self.encoder['name']}, {self.localizer!r})"
