"""Loop closure within one stream: learned online with Algorithm 1, scored by the forward evidence, decided."""
from __future__ import annotations

import dataclasses
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.sparse as sp
from tqdm import tqdm

from vpr import sdr as _sdr
from vpr.checks import check_exclude, check_top_k
from vpr.similarity import fits_dense, n_candidates
from vpr.statefile import joint_state, part_state
from vpr.types import Decider, Decision

from .backfill import Backfill
from .conf import LOOP_EXCLUDE, RshosmSeqConf
from .confirm import Confirmation
from .decide import loop_rule
from .evidence import LoopEvidence
from .memory import SequenceMemory
from .stream_graph import StreamEngine, StreamGraph, make_stream_engine

__all__ = ["LoopStream", "loop_evidence"]

class LoopStream:
    """One stream's loop closure: the memory learned so far, the evidence engine over it, the decisions.

    ``exclude``: frames closer are not candidates; ``conf``: the whole :class:`RshosmSeqConf`; ``caps``: whether the
    beam's caps apply (default: no; the evidence over the stream laid out by frame carries every cell, and a cap
    would drop the revisits across a change of conditions, ``research/docs/loops.md``); ``opinion(decider)``: a
    decider around the loop rule's (:class:`vpr.verify.GeometricOpinion`).
    """

    def __init__(self, exclude: int = LOOP_EXCLUDE, conf: RshosmSeqConf | None = None, caps: bool = False,
                 opinion=None):
        exclude = check_exclude(exclude)
        if not isinstance(caps, bool):
            raise ValueError(f"caps must be True or False, got {caps!r}")
        self.exclude, self.caps = int(exclude), caps
        self.seq = conf if conf is not None else RshosmSeqConf.build()
        self.mem = SequenceMemory(**self.seq.memory_params)
        self.graph = StreamGraph(self.mem)
        self.engine = make_stream_engine(self.graph, self.seq.evidence, self.seq.beam)
        self._shares_overlaps = isinstance(self.engine, StreamEngine) and not caps
        self._worker: ThreadPoolExecutor | None = None
        self.decider: Decider = loop_rule(self.seq.loop_rule)(self.seq.loop(), self.seq.path(between_sessions=True),
                                                              n_bits=self.mem.n_inputs)
        if opinion is not None:
            self.decider = opinion(self.decider)
        loop = self.seq.loop()
        stay, skip = self.seq.evidence.costs
        self.confirmation = Confirmation(loop.confirm_frames, loop.confirm_z, self.exclude, stay, skip,
                                         self.mem.n_inputs)
        self.backfill = Backfill(loop.backfill_frames, loop.back, loop.ahead, self.decider.accept_score)
        self._rows = _sdr.RowLog()  # the stream's SDR rows, where the decider keeps none
        self.starts = [0]  # the first frame of every session
        self.frames = 0

    @property
    def n_inputs(self) -> int:
        return self.mem.n_inputs

    def _pool(self) -> ThreadPoolExecutor:
        """The thread that computes a frame's confirmation overlaps beside the frame's learning and evidence."""
        if self._worker is None:
            self._worker = ThreadPoolExecutor(1, thread_name_prefix="vpr-confirm")
        return self._worker

    @property
    def rows(self) -> _sdr.RowLog:
        """The stream's SDR rows so far."""
        rows = self.decider.rows
        return self._rows if rows is None else rows

    def new_session(self) -> list[Decision]:
        """The next frame starts a new run of the robot (a session); returns the decisions of the last session's
        closures that waited (confirmed with the frames it had).

        What was learned stays, and later frames close loops onto every earlier session; nothing of the last session's
        last moment carries over: the memory's context (the first frame of this run is nobody's successor), the
        evidence and the decision's path. ``exclude`` holds within a session only.
        """
        if self.frames == self.starts[-1]:
            return []
        self.mem.reset()
        self.engine.reset()
        self.decider.new_session()
        self.starts.append(self.frames)
        return self._final(self.confirmation.end_session(self.rows, self.frames), end=True)

    def finish(self) -> list[Decision]:
        """The stream ends: the decisions of the frames still waiting, confirmed with the frames they have."""
        return self._final(self.confirmation.settle(self.rows, self.frames), end=True)

    def _final(self, ds: list[Decision], end: bool = False) -> list[Decision]:
        """Decisions leaving the confirmation, the frames leading up to a confirmed closure accepted with it
        (:class:`Backfill`; ``end``: the session ends, nothing waits on)."""
        return self.backfill.push(ds) + (self.backfill.flush() if end else [])

    @property
    def waiting(self) -> int:
        """Frames decided by the rule whose decisions are not final yet."""
        return len(self.confirmation.queue) + len(self.backfill.held)

    def step(self, sdr_row) -> tuple[np.ndarray, list[Decision]]:
        """Learn the next frame (SDR row: 1-row batch, dense row or bit indices), score and decide it.

        Returns its winner cells and the decisions final now (each with its column over the candidates), in frame
        order: this frame's, unless it or an earlier one waits for the frames after it (:class:`Confirmation`) or on
        a path that a later closure may accept with it (:class:`Backfill`).
        """
        bits = _sdr.row_bits(sdr_row, self.mem.n_inputs, name="frame SDR")
        j = self.frames
        self.decider.add_sdr(bits)
        if self.decider.rows is None:
            self._rows.append(bits)
        # the frame's overlaps with the earlier frames, which a closure waiting for it reads, on the other core while
        # the memory learns the frame and its evidence is scored (they share nothing)
        early = self._pool().submit(self.confirmation.prepare, self.rows, j) if self.confirmation.needs_rows else None
        try:
            old_len, ne_old = self.mem.view(sizes=False).bit_len.copy(), self.mem.n_connections
            shared = self._shares_overlaps  # the memory's overlap count of the frame, not counted again
            winners = self.mem.step(bits, keep_overlaps=shared)
            self.graph.attach(bits, winners, old_len, ne_old)
            self.engine.grow()
            n = n_candidates(j, self.exclude, self.starts[-1])
            column = self.engine.step(bits, n, self.caps, frame=j, overlaps=self.mem.overlaps()) if shared else \
                self.engine.step(bits, n, self.caps, frame=j)
        finally:
            if early is not None:
                early.result()
        self.frames += 1
        d = self.decider.decide(column)
        return winners, self._final(self.confirmation.push(d, self.rows, self.decider.pair_verified))

    # ------------------------------------------------------------- state
    def state(self) -> tuple[dict, dict]:
        """(header, arrays): the memory, the graph, the evidence and the decisions so far (:meth:`load_state`)."""
        header, arrays = joint_state(mem=self.mem, graph=self.graph, engine=self.engine, dec=self.decider,
                                     confirm=self.confirmation, backfill=self.backfill)
        if self.decider.rows is None:
            arrays.update(sdr_ptr=self._rows.ptr.copy(), sdr_ind=self._rows.ind.copy())
        header.update(exclude=self.exclude, seq=self.seq.flat(), caps=self.caps, frames=self.frames,
                      starts=list(self.starts))
        return header, arrays

    def load_state(self, header: dict, arrays: dict) -> LoopStream:
        """Continue from a :meth:`state` (raises ValueError on inconsistent arrays)."""
        self.mem.load_state(*part_state(header, arrays, "mem"))
        self.graph.load_state(*part_state(header, arrays, "graph"))
        self.engine = make_stream_engine(self.graph, self.seq.evidence, self.seq.beam).load_state(
            *part_state(header, arrays, "engine"))
        self.decider.load_state(*part_state(header, arrays, "dec"))
        self.confirmation.load_state(*part_state(header, arrays, "confirm"))
        self.backfill.load_state(*part_state(header, arrays, "backfill"))
        if "sdr_ptr" in arrays:
            self._rows = _sdr.RowLog(arrays["sdr_ptr"], arrays["sdr_ind"])
        self.frames, self.starts = int(header["frames"]), [int(v) for v in header["starts"]]
        if self.decider.frames != self.frames or self.rows.rows != self.frames:
            raise ValueError(f"loop stream state: {self.decider.frames} decisions and {self.rows.rows} SDR rows for "
                             f"{self.frames} frames")
        return self

    @classmethod
    def from_state(cls, header: dict, arrays: dict) -> LoopStream:
        """The stream of a :meth:`state` pair."""
        caps = header["caps"]
        if not isinstance(caps, bool):
            raise ValueError("a loop stream's state of an earlier version (its beam capped from a frame on)")
        return cls(header["exclude"], RshosmSeqConf.build(header["seq"]), caps).load_state(header, arrays)


