"""One stream's learned memory laid out by frame, and the causal evidence over it: what loop closure steps.

:class:`StreamGraph` takes each frame in as the memory learns it (:meth:`StreamGraph.attach`): the cells that won
for the first time get the next numbers, the frame's winner code and its new lateral connections are appended as
one block. :class:`StreamEngine` steps the graded evidence of the beam over it (:mod:`vpr.shosm.kernels.stream`):
a frame's cost is one pass over the arrays in the order they were written, where the beam's linked lists were
read scattered over every cell of the memory.
"""
from __future__ import annotations

import numpy as np

from vpr.types import Column

from .conf import BeamConf, EvidenceConf
from .kernels import evidence as KE
from .kernels import stream as KS
from .memory import SequenceMemory

__all__ = ["StreamGraph", "StreamEngine", "make_stream_engine"]


def _room(a: np.ndarray, n: int, fill=0) -> np.ndarray:
    """``a`` with room for ``n`` entries (doubled when it grows), new entries ``fill``."""
    if a.size >= n:
        return a
    out = np.full(max(n, 2 * a.size), fill, a.dtype)
    out[: a.size] = a
    return out


class StreamGraph:
    """What the evidence reads of a memory that learns one stream, frame by frame.

    Attributes (``n_r`` cells, ``n_frames`` frames, ``n_blocks`` blocks of connections, each array with room to grow)
    ----------
    r_col : int32 per cell: its minicolumn (cells numbered in the order they first won).
    r_end : int64 per frame: cells learned by the end of that frame.
    code_ptr, code_r, norm : each frame's winner cells, and their count (at least 1).
    s_ptr, s_r, d_ptr, d_r, p_ptr, p_s, p_d : per block (one a frame that made connections): its sources, its
        targets, and its pairs where not every source connects to every target.
    """

    ARRAYS = ("r_col", "r_end", "code_ptr", "code_r", "norm", "s_ptr", "s_r", "d_ptr", "d_r", "p_ptr", "p_s", "p_d",
              "cell_r", "col_size")

    def __init__(self, mem: SequenceMemory):
        self.mem, self.cpc = mem, mem.cells_per_column
        self.n_r = self.n_frames = self.n_blocks = 0
        self.r_col = np.zeros(1024, np.int32)
        self.r_end = np.zeros(1024, np.int64)
        self.code_ptr, self.code_r = np.zeros(1025, np.int64), np.zeros(4096, np.int32)
        self.norm = np.ones(1024, np.float64)
        self.s_ptr, self.d_ptr, self.p_ptr = (np.zeros(1025, np.int64) for _ in range(3))
        self.s_r, self.d_r = np.zeros(4096, np.int32), np.zeros(4096, np.int32)
        self.p_s, self.p_d = np.zeros(1024, np.int32), np.zeros(1024, np.int32)
        self.cell_r = np.full(1024 * self.cpc, -1, np.int32)  # memory cell -> its number here (-1: never won)
        self.col_size = np.zeros(1024, np.float64)  # feed-forward connections per minicolumn
        v = mem.view(sizes=False)
        self.bit_cols, self.bit_len = v.bit_cols, v.bit_len

    def numbers(self, cells: np.ndarray) -> np.ndarray:
        """The numbers of memory cells (each must have won already)."""
        return self.cell_r[np.asarray(cells, np.int64)]

    def attach(self, bits: np.ndarray, winners: np.ndarray, old_len: np.ndarray, ne_old: int) -> None:
        """The frame just learned (active ``bits``, winner cells ``winners``) becomes the next frame.

        ``old_len`` / ``ne_old``: the memory's ``bit_len`` and connection count before it learned the frame.
        """
        v = self.mem.view(sizes=False)  # (the sizes: kept here, col_size)
        j = self.n_frames
        self.cell_r = _room(self.cell_r, v.n_cells, -1)
        self.col_size = _room(self.col_size, v.n_columns, 0.0)
        from .kernels import beam as KB  # the feed-forward connections' count per minicolumn, as the beam keeps it

        KB.count_new_entries(self.col_size, bits, old_len, v.bit_len, v.bit_cols)
        winners = np.asarray(winners, np.int64)
        new = winners[self.cell_r[winners] < 0]
        self.r_col = _room(self.r_col, self.n_r + new.size)
        self.cell_r[new] = np.arange(self.n_r, self.n_r + new.size, dtype=np.int32)
        self.r_col[self.n_r: self.n_r + new.size] = new // self.cpc
        self.n_r += new.size
        self.r_end = _room(self.r_end, j + 1)
        self.r_end[j] = self.n_r
        self.code_ptr = _room(self.code_ptr, j + 2)
        self.code_r = _room(self.code_r, self.code_ptr[j] + winners.size)
        self.code_r[self.code_ptr[j]: self.code_ptr[j] + winners.size] = self.cell_r[winners]
        self.code_ptr[j + 1] = self.code_ptr[j] + winners.size
        self.norm = _room(self.norm, j + 1, 1.0)
        self.norm[j] = max(winners.size, 1)
        src, dst = v.e_src[ne_old:], v.e_dst[ne_old:]
        if src.size:
            b = self.n_blocks
            for name in ("s_ptr", "d_ptr", "p_ptr"):
                setattr(self, name, _room(getattr(self, name), b + 2))
            self.s_r = _room(self.s_r, self.s_ptr[b] + src.size)
            self.d_r = _room(self.d_r, self.d_ptr[b] + src.size)
            self.p_s = _room(self.p_s, self.p_ptr[b] + src.size)
            self.p_d = _room(self.p_d, self.p_ptr[b] + src.size)
            KS.add_block(self.s_ptr, self.s_r, self.d_ptr, self.d_r, self.p_ptr, self.p_s, self.p_d, b,
                         self.cell_r[src], self.cell_r[dst])
            self.n_blocks = b + 1
        self.n_frames = j + 1
        self.bit_cols, self.bit_len = v.bit_cols, v.bit_len

    def learned_by(self, frame: int) -> int:
        """The cells learned by the end of ``frame`` (-1: none)."""
        return int(self.r_end[frame]) if frame >= 0 else 0

    def kernel_args(self) -> tuple:
        v = (self.bit_cols, self.bit_len, self.col_size)
        blocks = (self.s_ptr, self.s_r, self.d_ptr, self.d_r, self.p_ptr, self.p_s, self.p_d)
        return v, (self.r_col,), blocks, (self.code_ptr, self.code_r, self.norm)

    # ------------------------------------------------------------- state
    def state(self) -> tuple[dict, dict]:
        header = {"n_r": self.n_r, "n_frames": self.n_frames, "n_blocks": self.n_blocks}
        return header, {k: getattr(self, k) for k in self.ARRAYS}

    def load_state(self, header: dict, arrays: dict) -> StreamGraph:
        for k in self.ARRAYS:
            if k not in arrays:
                raise ValueError(f"the stream graph's state lacks {k!r} (saved by another version?)")
            setattr(self, k, np.array(arrays[k]))
        self.n_r, self.n_frames, self.n_blocks = int(header["n_r"]), int(header["n_frames"]), int(header["n_blocks"])
        v = self.mem.view(sizes=False)
        if self.cell_r.size < v.n_cells or self.n_r > self.r_col.size or self.n_frames + 1 > self.code_ptr.size:
            raise ValueError("the stream graph does not match its memory")
        self.bit_cols, self.bit_len = v.bit_cols, v.bit_len
        return self


