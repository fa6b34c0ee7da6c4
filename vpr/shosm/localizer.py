"""Online localisation against a learned database: one query frame in, one place out."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from vpr import sdr as _sdr
from vpr.statefile import joint_state, part_state
from vpr.types import Column, Decision, MapLocalizer

from .conf import RshosmSeqConf, memory_params
from .decide import UNMOVED_SHARE, PathDecider, map_places, refuse_stands, standing
from .direction import Direction
from .evidence import Engine, make_engine, merge_columns
from .graph import Graph
from .memory import SequenceMemory, pad_codes

__all__ = ["Localizer", "LocalizerStep"]


@dataclass(frozen=True)
class LocalizerStep:
    """What :meth:`Localizer.step` made of one query frame.

    ``decision``: its answer at once; ``bits``: its active bits; ``raw``: its causal raw evidence per speed model
    (:meth:`Engine.step_raw`: rows, values, candidates); ``unmoved``: it kept :data:`UNMOVED_SHARE` of the frame
    before's bits (it did not move); ``refusing``: no answer is accepted now, the query running the map backwards or
    its direction not read yet (:class:`Direction`).
    """

    decision: Decision
    bits: np.ndarray
    raw: tuple
    unmoved: bool
    refusing: bool


class Localizer(MapLocalizer):
    """Causal place recognition of a query stream against a learned database.

    ``memory``: the memory that learned the database (queries do not change it); ``db_codes``: its winner codes
    (``memory.run``), one row per name of ``names``; ``conf``: rSHOSM-seq's conf, ``**flat`` keys over it (the
    evidence, ``exact``, and :meth:`RshosmSeqConf.path`); ``sessions``: each map session's first frame (a path never
    moves on across one).
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
        self.memory, self.names = memory, names
        self.db_codes = sp.csr_matrix(db_codes, dtype=bool)
        self.sessions = np.asarray(sorted({0, *(int(s) for s in (sessions or ()))}), np.int64)
        graph = Graph.of(memory, self.db_codes, backward=True)
        #: whether the engines step the dense column (:meth:`RshosmSeqConf.localize_exact`) or the beam
        self.exact = self.seq.localize_exact(len(names))
        self.engine = make_engine(graph, self.seq.evidence, self.seq.beam, self.exact)
        #: the engine's speed models, one :class:`Engine` each
        self.lanes: list[Engine] = self.engine.lanes
        #: the evidence of the query running the map backwards, against the engine's (:class:`Direction`)
        self.backward = Engine(graph, self.seq.evidence.split()[0], self.seq.beam, self.exact, reverse=True)
        self.direction = Direction()
        self.mirrored = PathDecider(self.seq.path())  # the path rule on the reversed evidence
        self.decider = PathDecider(self.seq.path(), self.sessions)
        #: each map frame's place number (:func:`vpr.shosm.map_places`) and whether it is a frame of a stand, onto
        #: which no answer is accepted (:func:`vpr.shosm.standing`)
        self.places = map_places(self.db_codes, memory.cells_per_column, self.sessions)
        self.standing = standing(self.places)
        self._before: np.ndarray | None = None  # the last query frame's active bits
        #: what :meth:`update` made of the last query frame (None before the first)
        self.last: LocalizerStep | None = None

    @classmethod
    def from_database(cls, db_sdr, names, progress: bool = False, conf: RshosmSeqConf | None = None,
                      sessions=None, **flat) -> Localizer:
        """Learn the database traverse ``db_sdr`` (SDR batch, frames x bits) named ``names``.

        ``sessions``: the first frame of each session of a multi-session map: the memory forgets its context at each
        (no frame is the successor of the last one of another run).
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
    def top_k(self) -> int | None:
        return self.seq.top_k

    @property
    def frames(self) -> int:
        """Query frames seen since the last :meth:`reset`."""
        return self.engine.frames

    def reconfigure(self, **flat) -> Localizer:
        """This map with other query-time settings (evidence, beam, ``top_k``, the decision), continuing its state.

        What the map's memory learned cannot change: its parameters are refused (ValueError naming them) unless they
        are the map's own.
        """
        mine = self.memory.get_params()
        fixed = sorted(k for k in set(flat) & set(memory_params()) if RshosmSeqConf.build({k: flat[k]}).memory[k]
                       != mine[k])
        if fixed:
            raise ValueError(f"{', '.join(fixed)}: fixed by the map (the memory was learned with "
                             f"{', '.join(f'{k}={mine[k]}' for k in fixed)}); learn a new map to change them")
        new = Localizer(self.memory, self.db_codes, self.names, self.seq.replace(**flat), sessions=self.sessions)
        header, arrays = self.state()
        if new.exact != self.exact or new.seq.evidence.speeds != self.seq.evidence.speeds:
            # the evidence of another kind or of other speed models starts afresh
            arrays = {k: v for k, v in arrays.items() if not k.startswith(("engine_", "backward_"))}
            header = {k: v for k, v in header.items() if k != "backward"} | {"engine": None}
        return new.load_state(header, arrays)

    def every(self, k: int, phase: int = 0) -> np.ndarray:
        """The frame numbers of one map frame in ``k`` of each session, from the session's frame ``phase`` on."""
        bounds = [*self.sessions.tolist(), self.n_db]
        return np.concatenate([np.arange(a + phase, b, k) for a, b in zip(bounds[:-1], bounds[1:], strict=True)])

    def relearned(self, db_sdr, keep, progress: bool = False) -> Localizer:
        """A localizer of the same conf learned from the map frames numbered ``keep`` (sorted) alone, their SDRs
        ``db_sdr[keep]`` (each kept frame learned as the successor of the one kept before, within a session)."""
        keep = np.asarray(keep, np.int64)
        sessions = sorted({int(np.searchsorted(keep, s)) for s in self.sessions} - {keep.size})
        return Localizer.from_database(db_sdr[keep], [self.names[k] for k in keep], progress, self.seq,
                                       sessions=sessions)

    def reset(self) -> None:
        """Start a new query traverse: forget the evidence carried from earlier frames and the decision's path."""
        self.engine.reset()
        self.backward.reset()
        self.direction.reset()
        self.mirrored.new_session()
        self.decider.new_session()
        self._before, self.last = None, None

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) the kernels, leaving the state as it was."""
        header, arrays = self.engine.state()
        self.engine.step(np.zeros(0, np.int64))
        self.engine.load_state(header, arrays)

    def update(self, sdr_row) -> Decision:
        """Localise one query frame (SDR row: 1-row batch, bool vector or bit indices); what else it made of the frame
        is :attr:`last` (a :class:`LocalizerStep`)."""
        return self.step(sdr_row).decision

    def step(self, sdr_row) -> LocalizerStep:
        """Localise one query frame: its decision and what else a late answer reads of it (:class:`LocalizerStep`)."""
        bits = _sdr.row_bits(sdr_row, self.memory.n_inputs, name="query SDR")
        frame = self.engine.frames
        raw = tuple(e.step_raw(bits) for e in self.lanes)
        column = merge_columns([e.column(*r, frame) for e, r in zip(self.lanes, raw, strict=True)])
        d = self.decider.decide(column)
        unmoved = self._before is not None and _sdr.kept_share(bits, self._before) >= UNMOVED_SHARE
        self._before = bits
        rev = self.backward.step(bits)
        back = self.direction.update(column.best()[1], rev.best()[1], moved=not unmoved)
        back = back and self.direction.read  # (before, no direction is read: no answer is accepted either)
        refusing = bool(back or not self.direction.read)
        n = rev.n  # the reversed evidence on the map's frames in reverse order: the path rule's confidence in it
        confident = self.mirrored.decide(Column(n - 1 - rev.rows[::-1], rev.z[::-1], rev.fill, n, rev.frame)).accepted
        if refusing or (d.accepted and not refuse_stands(d.best, True, self.standing, unmoved)):
            d = dataclasses.replace(d, accepted=False, reversed=bool(back and confident))
        self.last = LocalizerStep(d, bits, raw, bool(unmoved), refusing)
        return self.last

    # ------------------------------------------------------------ state
    def state(self) -> tuple[dict, dict]:
        """(header, arrays) of the query so far: the evidence and the decision (:meth:`load_state`)."""
        header, arrays = joint_state(engine=self.engine, dec=self.decider, backward=self.backward,
                                     direction=self.direction, mirrored=self.mirrored)
        header["before"] = self._before is not None
        return header, {**arrays, "before": np.zeros(0, np.int64) if self._before is None else self._before}

    def load_state(self, header: dict, arrays: dict) -> Localizer:
        if header.get("engine") is not None:
            self.engine.load_state(*part_state(header, arrays, "engine"))
        self.decider.load_state(*part_state(header, arrays, "dec"))
        for name in ("backward", "direction", "mirrored"):  # (a state saved before they were kept starts them afresh)
            if name in header:
                getattr(self, name).load_state(*part_state(header, arrays, name))
        self._before = np.asarray(arrays["before"], np.int64) if header.get("before") else None
        return self

    def map_state(self) -> tuple[dict, dict[str, dict]]:
        """(header, parts) of the memory, the database's winner codes and the query so far (:meth:`restore`)."""
        mem_header, mem_arrays = self.memory.state()
        q_header, q_arrays = self.state()
        header = {"conf": self.seq.flat(), "memory": mem_header, "query": q_header,
                  "db_shape": list(self.db_codes.shape), "sessions": self.sessions.tolist()}
        codes = {"indptr": self.db_codes.indptr.astype(np.int64), "indices": self.db_codes.indices.astype(np.int64)}
        return header, {"mem": mem_arrays, "query": q_arrays, "codes": codes}

    @classmethod
    def restore(cls, header: dict, parts: dict, names) -> Localizer:
        """The localizer of a :meth:`map_state`, continuing where it was saved (errors raise as they come: the map file
        reader names the file)."""
        mem_h = header["memory"]
        mem = SequenceMemory(**mem_h["params"]).load_state(mem_h, parts.get("mem", {}))
        n_db, width = header["db_shape"]
        idx = parts["codes"]["indices"]
        codes = sp.csr_matrix((np.ones(idx.size, bool), idx, parts["codes"]["indptr"]), shape=(n_db, width))
        loc = cls(mem, codes, names, sessions=header["sessions"], **header["conf"])
        return loc.load_state(header["query"], parts.get("query", {}))

    def __repr__(self) -> str:
        return (f"Localizer(n_db={self.n_db}, frames={self.frames}, drift={self.conf['drift']}, "
                f"min_score={self.conf['min_score']}, memory={self.memory!r})")
