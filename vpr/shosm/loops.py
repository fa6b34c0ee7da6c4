"""Loop closure within one stream: learned online with Algorithm 1, scored with forward graded evidence.

**Our extension, not the paper's** scoring (the paper compares winner codes;
``rshosm`` does that). :class:`LoopStream` is the engine: frame by frame it
learns the frame, scores every frame far enough back with the causal evidence
of rSHOSM-seq, and decides (:class:`vpr.shosm.decide.LoopDecider`) whether the
best of them is a loop closure or the frame is a new place.
:func:`loop_evidence` runs it over a whole stream and assembles the T x T
matrix; :class:`vpr.shosm.LoopDetector` runs it one frame at a time for a robot.
Both give the same answers, because they are the same engine.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from tqdm import tqdm

from vpr import sdr as _sdr
from vpr.checks import check_exclude, check_top_k
from vpr.similarity import n_candidates

from .beam import BIG, Beam, beam_params
from .conf import LOOP_EXCLUDE, RshosmSeqConf
from .decide import LoopDecider, LoopDecisions
from .kernels import beam as KB
from .memory import SequenceMemory

__all__ = ["LoopStream", "FrameLoop", "loop_evidence", "LoopEvidence", "LOOP_UNCAPPED_MAX", "LOOP_DENSE_MAX"]

#: The beam carries every cell until the stream has this many frames; from then on the caps of
#: :class:`vpr.shosm.BeamConf` bound the cost per frame (``caps="auto"``). Uncapped, a long stream's time and
#: memory grow too fast; capped from the start, the frames of the current condition fill the beam and the
#: other condition's frames of the same place never enter it (``docs/loops.md``).
LOOP_UNCAPPED_MAX = 10_000

#: Streams up to this many frames get a dense T x T loop matrix; beyond, top-K sparse (the conf's ``top_k``).
LOOP_DENSE_MAX = 20_000


@dataclass
class FrameLoop:
    """One frame of a :class:`LoopStream`: its winner cells, its evidence column and its decision.

    ``rows`` / ``z``: the earlier frames with evidence and their z-scores (or
    raw evidence with ``normalise="none"``), sorted by frame; ``fill``: the
    score of an earlier frame without evidence; ``n_candidates``: frames far
    enough back. ``best`` (-1: none), ``score`` (the path score of
    :class:`vpr.shosm.LoopConf`), ``accepted``, ``margin``, ``near``: the
    decision (:func:`vpr.shosm.accept_loops`).
    """

    winners: np.ndarray
    rows: np.ndarray
    z: np.ndarray
    fill: float
    n_candidates: int
    best: int
    score: float
    accepted: bool
    margin: float
    near: bool


def _grown(a, size, fill):
    out = np.full(size, fill, a.dtype)
    out[: a.size] = a
    return out


class LoopStream:
    """The state of one stream's loop closure: the memory learned so far, the beam, the decisions.

    Parameters
    ----------
    exclude : int >= 1
        Frames closer than this are not candidates.
    conf : RshosmSeqConf
        The memory, the evidence, the beam's floors and caps and the decision
        (:meth:`RshosmSeqConf.loop`); default: the defaults.
    caps : "auto" or bool
        Whether the caps apply: ``"auto"`` from frame :data:`LOOP_UNCAPPED_MAX` on.
    """

    def __init__(self, exclude: int = LOOP_EXCLUDE, conf: RshosmSeqConf | None = None, caps: str | bool = "auto"):
        exclude = check_exclude(exclude)
        if not (caps == "auto" or isinstance(caps, bool)):
            raise ValueError(f"caps must be 'auto', True or False, got {caps!r}")
        self.exclude = int(exclude)
        self.seq = conf if conf is not None else RshosmSeqConf.build()
        self.conf, self.beam_conf, self.loop = self.seq.evidence, self.seq.beam, self.seq.loop()
        self.caps = caps
        self.mem = SequenceMemory(**self.seq.memory_params)
        self.starts = [0]  # the first frame of every session
        self.decider = LoopDecider(self.loop)
        self.frames = 0
        self._params = {c: beam_params(self.conf, self.beam_conf if c else self.beam_conf.uncapped(), 0.0)
                        for c in (False, True)}
        cpc = self.mem.cells_per_column
        cap = 1024 * cpc
        self._g = {"cpc": cpc, "n_cells": cap, "col_size": np.zeros(cap // cpc), "relevant": np.zeros(cap, bool),
                   "birth": np.full(cap, BIG, np.int64), "c_head": np.full(cap, -1, np.int64),
                   "c_next": np.zeros(4096, np.int64), "c_frame": np.zeros(4096, np.int64),
                   "db_norm": np.ones(1024, np.float64)}
        self._a = (np.full(cap, -1, np.int64), np.zeros(4096, np.int64), np.zeros(4096, np.int64))
        self._n_nodes = 0
        self._beam = Beam(cap, cap // cpc, 1024)

    @property
    def n_inputs(self) -> int:
        return self.mem.n_inputs

    def new_session(self) -> None:
        """The next frame starts a new run of the robot (a session).

        What was learned stays, and later frames close loops onto every
        earlier session; nothing of the last session's last moment carries
        over: the memory's context (Algorithm 1's previous winner cells, so the
        first frame of this run is nobody's successor), the evidence in the
        beam and the decision's path. ``exclude`` holds within a session only.
        """
        if self.frames == self.starts[-1]:
            return  # nothing since the last start: already a new session
        self.mem.reset()
        self._beam.set_beam(np.zeros(0, np.int64), np.zeros(0, np.float64))
        self.decider.new_session()
        self.starts.append(self.frames)

    def _capped(self, j: int) -> bool:
        return j >= LOOP_UNCAPPED_MAX if self.caps == "auto" else bool(self.caps)

    def _attach(self, j: int, bits: np.ndarray, winners: np.ndarray, old_len: np.ndarray, ne_old: int) -> None:
        """Make frame ``j`` (learned, with winner cells ``winners``) a candidate of the evidence."""
        g, cpc = self._g, self._g["cpc"]
        v = self.mem.view()
        a_head, a_next, a_dst = self._a
        if v.n_cells > g["n_cells"]:  # grow everything indexed by cell or minicolumn
            new = max(v.n_cells, 2 * g["n_cells"])
            for name, fill in (("relevant", False), ("birth", BIG), ("c_head", -1), ("col_size", 0.0)):
                g[name] = _grown(g[name], new if name != "col_size" else new // cpc, fill)
            a_head = _grown(a_head, new, -1)
            g["n_cells"] = new
        if j >= g["db_norm"].size:
            g["db_norm"] = _grown(g["db_norm"], 2 * (j + 1), 1.0)
        self._beam.grow(g["n_cells"], g["n_cells"] // cpc, g["db_norm"].size)
        KB.count_new_entries(g["col_size"], bits, old_len, v.bit_len, v.bit_cols)
        ne = v.e_src.size
        if ne > a_next.size:
            a_next, a_dst = np.resize(a_next, max(ne, 2 * a_next.size)), np.resize(a_dst, max(ne, 2 * a_dst.size))
        KB.append_lists(a_head, a_next, a_dst, ne_old, v.e_src[ne_old:], v.e_dst[ne_old:])
        self._a = (a_head, a_next, a_dst)
        n = self._n_nodes
        if n + winners.size > g["c_next"].size:
            g["c_next"] = np.resize(g["c_next"], 2 * (n + winners.size))
            g["c_frame"] = np.resize(g["c_frame"], 2 * (n + winners.size))
        KB.append_lists(g["c_head"], g["c_next"], g["c_frame"], n, winners, np.full(winners.size, j, np.int64))
        self._n_nodes = n + winners.size
        g["relevant"][winners] = True
        g["birth"][winners] = np.minimum(g["birth"][winners], j)
        g["db_norm"][j] = max(winners.size, 1)
        g["bit_cols"], g["bit_len"] = v.bit_cols, v.bit_len

    # ------------------------------------------------------------- state
    _G_ARRAYS = ("col_size", "relevant", "birth", "c_head", "c_next", "c_frame", "db_norm")

    def state_dict(self) -> tuple[dict, dict]:
        """(header, arrays): the memory, the candidates' graph, the beam and the decisions so far.

        The header is JSON-serialisable; :meth:`from_state` continues exactly
        as this stream would have.
        """
        mem_header, mem_arrays = self.mem.to_arrays()
        header = {"exclude": self.exclude, "seq": self.seq.flat(), "caps": self.caps, "frames": self.frames,
                  "starts": list(self.starts),
                  "n_nodes": self._n_nodes, "n_cells": self._g["n_cells"], "memory": mem_header}
        arrays = {f"mem_{k}": v for k, v in mem_arrays.items()}
        arrays.update({f"g_{k}": self._g[k] for k in self._G_ARRAYS})
        arrays.update({"a_head": self._a[0], "a_next": self._a[1], "a_dst": self._a[2]})
        cells, values = self._beam.cells()
        arrays.update({"beam_cells": cells, "beam_e": values, "beam_st": self._beam.st.copy()})
        arrays.update({f"dec_{k}": v for k, v in self.decider.state_dict().items()})
        return header, arrays

    @classmethod
    def from_state(cls, header: dict, arrays: dict) -> LoopStream:
        """The stream of a :meth:`state_dict` pair (raises ValueError on inconsistent arrays)."""
        mem_h = header["memory"]
        # written before the one conf: its parts apart
        seq = header["seq"] if "seq" in header else \
            {**header["conf"], **header["loop"], **header["beam"], **mem_h["params"]}
        s = cls(header["exclude"], RshosmSeqConf.build({**seq, **mem_h["params"]}), header["caps"])
        s.mem = SequenceMemory.from_arrays(mem_h, {k[4:]: v for k, v in arrays.items() if k.startswith("mem_")})
        s.frames, s._n_nodes = int(header["frames"]), int(header["n_nodes"])
        s.starts = [int(v) for v in header.get("starts", [0])]
        g = s._g
        g["n_cells"] = int(header["n_cells"])
        for k in cls._G_ARRAYS:
            g[k] = np.array(arrays[f"g_{k}"])
        if g["relevant"].size != g["n_cells"] or g["col_size"].size * g["cpc"] != g["n_cells"]:
            raise ValueError("loop stream state: the candidates' graph does not match its size")
        s._a = (np.array(arrays["a_head"]), np.array(arrays["a_next"]), np.array(arrays["a_dst"]))
        v = s.mem.view()
        g["bit_cols"], g["bit_len"] = v.bit_cols, v.bit_len
        s._beam = Beam(g["n_cells"], g["n_cells"] // g["cpc"], g["db_norm"].size)
        cells = np.asarray(arrays["beam_cells"], np.int64)
        if cells.size and (cells.min() < 0 or cells.max() >= g["n_cells"]):
            raise ValueError("loop stream state: beam cells outside the memory")
        s._beam.set_beam(cells, np.asarray(arrays["beam_e"], np.float64))
        s._beam.st[:] = arrays["beam_st"]
        s.decider.load_state({k[4:]: v for k, v in arrays.items() if k.startswith("dec_")})
        if s.decider.frames != s.frames:
            raise ValueError(f"loop stream state: {s.decider.frames} decisions for {s.frames} frames")
        return s

    def step(self, sdr_row) -> FrameLoop:
        """Learn the next frame (SDR row: 1-row batch, dense row or bit indices), score and decide it."""
        bits = _sdr.row_bits(sdr_row, self.mem.n_inputs, name="frame SDR")
        j = self.frames
        old_len, ne_old = self.mem.view().bit_len.copy(), self.mem.n_connections
        winners = self.mem.step(bits)
        self._attach(j, bits, winners, old_len, ne_old)
        n = n_candidates(j, self.exclude, self.starts[-1])
        p, rows, val = self._beam.run(self._g, self._a, np.array([0, bits.size], np.int64), bits,
                                      np.zeros(1, np.int64), np.array([n - 1], np.int64),
                                      self._params[self._capped(j)])
        order = np.argsort(rows, kind="stable")
        rows, val = rows[order], val[order]
        if self.conf.normalise == "query" and n > 0:
            mean = val.sum() / n
            var = (val * val).sum() / n - mean * mean
            sd = np.sqrt(var) if var > 0 else 1.0
            z, fill = (val - mean) / sd, -mean / sd
        else:
            z, fill = val, 0.0
        # decided on the float32 values the matrix keeps, so that deciding again on it gives the same
        z, fill = z.astype(np.float32), float(np.float32(fill))
        self.decider.add_sdr(bits)
        best, score, ok, margin, near = self.decider.decide(j, rows, z, n, fill)
        self.frames += 1
        return FrameLoop(winners, rows, z, fill, n, int(best), float(score), bool(ok), float(margin), bool(near))


@dataclass
class LoopEvidence:
    """What :func:`loop_evidence` gives: the T x T matrix, the winner codes, the decisions.

    ``similarity``: rows earlier frame ``i``, columns frame ``j``; dense
    float32 with ``-inf`` outside ``i <= j - exclude``, or a top-K csr matrix.
    ``fill[j]``: the score of a candidate of frame ``j`` without any evidence
    (what a missing entry of a top-K column stands for). ``decisions``: each
    frame's decision, taken on its full evidence column, so the same whether
    the matrix is dense or top-K.
    """

    similarity: np.ndarray | sp.csr_matrix
    codes: sp.csr_matrix
    fill: np.ndarray
    exclude: int
    decisions: LoopDecisions | None = None
    #: the first frame of every session (``[0]``: one)
    starts: tuple = (0,)

    def __iter__(self):  # ``S, codes = loop_evidence(...)``
        return iter((self.similarity, self.codes))


def loop_evidence(sdr_batch, exclude: int = LOOP_EXCLUDE, conf=None, top_k: int | None = None,
                  caps: str | bool = "auto", dense_max: int = LOOP_DENSE_MAX, stops: bool = True,
                  progress: bool = False, sessions=None, **flat) -> LoopEvidence:
    """Loop closure within one stream with graded forward sequence evidence, learned online.

    Frame ``j`` is learned with Algorithm 1 (as the paper, one memory over the
    stream) and then scored against the frames ``i <= j - exclude`` with the
    forward (causal) evidence of :func:`vpr.shosm.sparse_evidence`: only the
    past counts. Cells first learned at a frame after ``j - exclude`` take no
    part in the evidence at ``j`` at all (not only masked in the output):
    within one traverse a frame's own evidence would otherwise linger, through
    the stay transition, on the frames just before it and win there. Each
    frame is then decided (loop closure or new place, :class:`LoopConf`).

    Parameters
    ----------
    sdr_batch : SDR batch (T x n_inputs), the stream.
    exclude : int >= 1
        Frames closer than this are not candidates.
    conf : RshosmSeqConf, one of its parts, or a mapping of its flat keys
        The memory, the evidence (decay, transition costs, standardisation:
        z-scores per frame over its candidate frames), the beam's floors and
        caps (``caps`` says when they apply, :class:`LoopStream`) and the
        decision; ``**flat`` keys over it (:meth:`RshosmSeqConf.of`).
    top_k : int or None
        Earlier frames kept per frame in the matrix (None: dense T x T up to
        ``dense_max`` frames, the conf's ``top_k`` beyond). The decisions do not depend on it.
    stops : bool
        False leaves out the decision's stop check.
    sessions : sequence of int, optional
        The first frame of each session (a stream that joins a robot's runs):
        :meth:`LoopStream.new_session` there. Closures onto earlier sessions
        count; the seam between two runs is never "moving on".
    progress : bool
        tqdm progress bar.

    Returns
    -------
    LoopEvidence (unpacks as ``S, codes``).
    """
    top_k = check_top_k(top_k)
    seq = RshosmSeqConf.of(conf, **flat)
    if not stops:
        seq = seq.replace(stop_ratio=0.0)
    stream = LoopStream(exclude, seq, caps)
    x = _sdr.check_batch(sdr_batch, n_bits=stream.n_inputs, name="stream SDR batch")
    T = x.shape[0]
    starts = sorted({int(s) for s in (sessions or ())} - {0})
    if starts and (starts[0] < 0 or starts[-1] >= T):
        raise ValueError(f"sessions must start at frames 0 .. {T - 1}, got {sorted(sessions)}")
    if top_k is None and T > int(dense_max):  # a dense T x T would not fit (the project's limit on dense matrices)
        if seq.top_k is None:
            raise ValueError(f"top_k none keeps every earlier frame, a dense {T} x {T} matrix: above the "
                             f"{int(dense_max)} frames a loop matrix may have; give top_k")
        top_k = seq.top_k
    dense = np.full((T, T), -np.inf, np.float32) if top_k is None else None
    cols_i, cols_v, counts = [], [], np.zeros(T, np.int64)
    codes_ptr, codes_idx = np.zeros(T + 1, np.int64), []
    dec = np.zeros((5, T))
    fill = np.zeros(T, np.float32)
    begin = set(starts)
    for j in tqdm(range(T), desc="rSHOSM loops", unit="frame", leave=False, disable=not progress):
        if j in begin:
            stream.new_session()
        f = stream.step(x.indices[x.indptr[j]:x.indptr[j + 1]])
        codes_idx.append(f.winners)
        codes_ptr[j + 1] = codes_ptr[j] + f.winners.size
        dec[:, j] = (f.best, f.score, f.accepted, f.margin, f.near)
        fill[j] = f.fill
        if dense is not None:
            dense[: f.n_candidates, j] = f.fill
            dense[f.rows, j] = f.z
        else:
            keep = np.lexsort((f.rows, -f.z))[: int(top_k)]
            cols_i.append(f.rows[keep])
            cols_v.append(f.z[keep])
            counts[j] = keep.size
    codes = sp.csr_matrix((np.ones(int(codes_ptr[-1]), bool), np.concatenate(codes_idx + [np.zeros(0, np.int64)]),
                           codes_ptr), shape=(T, max(stream.mem.n_cells, 1)))
    decisions = LoopDecisions(dec[0].astype(np.int64), dec[1], dec[2].astype(bool), dec[3], dec[4].astype(bool))
    if dense is not None:
        return LoopEvidence(dense, codes, fill, stream.exclude, decisions, tuple(stream.starts))
    S = sp.csc_matrix((np.concatenate(cols_v + [np.zeros(0, np.float32)]),
                       np.concatenate(cols_i + [np.zeros(0, np.int64)]), np.r_[0, np.cumsum(counts)]),
                      shape=(T, T)).tocsr()
    S.sort_indices()
    return LoopEvidence(S, codes, fill, stream.exclude, decisions, tuple(stream.starts))
