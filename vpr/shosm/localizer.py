"""Online localisation against a learned database: one query frame in, one place out.

**Our extension, not the paper's** (the method is ``rshosm-seq``'s forward
evidence, :class:`vpr.shosm.ForwardEvidence`). A robot learns its map once
(:meth:`Localizer.from_database`: the database traverse is learned with
Algorithm 1 with rSHOSM-seq's learning threshold), then calls :meth:`Localizer.update`
with the SDR of each new camera frame and gets the best database frame, its
name, its score and whether it is accepted. Only the past counts (causal), and
the cost per frame does not depend on how many frames were seen before: the
state is the evidence carried from the last frame. The memory is only read.

Acceptance rule (:class:`vpr.shosm.PathConf`, :class:`vpr.shosm.PathDecider`):
the best database frame's margin over the strongest other place (z-scores of
this query frame's evidence, outside the best frame's island), minus
``drift``, is accumulated while the best database frame moves on
consistently; the answer is accepted when this path score reaches
``min_score``. A margin rather than the z-score itself, because the z-score
of a true match grows and shrinks with the size and frame rate of the map
(chosen in ``docs/localize.md``). Maps saved with the old ``z_min`` rule load
with the new one.

:meth:`Localizer.save` writes one versioned ``.npz`` (atomically): the memory,
the database names and winner codes, the streaming state, the conf and
optional caller metadata (`vpr learn` stores the encoder there), so
a robot can stop and, after :meth:`Localizer.load`, continue with the answers
it would have given without stopping.

Encoding images is not done here (``vpr`` never imports ``encoders``): the
caller encodes each frame with the encoder used for the database.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from vpr import sdr as _sdr

from .conf import RshosmSeqConf, memory_params
from .decide import PathDecider
from .memory import SequenceMemory, pad_codes
from .state import load_state, save_state
from .streaming import ForwardEvidence

__all__ = ["Localizer", "LocalizerResult"]

_FORMAT = "vpr.Localizer"
_FORMAT_VERSION = 1


@dataclass
class LocalizerResult:
    """The answer for one query frame.

    ``best_db`` is the database frame index (-1 with ``db_name`` None when no
    database frame has any evidence); ``score`` the path score of
    :class:`vpr.shosm.PathConf` (the decision's statistic, 0 when the answer
    does not stand out), ``accepted`` whether it reached ``min_score``;
    ``z``: the best frame's z-score (-inf without evidence); ``db_idx`` /
    ``scores``: the ``top_k`` best database frames and their z-scores.
    """

    best_db: int
    db_name: str | None
    score: float
    accepted: bool
    db_idx: np.ndarray
    scores: np.ndarray
    z: float = float("-inf")


class Localizer:
    """Causal place recognition of a query stream against a learned database.

    Parameters
    ----------
    memory : SequenceMemory
        The memory that learned the database (not changed by queries).
    db_codes : csr matrix (n_db x cells)
        The database's winner codes from ``memory.run``.
    names : sequence of str
        Database frame names (one per row of ``db_codes``).
    conf : RshosmSeqConf, optional
        rSHOSM-seq's conf (the ``rshosm-seq`` method's, ``method.seq``): the
        forward evidence (:class:`vpr.shosm.ForwardEvidence`: the evidence,
        ``top_k``, ``exact``, the beam) and the decision
        (:meth:`RshosmSeqConf.path`); ``**flat`` keys over it. Its memory
        parameters are ``memory``'s.

    Attributes
    ----------
    frames : int
        Query frames seen since the last :meth:`reset`.
    meta : dict
        Caller metadata stored with :meth:`save` and returned by :meth:`load`.
    arrays : dict
        Caller arrays stored with :meth:`save` (e.g. an encoder's fitted statistics).
    """

    def __init__(self, memory: SequenceMemory, db_codes, names, conf: RshosmSeqConf | None = None, sessions=None,
                 **flat):
        self.seq = RshosmSeqConf.of(conf, flat, memory.get_params())
        names = [str(n) for n in names]
        if not sp.issparse(db_codes) or db_codes.shape[0] != len(names):
            raise ValueError(f"db_codes must be a sparse matrix with one row per database name "
                             f"({len(names)} names, got {getattr(db_codes, 'shape', None)})")
        if not names:
            raise ValueError("the database is empty: a Localizer needs at least one database frame")
        #: the whole conf with the decision's defaults filled in (recorded in metrics.json)
        self.conf = self.seq.resolved("map")
        self.memory = memory
        self.names = names
        self.db_codes = sp.csr_matrix(db_codes, dtype=bool)
        seq = self.seq
        self._fwd = ForwardEvidence(memory, self.db_codes, seq.evidence, top_k=seq.top_k, exact=seq.exact,
                                    beam=seq.beam)
        self._initial = self._fwd.state_dict()
        #: the first map frame of each session of the map (a robot's runs learned one after the other)
        self.sessions = np.asarray(sorted({0, *(int(s) for s in (sessions or ()))}), np.int64)
        self._decider = PathDecider(seq.path(), self.sessions)
        self.meta: dict = {}
        self.arrays: dict = {}

    @classmethod
    def from_database(cls, db_sdr, names, progress: bool = False, conf: RshosmSeqConf | None = None,
                      sessions=None, **flat) -> Localizer:
        """Learn the database traverse ``db_sdr`` (SDR batch, frames x bits) named ``names``.

        ``conf`` (and ``**flat`` keys over it): rSHOSM-seq's conf, memory parameters included.
        ``sessions``: the first frame of each session of a multi-session map: the
        memory forgets its context at each (no frame is the successor of the last
        one of another run), and a localisation path never moves on across one.
        """
        seq = RshosmSeqConf.of(conf, **flat)
        params = seq.memory_params
        x = _sdr.check_batch(db_sdr, n_bits=params["n_inputs"], name="database SDR batch")
        names = list(names)
        if x.shape[0] != len(names):
            raise ValueError(f"{x.shape[0]} database SDR rows but {len(names)} names")
        mem = SequenceMemory(**params)
        bounds = sorted({0, *(int(s) for s in (sessions or ()))} | {x.shape[0]})
        parts = []
        for a, b in zip(bounds[:-1], bounds[1:], strict=True):
            mem.reset()
            parts.append(mem.run(x[a:b], progress=progress))
        mem.reset()
        codes = sp.vstack(pad_codes(*parts)).tocsr() if len(parts) > 1 else parts[0]
        return cls(mem, codes, names, seq, sessions=bounds[:-1])

    @property
    def n_db(self) -> int:
        return len(self.names)

    @property
    def frames(self) -> int:
        return self._fwd.frames

    def reconfigure(self, **flat) -> Localizer:
        """This map with other query-time settings (evidence, beam, ``top_k``, the decision), continuing its state.

        What the map's memory learned cannot change: its parameters are refused
        (ValueError naming them) unless they are the map's own, as are unknown
        keys and bad values.
        """
        mine = self.memory.get_params()
        fixed = sorted(k for k in set(flat) & set(memory_params()) if RshosmSeqConf.build({k: flat[k]}).memory[k]
                       != mine[k])
        if fixed:
            raise ValueError(f"{', '.join(fixed)}: fixed by the map (the memory was learned with "
                             f"{', '.join(f'{k}={mine[k]}' for k in fixed)}); learn a new map to change them")
        new = Localizer(self.memory, self.db_codes, self.names, self.seq.replace(**flat), sessions=self.sessions)
        if new.seq.exact == self.seq.exact:
            new._fwd.load_state(self._fwd.state_dict())
        new._decider.load_state(self._decider.state_dict())
        new.meta, new.arrays = self.meta, self.arrays
        return new

    @property
    def forward(self) -> ForwardEvidence:
        """The causal evidence (read its columns; stepping it apart from :meth:`update` skips the decisions)."""
        return self._fwd

    def reset(self) -> None:
        """Start a new query traverse: forget the evidence carried from earlier frames and the decision's path."""
        self._fwd.load_state(self._initial)
        self._decider.reset()

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) the kernels, leaving the state as it was.

        Otherwise the first :meth:`update` after start pays for it (hundreds of ms).
        """
        state = self._fwd.state_dict()
        self._fwd.update(np.zeros(0, np.int64))
        self._fwd.load_state(state)

    def update(self, sdr_row) -> LocalizerResult:
        """Localise one query frame (SDR row: 1-row batch, bool vector or bit indices)."""
        o = self._fwd.update(sdr_row)
        best, score, ok, _ = self._decider.decide(o.rows, o.vals, self.n_db, o.fill)
        if o.best_db < 0:  # no evidence anywhere (the dense column's argmax is not an answer)
            best, score, ok = -1, 0.0, False
        return LocalizerResult(int(best), self.names[best] if best >= 0 else None, float(score), bool(ok), o.db_idx,
                               o.scores, float(o.score))

    # ------------------------------------------------------------ files
    def save(self, path) -> Path:
        """Write memory, database names and codes, streaming state, conf, ``meta`` and ``arrays`` (atomic ``.npz``)."""
        mem_header, mem_arrays = self.memory.to_arrays()
        header = {"conf": self.seq.flat(), "memory_params": mem_header["params"], "memory_rng": mem_header["rng"],
                  "meta": self.meta, "db_shape": list(self.db_codes.shape), "sessions": self.sessions.tolist()}
        parts = {"mem": mem_arrays, "state": self._fwd.state_dict(), "decide": self._decider.state_dict(),
                 "user": self.arrays,
                 "db": {"indptr": self.db_codes.indptr.astype(np.int64),
                        "indices": self.db_codes.indices.astype(np.int64)}}
        return save_state(path, _FORMAT, _FORMAT_VERSION, header, parts, names=self.names)

    @classmethod
    def load(cls, path) -> Localizer:
        """Read a file written by :meth:`save`; the localizer continues where it was saved.

        Raises
        ------
        MemoryFileError
            Missing, corrupt or foreign file, or an unsupported format version.
        """
        with load_state(path, _FORMAT, _FORMAT_VERSION, "localizer", " (written by `vpr learn` / Localizer.save)",
                        ("mem", "state", "decide", "user", "db")) as (header, parts, names):
            mem = SequenceMemory.from_arrays({"params": header["memory_params"], "rng": header["memory_rng"]},
                                             parts["mem"])
            n_db, width = header["db_shape"]
            idx = parts["db"]["indices"]
            codes = sp.csr_matrix((np.ones(idx.size, bool), idx, parts["db"]["indptr"]), shape=(n_db, width))
            # maps written before the path rule hold its predecessor's z_min: they load with the path rule
            conf = {k: v for k, v in header["conf"].items() if k != "z_min"}
            loc = cls(mem, codes, names, sessions=header.get("sessions"), **conf)
            loc._fwd.load_state(parts["state"])
            loc._decider.load_state(parts["decide"])
            loc.meta = header.get("meta", {})
            loc.arrays = parts["user"]
        return loc

    def __repr__(self) -> str:
        return (f"Localizer(n_db={self.n_db}, frames={self.frames}, drift={self.conf['drift']}, "
                f"min_score={self.conf['min_score']}, memory={self.memory!r})")