class StreamEngine:
    """The causal graded evidence of each new frame of a stream over the frames before it (the beam's evidence,
    :class:`vpr.shosm.Engine`, laid out by frame): :meth:`step` one frame, as :meth:`vpr.shosm.Engine.step`."""

    def __init__(self, graph: StreamGraph, evidence: EvidenceConf | None = None, beam: BeamConf | None = None,
                 z_weight: float = 0.0):
        self.graph, self.evidence, self.beam_conf = graph, evidence or EvidenceConf(), beam or BeamConf()
        self.normalise = self.evidence.normalise == "query"
        self.frames = 0
        stay, skip = self.evidence.costs
        base = [float(self.evidence.decay), stay, skip, float(z_weight), float(self.beam_conf.floor),
                float(self.beam_conf.rel_floor), float(self.beam_conf.z_floor)]
        caps = self.beam_conf.caps
        self._params = {True: np.array([*base, *caps], np.float64), False: np.array([*base, 0, 0], np.float64)}
        self.e_beam = np.zeros(1024, np.float64)
        self._scratch_r = 0
        self._grow_scratch()

    @property
    def lanes(self) -> list:
        return [self]

    def _grow_scratch(self) -> None:
        g = self.graph
        n_r, n_cols = max(g.r_col.size, 1), max(g.col_size.size, 1)
        if self._scratch_r >= n_r and self.counts.size >= n_cols:
            return
        self.counts, self.touched = np.zeros(n_cols, np.int32), np.zeros(n_cols, np.int32)
        self.p1, self.p2, self.z, self.e_new = (np.zeros(n_r, np.float64) for _ in range(4))
        self.cand = np.zeros(n_r, np.uint8)
        self.e_beam = _room(self.e_beam, n_r, 0.0)
        self.out_idx, self.out_val = np.zeros(max(g.norm.size, 1), np.int64), np.zeros(max(g.norm.size, 1))
        self._scratch_r = n_r

    def grow(self) -> None:
        """Make room after the graph took a frame in."""
        g = self.graph
        if g.r_col.size > self._scratch_r or g.col_size.size > self.counts.size or g.norm.size > self.out_idx.size:
            self._scratch_r = 0
            self._grow_scratch()

    def step(self, bits, n: int | None = None, capped: bool = False, frame: int = -1, overlaps=None) -> Column:
        """The evidence of the next frame (its active bits, sorted) over the candidate frames ``0 .. n - 1``
        (default: every frame learned); only the cells learned by frame ``n - 1`` take part. ``capped``: the beam's
        caps apply; ``overlaps``: the frame's overlap counts as the memory kept them learning it
        (:meth:`vpr.shosm.SequenceMemory.overlaps`, set back to 0 here), counted again where the caps apply."""
        rows, val, n = self.step_raw(bits, n, capped, overlaps)
        return self.column(rows, val, n, frame)

    def step_raw(self, bits, n: int | None = None, capped: bool = False,
                 overlaps=None) -> tuple[np.ndarray, np.ndarray, int]:
        g = self.graph
        n = g.n_frames if n is None else int(n)
        self.grow()
        n_r = g.learned_by(n - 1)
        ff, cells, blocks, codes = g.kernel_args()
        counts, touched, counted = self.counts, self.touched, -1
        if overlaps is not None:
            counts, touched, n_touched = overlaps
            if capped:  # the cap ranks every minicolumn touched, those the frame created with them: count again
                counts[touched[:n_touched]] = 0
            else:
                counted = n_touched
        m = KS.stream_step(np.asarray(bits, np.int64), counted, n_r, n, g.n_blocks, ff, cells, blocks, codes,
                           self._params[bool(capped)], self.e_beam,
                           (counts, touched, self.p1, self.p2, self.z, self.e_new, self.cand),
                           self.out_idx, self.out_val)
        self.frames += 1
        return self.out_idx[:m].copy(), self.out_val[:m].copy(), n

    def column(self, rows, val, n: int, frame: int = -1) -> Column:
        """The standardised column of raw evidence ``val`` at ``rows`` (sorted) over ``n`` candidates."""
        mu, sd = KE.moments(val, n) if self.normalise and n > 0 else (0.0, 1.0)
        z = ((val - mu) / sd).astype(np.float32)
        return Column(np.asarray(rows, np.int64), z, float(np.float32(-mu / sd)), int(n), frame)

    def reset(self) -> None:
        """Forget the evidence carried from earlier frames (a new session)."""
        self.frames = 0
        self.e_beam[:] = 0.0

    def state(self) -> tuple[dict, dict]:
        return {"frames": self.frames, "stream": True}, {"e_beam": self.e_beam[: self.graph.n_r].copy()}

    def load_state(self, header: dict, arrays: dict) -> StreamEngine:
        if not header.get("stream"):
            raise ValueError("the state is of another evidence engine (saved by another version?)")
        self.frames = int(header["frames"])
        self._scratch_r = 0
        self._grow_scratch()
        e = np.asarray(arrays["e_beam"], np.float64)
        if e.size > self.e_beam.size:
            raise ValueError("the evidence state has more cells than its graph")
        self.e_beam[:] = 0.0
        self.e_beam[: e.size] = e
        return self



def make_stream_engine(graph: StreamGraph, evidence: EvidenceConf | None = None, beam: BeamConf | None = None):
    """The stream's evidence engine of ``evidence``'s speed models: a :class:`StreamEngine` for one, a
    :class:`vpr.shosm.SpeedEngine` of one each for several (as :func:`vpr.shosm.make_engine`)."""
    from .evidence import SpeedEngine

    evidence = evidence or EvidenceConf()
    lanes = evidence.split()
    if len(lanes) == 1:
        return StreamEngine(graph, lanes[0], beam)
    return SpeedEngine.of_lanes(graph, evidence, [StreamEngine(graph, lane, beam) for lane in lanes])
