"""A toy method that runs online, written against the Method contract alone (the test of the one door).

Each frame's answer is the earlier frame (loops) or the map frame (localize) whose SDR shares the most bits with
it, accepted where it shares at least ``min_share`` of them. Registered by the test that uses it with one line:
``methods.register("toy-online", "tests.toy_online", "ToyOnline")``.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from vpr.methods import Method
from vpr.similarity import n_candidates, overlap_similarity
from vpr.statefile import read_file, write_file
from vpr.types import Column, Decision, EncodedTraverse, MapLocalizer, StreamDetector

_FORMAT, _VERSION = "toy.Detector", 1


def _answer(rows: sp.csr_matrix, bits: np.ndarray, n: int, min_share: float, frame: int) -> Decision:
    """The best of the first ``n`` rows for a frame of active ``bits``, as a decision with its column."""
    if n <= 0 or not bits.size:
        return Decision(-1, float("-inf"), False, 0.0, frame, Column(np.zeros(0, np.int64), np.zeros(0, np.float32),
                                                                     0.0, max(n, 0), frame))
    x = np.zeros(rows.shape[1], bool)
    x[bits] = True
    share = np.asarray(rows[:n].astype(np.float32) @ x.astype(np.float32)).ravel() / bits.size
    best = int(np.argmax(share))
    column = Column(np.arange(n), share.astype(np.float32), 0.0, n, frame)
    return Decision(best, float(share[best]), bool(share[best] >= min_share), 0.0, frame, column)


def _bits(rows: sp.csr_matrix, r: int) -> np.ndarray:
    return rows.indices[rows.indptr[r]:rows.indptr[r + 1]].astype(np.int64)


class ToyDetector(StreamDetector):
    def __init__(self, encoder, exclude: int, min_share: float, n_bits: int = 0):
        self.encoder, self.exclude, self.min_share = encoder, int(exclude), float(min_share)
        self.names, self.meta, self._late = [], {}, []
        self.conf = {"min_share": self.min_share, "exclude": self.exclude}
        self.rows = sp.csr_matrix((0, n_bits), dtype=bool)
        self._starts = [0]

    @property
    def starts(self) -> list[int]:
        return list(self._starts)

    @property
    def waiting(self) -> int:
        return 0

    @property
    def top_k(self) -> int | None:
        return 5

    def warm_up(self) -> None:
        pass

    def _learn(self, rows) -> list[Decision]:
        rows = sp.csr_matrix(rows, dtype=bool)
        if not self.rows.shape[1]:  # the width of the first rows given
            self.rows = sp.csr_matrix((0, rows.shape[1]), dtype=bool)
        out = []
        for r in range(rows.shape[0]):
            j = self.rows.shape[0]
            n = n_candidates(j, self.exclude, self._starts[-1])
            out.append(_answer(self.rows, _bits(rows, r), n, self.min_share, j))
            self.rows = sp.vstack([self.rows, rows[r]]).tocsr()
        return out

    def update_encoded(self, rows, name=None) -> Decision | None:
        self.names.append(str(name) if name is not None else f"frame {len(self.names)}")
        ds = self._learn(rows)
        mine = [d for d in ds if d.frame == len(self.names) - 1]
        self._late.extend(d for d in ds if d.frame != len(self.names) - 1)
        return mine[0] if mine else None

    def take_late(self) -> list[Decision]:
        out, self._late = self._late, []
        return out

    def flush(self, closures: bool = True) -> None:
        if self.encoder is not None:
            self._late.extend(self._learn(self.encoder.flush()))

    def new_session(self) -> None:
        if self.encoder is not None:
            self._late.extend(self._learn(self.encoder.new_session()))
        self._starts.append(len(self.names))

    def save(self, path):
        enc_header, enc_arrays = self.encoder.state() if self.encoder is not None else ({}, {})
        header = {"meta": self.meta, "conf": self.conf, "starts": self._starts, "n_bits": self.rows.shape[1],
                  "enc": enc_header, "opinion": False}
        arrays = {"indptr": self.rows.indptr.astype(np.int64), "indices": self.rows.indices.astype(np.int64)}
        return write_file(path, _FORMAT, _VERSION, header, {"rows": arrays, "enc": enc_arrays}, names=self.names)

    @classmethod
    def load(cls, path, encoder=None) -> ToyDetector:
        with read_file(path, _FORMAT, _VERSION, "toy detector", "", ("rows", "enc")) as (header, parts, names):
            det = cls(encoder, header["conf"]["exclude"], header["conf"]["min_share"], header["n_bits"])
            r = parts["rows"]
            det.rows = sp.csr_matrix((np.ones(r["indices"].size, bool), r["indices"], r["indptr"]),
                                     shape=(len(r["indptr"]) - 1, header["n_bits"]))
            det.names, det.meta, det._starts = list(names or []), header["meta"], header["starts"]
            if encoder is not None:
                encoder.load_state(header.get("enc", {}), parts["enc"])
        return det


class ToyLocalizer(MapLocalizer):
    def __init__(self, db_sdr, names, min_share: float, sessions=None):
        self.db = sp.csr_matrix(db_sdr, dtype=bool)
        self.names, self.min_share = [str(n) for n in names], float(min_share)
        self.conf = {"min_share": self.min_share}
        self.sessions = np.asarray(sorted({0, *(sessions or ())}), np.int64)
        self.frames = 0

    @property
    def top_k(self) -> int | None:
        return 5

    def update(self, sdr_row) -> Decision:
        row = sp.csr_matrix(sdr_row, dtype=bool)
        d = _answer(self.db, _bits(row, 0), self.n_db, self.min_share, self.frames)
        self.frames += 1
        return d

    def reset(self) -> None:
        self.frames = 0

    def warm_up(self) -> None:
        pass

    def reconfigure(self, **conf) -> ToyLocalizer:
        return ToyLocalizer(self.db, self.names, conf.get("min_share", self.min_share), self.sessions)

    def every(self, k: int, phase: int = 0) -> np.ndarray:
        return np.arange(phase, self.n_db, k)

    def relearned(self, db_sdr, keep, progress: bool = False) -> ToyLocalizer:
        return ToyLocalizer(sp.csr_matrix(db_sdr)[keep], [self.names[k] for k in keep], self.min_share)

    def map_state(self):
        header = {"min_share": self.min_share, "shape": list(self.db.shape), "frames": self.frames,
                  "sessions": self.sessions.tolist()}
        return header, {"toydb": {"indptr": self.db.indptr.astype(np.int64),
                                  "indices": self.db.indices.astype(np.int64)}}


class ToyOnline(Method):
    """Single-frame bit sharing, one frame at a time."""

    name = "toy-online"
    default_conf = {"min_share": 0.5}
    required_inputs = ("sdr",)
    runs_online = True

    def _match(self, db: EncodedTraverse, query: EncodedTraverse, progress: bool):
        return overlap_similarity(self.need(db, "sdr", "database"), self.need(query, "sdr", "query")), None

    def loop_detector(self, encoder=None, exclude: int = 1, opinion=None) -> ToyDetector:
        det = ToyDetector(encoder, exclude, self.conf["min_share"])
        det.meta["method"] = self.name
        return det

    @classmethod
    def resume_loop_detector(cls, path, encoder=None, opinion=None) -> ToyDetector:
        return ToyDetector.load(path, encoder)

    @classmethod
    def saved_loop_meta(cls, path) -> dict:
        with read_file(path, _FORMAT, _VERSION, "toy detector", "", ()) as (header, _, _):
            return {**header["meta"], "opinion": False}

    def localizer(self, db_sdr, names, progress: bool = False, sessions=None) -> ToyLocalizer:
        return ToyLocalizer(db_sdr, names, self.conf["min_share"], sessions)

    @classmethod
    def restore_localizer(cls, header: dict, parts: dict, names) -> ToyLocalizer:
        d = parts["toydb"]
        db = sp.csr_matrix((np.ones(d["indices"].size, bool), d["indices"], d["indptr"]), shape=tuple(header["shape"]))
        loc = ToyLocalizer(db, names, header["min_share"], header["sessions"])
        loc.frames = int(header["frames"])
        return loc