def loop_evidence(sdr_batch, exclude: int = LOOP_EXCLUDE, conf=None, top_k: int | None = None,
                  caps: bool = False, dense_max: int | None = None, progress: bool = False, sessions=None,
                  opinion=None, **flat) -> LoopEvidence:
    """Loop closure within one stream with graded forward sequence evidence, learned online.

    Frame ``j`` is learned with Algorithm 1 (one memory over the stream), scored against the frames ``i <= j -
    exclude`` with the causal evidence of the cells learned by then, and decided (:class:`LoopConf`).

    Parameters
    ----------
    sdr_batch : SDR batch (T x n_inputs), the stream.
    exclude : int >= 1
        Frames closer than this are not candidates.
    conf : RshosmSeqConf, one of its parts, or a mapping of its flat keys
        ``**flat`` keys over it (:meth:`RshosmSeqConf.of`; ``stop_ratio=0`` leaves out the decision's stop check);
        ``caps`` as :class:`LoopStream`.
    top_k : int or None
        Earlier frames kept per frame (None: dense where it fits, :func:`vpr.similarity.fits_dense`, or up to
        ``dense_max`` frames; the conf's ``top_k`` beyond). The decisions do not depend on it.
    sessions : sequence of int, optional
        The first frame of each session.
    opinion : callable, optional
        A second opinion around the loop rule (:class:`LoopStream`).
    progress : bool

    Returns
    -------
    LoopEvidence (unpacks as ``S, codes``), with each frame's decision.
    """
    top_k = check_top_k(top_k)
    seq = RshosmSeqConf.of(conf, **flat)
    stream = LoopStream(exclude, seq, caps, opinion)
    x = _sdr.check_batch(sdr_batch, n_bits=stream.n_inputs, name="stream SDR batch")
    T = x.shape[0]
    starts = sorted({int(s) for s in (sessions or ())} - {0})
    if starts and (starts[0] < 0 or starts[-1] >= T):
        raise ValueError(f"sessions must start at frames 0 .. {T - 1}, got {sorted(sessions)}")
    if top_k is None and not (fits_dense(T, T) if dense_max is None else T <= int(dense_max)):
        if seq.top_k is None:
            raise ValueError(f"top_k none keeps every earlier frame, a dense {T} x {T} matrix: above the memory "
                             "budget (--memory-budget); give top_k")
        top_k = seq.top_k
    dense = np.full((T, T), -np.inf, np.float32) if top_k is None else None
    cols_i, cols_v, counts = [], [], np.zeros(T, np.int64)
    codes_ptr, codes_idx = np.zeros(T + 1, np.int64), []
    decisions, fill, best, z = [], np.zeros(T, np.float32), np.full(T, -1, np.int64), np.full(T, -np.inf)
    begin = set(starts)

    def take(ds) -> None:
        for d in ds:
            j, c = d.frame, d.column
            decisions.append(dataclasses.replace(d, column=None))  # its column is kept below, dense or top-K
            fill[j] = c.fill
            best[j], z[j] = c.best()
            if dense is not None:
                dense[: c.n, j] = c.fill
                dense[c.rows, j] = c.z
            else:
                rows, vals = c.top(int(top_k))
                cols_i.append(rows)
                cols_v.append(vals)
                counts[j] = rows.size

    for j in tqdm(range(T), desc="rSHOSM loops", unit="frame", leave=False, disable=not progress):
        if j in begin:
            take(stream.new_session())
        winners, ds = stream.step(x.indices[x.indptr[j]:x.indptr[j + 1]])
        codes_idx.append(winners)
        codes_ptr[j + 1] = codes_ptr[j] + winners.size
        take(ds)
    take(stream.finish())
    codes = sp.csr_matrix((np.ones(int(codes_ptr[-1]), bool), np.concatenate(codes_idx + [np.zeros(0, np.int64)]),
                           codes_ptr), shape=(T, max(stream.mem.n_cells, 1)))
    decision = Decision.stack(decisions)
    if dense is not None:
        S = dense
    else:
        S = sp.csc_matrix((np.concatenate(cols_v + [np.zeros(0, np.float32)]),
                           np.concatenate(cols_i + [np.zeros(0, np.int64)]), np.r_[0, np.cumsum(counts)]),
                          shape=(T, T)).tocsr()
        S.sort_indices()
    return LoopEvidence(S, best, z, fill, stream.exclude, codes, tuple(stream.starts), decision)
