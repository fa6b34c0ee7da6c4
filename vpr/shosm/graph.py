"""A learned database as the beam's kernels read it (:class:`Graph`), and one pass's scratch (:class:`Beam`)."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from .kernels import beam as KB
from .memory import SequenceMemory

__all__ = ["Graph", "DenseGraph", "Beam", "check_codes", "linked_lists", "grouped_lists"]


def check_codes(mem: SequenceMemory, db_codes) -> sp.csr_matrix:
    """Winner codes of the database (csr), refused when they are not codes of ``mem``."""
    if not sp.issparse(db_codes) or db_codes.ndim != 2:
        raise ValueError("db_codes must be a sparse winner-code matrix (database frames x cells)")
    db = sp.csr_matrix(db_codes)
    if db.shape[1] > mem.n_cells and db[:, mem.n_cells:].nnz:
        raise ValueError(f"db_codes use cells beyond this memory's {mem.n_cells}: codes of another memory?")
    return db


def linked_lists(keys, vals, n_heads):
    """Linked lists key -> values laid out contiguously (sorted by key): (head, next, value)."""
    keys = np.asarray(keys, np.int64)
    order = np.argsort(keys, kind="stable")
    ks = keys[order]
    head = np.full(n_heads, -1, np.int64)
    nxt = np.arange(1, ks.size + 1, dtype=np.int64)
    if ks.size:
        first = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
        head[ks[first]] = first
        nxt[np.r_[ks[1:] != ks[:-1], True]] = -1
    return head, nxt, np.asarray(vals, np.int64)[order]


def grouped_lists(keys, vals, n_heads):
    """Linked lists key -> values, one per group of keys with the same set of values: (head, next, value, group).

    ``group[k]`` is key ``k``'s group (-1: no values). A frame's winner cells all predict the next frame's, so the
    beam relaxes a group's largest evidence once: the same maxima as key by key, fewer relaxations.
    """
    keys, vals = np.asarray(keys, np.int64), np.asarray(vals, np.int64)
    order = np.lexsort((vals, keys))
    k, v = keys[order], vals[order]
    if k.size:
        keep = np.r_[True, (k[1:] != k[:-1]) | (v[1:] != v[:-1])]  # a repeated connection relaxes nothing new
        k, v = k[keep], v[keep]
    starts = np.flatnonzero(np.r_[True, k[1:] != k[:-1]]) if k.size else np.zeros(0, np.int64)
    ends = np.r_[starts[1:], k.size].astype(np.int64)[: starts.size]
    ids: dict[bytes, int] = {}
    row_group = np.array([ids.setdefault(v[a:b].tobytes(), len(ids)) for a, b in zip(starts, ends, strict=True)],
                         np.int64)
    group = np.full(n_heads, -1, np.int64)
    group[k[starts]] = row_group
    first = np.full(len(ids), -1, np.int64)
    first[row_group[::-1]] = np.arange(row_group.size - 1, -1, -1)  # each group's first row
    lens = ends[first] - starts[first]
    take = np.concatenate([np.arange(starts[r], ends[r]) for r in first]) if first.size else np.zeros(0, np.int64)
    head, nxt, value = linked_lists(np.repeat(np.arange(len(ids)), lens), v[take], len(ids))
    return head, nxt, value, group


def _narrow(lists) -> tuple:
    """Linked lists as the kernels read them: 32-bit entries (half the memory traffic of 64)."""
    return tuple(np.asarray(a, np.int32) for a in lists)


class Graph:
    """A learned memory and the database frames it can answer with, as the beam's kernels read them (one stream
    learned while it is read: :class:`vpr.shosm.StreamGraph`).

    Only cells in the database's codes or on a lateral connection can carry evidence to a database frame: they are
    numbered ``0 .. n_rel - 1`` in the order of the memory's cells (``rel``: each one's memory cell), so that every
    array indexed by cell is as long as those cells, not as the whole memory. ``bit_cols, bit_len``: input bit ->
    minicolumns; ``col_size``: connections per minicolumn; ``col_ptr``: minicolumn ``m``'s cells are ``col_ptr[m] ..
    col_ptr[m + 1] - 1``; ``r_col``: each cell's minicolumn; ``fwd, bwd``: successor lists ``(head, next, target[,
    group])`` per cell or group (``bwd`` reversed, or None); ``c_head, c_next, c_frame``: cell -> database frames;
    ``db_norm`` per frame; ``n_db``.
    """

    def __init__(self, mem: SequenceMemory, codes: sp.csr_matrix, backward: bool = False):
        v = mem.view()
        self.mem, self.cpc = mem, v.cells_per_column
        self.bit_cols, self.bit_len = v.bit_cols, v.bit_len
        self.codes = codes
        self.n_cols, self.n_db = max(v.n_columns, 1), codes.shape[0]
        self.col_size = v.column_sizes.astype(np.float64)
        self.rel = np.unique(np.concatenate([codes.indices.astype(np.int64), v.e_src, v.e_dst]))
        self.n_rel = self.rel.size
        self.r_col = (self.rel // self.cpc).astype(np.int32)
        self.col_ptr = np.r_[0, np.cumsum(np.bincount(self.r_col, minlength=self.n_cols))].astype(np.int32)
        coo = codes.tocoo()
        self.c_head, self.c_next, self.c_frame = _narrow(linked_lists(self.number(coo.col), coo.row, self.n_rel))
        self.db_norm = np.maximum(np.diff(codes.indptr), 1).astype(np.float64)
        src, dst = self.number(v.e_src), self.number(v.e_dst)
        self.fwd = _narrow(grouped_lists(src, dst, self.n_rel))
        self.bwd = _narrow(grouped_lists(dst, src, self.n_rel)) if backward else None

    def number(self, cells) -> np.ndarray:
        """The numbers of memory cells that can carry evidence (:attr:`rel`)."""
        return np.searchsorted(self.rel, np.asarray(cells, np.int64)).astype(np.int64)

    @classmethod
    def of(cls, mem: SequenceMemory, db_codes, backward: bool = False) -> Graph:
        """The graph of a learned database (``db_codes``: its winner codes); ``backward``: also ``bwd``."""
        return cls(mem, check_codes(mem, db_codes), backward)

    def dense(self) -> tuple[np.ndarray, DenseGraph]:
        """The dense kernel's form (:func:`vpr.shosm.kernels.evidence.evidence_frames`), on the cells that can carry
        evidence: ``(rel, DenseGraph)``."""
        v, db = self.mem.view(), self.codes
        db_ptr = db.indptr.astype(np.int64)
        return self.rel, DenseGraph(v.bit_cols, v.bit_len, v.column_sizes.astype(np.float64),
                                    self.rel // v.cells_per_column, self.number(v.e_src), self.number(v.e_dst), db_ptr,
                                    self.number(db.indices), np.diff(db_ptr).astype(np.float64))


class DenseGraph(NamedTuple):
    """A database as the dense kernel reads it (:func:`vpr.shosm.kernels.evidence.evidence_frames`'s arguments in
    their order): the inverted index, each cell's minicolumn, the lateral connections ``src -> dst`` (a pass along
    the map's transitions reversed swaps them: :meth:`reversed`) and the database's codes."""

    bit_cols: np.ndarray
    bit_len: np.ndarray
    col_size: np.ndarray
    rel_col: np.ndarray
    src: np.ndarray
    dst: np.ndarray
    db_ptr: np.ndarray
    db_ind: np.ndarray
    db_norm: np.ndarray

    def reversed(self) -> DenseGraph:
        """The same database along its transitions reversed."""
        return self._replace(src=self.dst, dst=self.src)


class Beam:
    """The state and scratch arrays of :func:`vpr.shosm.kernels.beam.beam_frames`, one direction."""

    def __init__(self, graph: Graph):
        n_cells, n_cols, n_db = max(graph.n_rel, 1), graph.n_cols, max(graph.db_norm.size, 1)
        self.st = np.zeros(KB.BEAM_STATE_SIZE, np.int64)
        # per cell (32 bits: 2**31 cells): its place in the beam and its candidate number, plus one (0: none); per
        # candidate or beam entry (at most one per cell; np.zeros leaves the pages no frame reached unmapped)
        for name in ("in_beam", "slot", "beam", "cand"):
            setattr(self, name, np.zeros(n_cells, np.int32))
        for name in ("beam_e", "p1", "p2", "z", "e_new"):
            setattr(self, name, np.zeros(n_cells, np.float64))
        self.counts, self.touched_cols = np.zeros(n_cols, np.int32), np.zeros(n_cols, np.int32)
        self.acc, self.db_mark, self.db_touch = np.zeros(n_db, np.float64), np.zeros(n_db, bool), np.zeros(n_db,
                                                                                                             np.int64)
        self.out_idx, self.out_val = np.zeros(4096, np.int64), np.zeros(4096, np.float64)
        self.out_val2, self.acc2 = np.zeros(0), np.zeros(0)  # a second output where a run asks for it
        self.gmax, self.gmark, self.gtouch = np.zeros(0), np.zeros(0, bool), np.zeros(0, np.int64)

    @property
    def largest(self) -> tuple[int, int]:
        """(largest beam, largest candidate set) of any frame so far (to check the caps)."""
        return int(self.st[KB.B_MAX_BEAM]), int(self.st[KB.B_MAX_CAND])

    def cells(self) -> tuple[np.ndarray, np.ndarray]:
        """(cells, evidence) of the beam now (copies)."""
        n = int(self.st[KB.B_SIZE])
        return self.beam[:n].astype(np.int64), self.beam_e[:n].copy()

    def set_cells(self, cells, values) -> None:
        """Replace the beam (empty: a new start)."""
        self.in_beam[self.beam[: int(self.st[KB.B_SIZE])]] = 0
        n = len(cells)
        self.beam[:n], self.beam_e[:n] = cells, values
        self.in_beam[np.asarray(cells, np.int64)] = np.arange(1, n + 1, dtype=np.int32)
        self.st[KB.B_SIZE] = n

    def _lists(self, adj) -> tuple:
        grp = adj[3] if len(adj) == 4 else np.zeros(0, np.int32)
        if grp.size and self.gmax.size < adj[0].size:
            self.gmax, self.gmark = np.zeros(adj[0].size), np.zeros(adj[0].size, bool)
            self.gtouch = np.zeros(adj[0].size, np.int64)
        return adj[0], adj[1], adj[2], grp

    def _scratch(self, counts=None, touched=None) -> tuple:
        return (self.counts if counts is None else counts, self.touched_cols if touched is None else touched,
                self.p1, self.p2, self.z, self.slot, self.cand, self.e_new, self.gmax, self.gmark, self.gtouch,
                self.acc, self.db_mark, self.db_touch, self.acc2)

    def _out(self, out_ptr, z_weight2) -> tuple:
        """The output arrays (with ``z_weight2``, the second value array and its accumulator made room for first)."""
        two = z_weight2 is not None
        if two and self.out_val2.size != self.out_idx.size:
            self.out_val2 = np.zeros(self.out_idx.size)
        if two and self.acc2.size != self.acc.size:
            self.acc2 = np.zeros(self.acc.size)
        return out_ptr, self.out_idx, self.out_val, self.out_val2 if two else np.zeros(0), \
            0.0 if z_weight2 is None else float(z_weight2)

    def _grow_out(self, need: int, two: bool) -> None:
        size = max(int(need), 2 * self.out_idx.size)
        self.out_idx, self.out_val = np.resize(self.out_idx, size), np.resize(self.out_val, size)
        if two:
            self.out_val2 = np.resize(self.out_val2, size)

    def _columns(self, out_ptr, z_weight2) -> tuple:
        end = out_ptr[-1]
        cols = (out_ptr, self.out_idx[:end].copy(), self.out_val[:end].copy())
        return cols if z_weight2 is None else (cols, (out_ptr, cols[1], self.out_val2[:end].copy()))

    def _start(self, n: int):
        out_ptr = np.zeros(n + 1, np.int64)
        self.st[KB.B_OUT_POS] = 0
        self.st[KB.B_FRAMES] = 0
        return out_ptr

    @staticmethod
    def _ff(g: Graph) -> tuple:
        return g.bit_cols, g.bit_len, g.col_size, g.col_ptr

    @staticmethod
    def _cells(g: Graph) -> tuple:
        return g.c_head, g.c_next, g.c_frame, g.r_col, g.db_norm

    def _state(self) -> tuple:
        return self.st, self.beam, self.beam_e, self.in_beam

    def run(self, g: Graph, adj, q_ptr, q_ind, order, params, z_weight2: float | None = None):
        """Run frames ``order`` along the successor lists ``adj``; return their sparse columns (ptr, idx, val), and
        with ``z_weight2`` a pair of them: the second with the frame's own overlap taken out ``z_weight2`` times."""
        lists = self._lists(adj)
        n = order.size
        out_ptr = self._start(n)
        while True:
            out = self._out(out_ptr, z_weight2)  # (before the scratch: it sizes the second accumulator)
            done = KB.beam_frames((q_ptr, q_ind, order), self._ff(g), lists, self._cells(g), params, self._state(),
                                  self._scratch(), out)
            if done >= n:
                break
            self._grow_out(self.st[KB.B_NEED], z_weight2 is not None)
        return self._columns(out_ptr, z_weight2)

    def run_pair(self, other: Beam, g: Graph, adj, other_adj, q_ptr, q_ind, order, params, other_params,
                 z_weight2: float | None = None):
        """:meth:`run` of this beam along ``adj`` and of ``other`` along ``other_adj`` over the same frames at once,
        each frame's overlaps counted once for both; returns (this run's columns, the other's)."""
        lists, other_lists = self._lists(adj), other._lists(other_adj)
        n = order.size
        out_ptr, other_ptr = self._start(n), other._start(n)
        while True:
            out, other_out = self._out(out_ptr, z_weight2), other._out(other_ptr, None)  # (before the scratch)
            done = KB.beam_frames_pair((q_ptr, q_ind, order), self._ff(g), lists, other_lists, self._cells(g), params,
                                       other_params, self._state(), other._state(), self._scratch(),
                                       other._scratch(self.counts, self.touched_cols), out, other_out)
            if done >= n:
                break
            self._grow_out(self.st[KB.B_NEED], z_weight2 is not None)
            other._grow_out(other.st[KB.B_NEED], False)
        return self._columns(out_ptr, z_weight2), other._columns(other_ptr, None)
