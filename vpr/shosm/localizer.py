"""Online localisation against a learned database: one query frame in, one place out.

**Our extension, not the paper's** (the method is ``rshosm-seq``'s forward
evidence, :class:`vpr.shosm.ForwardEvidence`). A robot learns its map once
(:meth:`Localizer.from_database`: the database traverse is learned with
Algorithm 1 with rSHOSM-seq's learning threshold), then calls :meth:`Localizer.update`
with the SDR of each new camera frame and gets the best database frame, its
name, its score and whether it is accepted. Only the past counts (causal), and
the cost per frame does not depend on how many frames were seen before: the
state is the evidence carried from the last frame. The memory is only read.

Acceptance rule: the score is the z-score of the best database frame's
evidence against all database frames' evidence for this query frame (what
``normalise="query"`` computes); the answer is accepted when it is at least
``z_min`` (chosen in ``docs/localize.md``).

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

from vpr import io as _io
from vpr import sdr as _sdr
from vpr.config import merge_conf

from .conf import BeamConf, EvidenceConf, memory_params
from .memory import MemoryFileError, SequenceMemory
from .streaming import ForwardEvidence

__all__ = ["Localizer", "LocalizerResult", "LOCALIZER_DEFAULTS"]

_FORMAT = "vpr.Localizer"
_FORMAT_VERSION = 1

#: Conf of :class:`Localizer`: the memory's parameters (rSHOSM-seq's), the forward evidence's
#: (:class:`vpr.shosm.ForwardEvidence`: :class:`vpr.shosm.EvidenceConf`, ``top_k``, ``exact``,
#: :class:`vpr.shosm.BeamConf`) and the acceptance threshold ``z_min``.
LOCALIZER_DEFAULTS = {**memory_params(), **EvidenceConf().as_dict(), "top_k": 50, "exact": False, "z_min": 4.0,
                      **BeamConf().as_dict()}
_NULLABLE = frozenset({"seed", "stay", "skip", "top_k", "max_beam", "max_enter"})


@dataclass
class LocalizerResult:
    """The answer for one query frame.

    ``best_db`` is the database frame index (-1 with ``db_name`` None and score
    ``-inf`` when no database frame has any evidence), ``score`` its z-score,
    ``accepted`` whether ``score >= z_min``; ``db_idx`` / ``scores``: the
    ``top_k`` best database frames and their z-scores.
    """

    best_db: int
    db_name: str | None
    score: float
    accepted: bool
    db_idx: np.ndarray
    scores: np.ndarray


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
    **conf
        Overrides of :data:`LOCALIZER_DEFAULTS` (memory keys are ignored here:
        they describe ``memory``); unknown keys raise ValueError.

    Attributes
    ----------
    frames : int
        Query frames seen since the last :meth:`reset`.
    meta : dict
        Caller metadata stored with :meth:`save` and returned by :meth:`load`.
    arrays : dict
        Caller arrays stored with :meth:`save` (e.g. an encoder's fitted statistics).
    """

    def __init__(self, memory: SequenceMemory, db_codes, names, **conf):
        self.conf = merge_conf(LOCALIZER_DEFAULTS, {**memory.get_params(), **conf}, "Localizer", nullable=_NULLABLE)
        names = [str(n) for n in names]
        if not sp.issparse(db_codes) or db_codes.shape[0] != len(names):
            raise ValueError(f"db_codes must be a sparse matrix with one row per database name "
                             f"({len(names)} names, got {getattr(db_codes, 'shape', None)})")
        if not names:
            raise ValueError("the database is empty: a Localizer needs at least one database frame")
        self.memory = memory
        self.names = names
        self.db_codes = sp.csr_matrix(db_codes, dtype=bool)
        self._fwd = ForwardEvidence(memory, self.db_codes, EvidenceConf.from_conf(self.conf), top_k=self.conf["top_k"],
                                    exact=self.conf["exact"], beam=BeamConf.from_conf(self.conf))
        self._initial = self._fwd.state_dict()
        self.meta: dict = {}
        self.arrays: dict = {}

    @classmethod
    def from_database(cls, db_sdr, names, progress: bool = False, **conf) -> Localizer:
        """Learn the database traverse ``db_sdr`` (SDR batch, frames x bits) named ``names``.

        ``conf``: :data:`LOCALIZER_DEFAULTS` overrides (memory parameters included).
        """
        c = merge_conf(LOCALIZER_DEFAULTS, conf, "Localizer", nullable=_NULLABLE)
        params = memory_params(c)
        x = _sdr.check_batch(db_sdr, n_bits=params["n_inputs"], name="database SDR batch")
        names = list(names)
        if x.shape[0] != len(names):
            raise ValueError(f"{x.shape[0]} database SDR rows but {len(names)} names")
        mem = SequenceMemory(**params)
        codes = mem.run(x, progress=progress)
        mem.reset()
        return cls(mem, codes, names, **c)

    @property
    def n_db(self) -> int:
        return len(self.names)

    @property
    def frames(self) -> int:
        return self._fwd.frames

    def reset(self) -> None:
        """Start a new query traverse: forget the evidence carried from earlier frames."""
        self._fwd.load_state(self._initial)

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
        ok = o.best_db >= 0 and np.isfinite(o.score) and o.score >= self.conf["z_min"]
        return LocalizerResult(o.best_db, self.names[o.best_db] if o.best_db >= 0 else None, float(o.score),
                               bool(ok), o.db_idx, o.scores)

    # ------------------------------------------------------------ files
    def save(self, path) -> Path:
        """Write memory, database names and codes, streaming state, conf, ``meta`` and ``arrays`` (atomic ``.npz``)."""
        path = Path(path)
        mem_header, mem_arrays = self.memory.to_arrays()
        header = {"format": _FORMAT, "version": _FORMAT_VERSION, "conf": self.conf,
                  "memory_params": mem_header["params"], "memory_rng": mem_header["rng"],
                  "meta": self.meta, "db_shape": list(self.db_codes.shape)}
        arrays = {f"mem_{k}": v for k, v in mem_arrays.items()}
        arrays.update({f"state_{k}": np.asarray(v) for k, v in self._fwd.state_dict().items()})
        arrays.update({f"user_{k}": np.asarray(v) for k, v in self.arrays.items()})
        arrays["names"] = np.array(self.names, dtype=str)
        arrays["db_indptr"] = self.db_codes.indptr.astype(np.int64)
        arrays["db_indices"] = self.db_codes.indices.astype(np.int64)
        return _io.save_versioned_npz(path, header, arrays, default=_json_default)

    @classmethod
    def load(cls, path) -> Localizer:
        """Read a file written by :meth:`save`; the localizer continues where it was saved.

        Raises
        ------
        MemoryFileError
            Missing, corrupt or foreign file, or an unsupported format version.
        """
        header, data = _io.load_versioned_npz(path, _FORMAT, _FORMAT_VERSION, "localizer", MemoryFileError,
                                              hint=" (written by `vpr learn` / Localizer.save)")
        try:
            mem = SequenceMemory.from_arrays({"params": header["memory_params"], "rng": header["memory_rng"]},
                                             {k[4:]: v for k, v in data.items() if k.startswith("mem_")})
            n_db, width = header["db_shape"]
            idx = data["db_indices"]
            codes = sp.csr_matrix((np.ones(idx.size, bool), idx, data["db_indptr"]), shape=(n_db, width))
            loc = cls(mem, codes, data["names"].tolist(), **header["conf"])
            loc._fwd.load_state({k[6:]: v for k, v in data.items() if k.startswith("state_")})
        except MemoryFileError:
            raise
        except Exception as e:
            raise MemoryFileError(f"{path}: corrupt localizer file ({type(e).__name__}: {e})") from e
        loc.meta = header.get("meta", {})
        loc.arrays = {k[5:]: v for k, v in data.items() if k.startswith("user_")}
        return loc

    def __repr__(self) -> str:
        return f"Localizer(n_db={self.n_db}, frames={self.frames}, z_min={self.conf['z_min']}, memory={self.memory!r})"


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
