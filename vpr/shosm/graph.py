"""The learned memory as the evidence kernels read it (:class:`Graph`), and one pass's scratch (:class:`Beam`)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .kernels import beam as KB
from .memory import SequenceMemory

__all__ = ["BIG", "Graph", "Beam", "check_codes", "linked_lists", "grouped_lists"]

#: "Never": a birth frame or a limit beyond any frame.
BIG = KB.NO_LIMIT


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


def _grown(a, size, fill):
    out = np.full(size, fill, a.dtype)
    out[: a.size] = a
    return out


class Graph:
    """A learned memory and the database frames it can answer with, as the kernels read them.

    ``bit_cols, bit_len``: input bit -> minicolumns; ``col_size``: connections per minicolumn; ``cpc, n_cells,
    n_cols``; ``fwd, bwd``: successor lists ``(head, next, target[, group])`` per cell or group (``bwd`` reversed, or
    None); ``c_head, c_next, c_frame``: cell -> database frames; ``relevant``, ``birth`` per cell; ``db_norm`` per
    frame; ``n_db``.
    """

    ARRAYS = ("col_size", "relevant", "birth", "c_head", "c_next", "c_frame", "db_norm")

    def __init__(self, mem: SequenceMemory, codes: sp.csr_matrix | None = None, backward: bool = False):
        v = mem.view()
        self.mem, self.cpc = mem, v.cells_per_column
        self.bit_cols, self.bit_len = v.bit_cols, v.bit_len
        self.codes = codes
        if codes is None:  # grows with the stream (attach)
            cap = 1024 * self.cpc
            self.n_cells, self.n_cols, self.n_db = cap, 1024, 0
            self.col_size, self.relevant = np.zeros(1024), np.zeros(cap, bool)
            self.birth, self.c_head = np.full(cap, BIG, np.int64), np.full(cap, -1, np.int32)
            self.c_next, self.c_frame = np.zeros(4096, np.int32), np.zeros(4096, np.int32)
            self.db_norm = np.ones(1024, np.float64)
            self.fwd, self.bwd = (np.full(cap, -1, np.int32), np.zeros(4096, np.int32), np.zeros(4096, np.int32)), None
            self.n_nodes = 0
            return
        n_cells = max(v.n_cells, codes.shape[1], 1)
        self.n_cells, self.n_cols, self.n_db = n_cells, max(v.n_columns, 1), codes.shape[0]
        self.col_size = v.column_sizes.astype(np.float64)
        self.relevant = np.zeros(n_cells, bool)
        self.relevant[codes.indices] = True
        self.relevant[v.e_src] = True
        self.relevant[v.e_dst] = True
        coo = codes.tocoo()
        self.c_head, self.c_next, self.c_frame = _narrow(linked_lists(coo.col, coo.row, n_cells))
        self.n_nodes = self.c_frame.size
        self.birth = np.zeros(n_cells, np.int64)
        self.db_norm = np.maximum(np.diff(codes.indptr), 1).astype(np.float64)
        self.fwd = _narrow(grouped_lists(v.e_src, v.e_dst, n_cells))
        self.bwd = _narrow(grouped_lists(v.e_dst, v.e_src, n_cells)) if backward else None

    @classmethod
    def of(cls, mem: SequenceMemory, db_codes, backward: bool = False) -> Graph:
        """The graph of a learned database (``db_codes``: its winner codes); ``backward``: also ``bwd``."""
        return cls(mem, check_codes(mem, db_codes), backward)

    @classmethod
    def growing(cls, mem: SequenceMemory) -> Graph:
        """An empty graph over ``mem``, which learns one stream while it is read: :meth:`attach` each frame."""
        return cls(mem)

    def attach(self, j: int, bits: np.ndarray, winners: np.ndarray, old_len: np.ndarray, ne_old: int) -> None:
        """Frame ``j``, just learned (winner cells ``winners``), becomes a database frame.

        ``old_len`` / ``ne_old``: the memory's ``bit_len`` and connection count before it learned the frame.
        """
        v, cpc = self.mem.view(), self.cpc
        a_head, a_next, a_dst = self.fwd
        if v.n_cells > self.n_cells:  # grow everything indexed by cell or minicolumn
            new = max(v.n_cells, 2 * self.n_cells)
            self.relevant, self.birth = _grown(self.relevant, new, False), _grown(self.birth, new, BIG)
            self.c_head, self.col_size = _grown(self.c_head, new, -1), _grown(self.col_size, new // cpc, 0.0)
            a_head = _grown(a_head, new, -1)
            self.n_cells, self.n_cols = new, new // cpc
        if j >= self.db_norm.size:
            self.db_norm = _grown(self.db_norm, 2 * (j + 1), 1.0)
        KB.count_new_entries(self.col_size, bits, old_len, v.bit_len, v.bit_cols)
        ne = v.e_src.size
        if ne > a_next.size:
            a_next, a_dst = np.resize(a_next, max(ne, 2 * a_next.size)), np.resize(a_dst, max(ne, 2 * a_dst.size))
        KB.append_lists(a_head, a_next, a_dst, ne_old, v.e_src[ne_old:], v.e_dst[ne_old:])
        self.fwd = (a_head, a_next, a_dst)
        n = self.n_nodes
        if n + winners.size > self.c_next.size:
            self.c_next = np.resize(self.c_next, 2 * (n + winners.size))
            self.c_frame = np.resize(self.c_frame, 2 * (n + winners.size))
        KB.append_lists(self.c_head, self.c_next, self.c_frame, n, winners, np.full(winners.size, j, np.int64))
        self.n_nodes = n + winners.size
        self.relevant[winners] = True
        self.birth[winners] = np.minimum(self.birth[winners], j)
        self.db_norm[j] = max(winners.size, 1)
        self.bit_cols, self.bit_len = v.bit_cols, v.bit_len
        self.n_db = j + 1

    def dense(self) -> tuple:
        """The dense kernel's form (:func:`vpr.shosm.kernels.evidence.evidence_frames`), on the relevant cells only.

        Only cells in database codes or on a connection can carry evidence to the output; they are renumbered ``0 ..
        n_rel - 1``. Returns ``(rel, (bit_cols, bit_len, col_size, rel_col, src, dst, db_ptr, db_ind, db_norm))`` with
        ``rel`` the memory's cell index of each relevant cell.
        """
        v, db = self.mem.view(), self.codes
        rel = np.unique(np.concatenate([db.indices.astype(np.int64), v.e_src, v.e_dst]))
        db_ptr = db.indptr.astype(np.int64)
        return rel, (v.bit_cols, v.bit_len, v.column_sizes.astype(np.float64), rel // v.cells_per_column,
                     np.searchsorted(rel, v.e_src).astype(np.int64), np.searchsorted(rel, v.e_dst).astype(np.int64),
                     db_ptr, np.searchsorted(rel, db.indices.astype(np.int64)).astype(np.int64),
                     np.diff(db_ptr).astype(np.float64))

    # ------------------------------------------------------------- state (a growing graph)
    def state(self) -> tuple[dict, dict]:
        header = {"n_cells": self.n_cells, "n_nodes": self.n_nodes, "n_db": self.n_db}
        arrays = {k: getattr(self, k) for k in self.ARRAYS}
        arrays.update(a_head=self.fwd[0], a_next=self.fwd[1], a_dst=self.fwd[2])
        return header, arrays

    def load_state(self, header: dict, arrays: dict) -> Graph:
        self.n_cells, self.n_nodes = int(header["n_cells"]), int(header["n_nodes"])
        for k in self.ARRAYS:
            setattr(self, k, np.array(arrays[k]))
        self.c_head, self.c_next, self.c_frame = _narrow((self.c_head, self.c_next, self.c_frame))
        self.n_cols = self.col_size.size
        self.n_db = int(header.get("n_db", self.db_norm.size))
        if self.relevant.size != self.n_cells or self.n_cols * self.cpc != self.n_cells:
            raise ValueError("the evidence graph does not match its size")
        self.fwd = _narrow((arrays["a_head"], arrays["a_next"], arrays["a_dst"]))
        v = self.mem.view()
        self.bit_cols, self.bit_len = v.bit_cols, v.bit_len
        return self


class Beam:
    """The state and scratch arrays of :func:`vpr.shosm.kernels.beam.beam_frames`, one direction."""

    def __init__(self, graph: Graph):
        n_cells, n_cols, n_db = graph.n_cells, graph.n_cols, max(graph.db_norm.size, 1)
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
        self.gmax, self.gmark, self.gtouch = np.zeros(0), np.zeros(0, bool), np.zeros(0, np.int64)

    @property
    def largest(self) -> tuple[int, int]:
        """(largest beam, largest candidate set) of any frame so far (to check the caps)."""
        return int(self.st[KB.B_MAX_BEAM]), int(self.st[KB.B_MAX_CAND])

    def grow(self, graph: Graph) -> None:
        """Make room for a graph that has grown (online learning)."""
        def g(a, n):
            return a if a.size >= n else _grown(a, max(n, 2 * a.size), 0)

        for name in ("in_beam", "slot", "beam", "cand", "beam_e", "p1", "p2", "z", "e_new"):
            setattr(self, name, g(getattr(self, name), graph.n_cells))
        self.counts, self.touched_cols = g(self.counts, graph.n_cols), g(self.touched_cols, graph.n_cols)
        n_db = graph.db_norm.size
        self.acc, self.db_mark, self.db_touch = g(self.acc, n_db), g(self.db_mark, n_db), g(self.db_touch, n_db)

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

    def run(self, g: Graph, adj, q_ptr, q_ind, order, limits, params):
        """Run frames ``order`` along the successor lists ``adj``; return their sparse columns (ptr, idx, val)."""
        grp = adj[3] if len(adj) == 4 else np.zeros(0, np.int32)
        if grp.size and self.gmax.size < adj[0].size:
            self.gmax, self.gmark = np.zeros(adj[0].size), np.zeros(adj[0].size, bool)
            self.gtouch = np.zeros(adj[0].size, np.int64)
        n = order.size
        out_ptr = np.zeros(n + 1, np.int64)
        st = self.st
        st[KB.B_OUT_POS] = 0
        st[KB.B_FRAMES] = 0
        while True:
            done = KB.beam_frames((q_ptr, q_ind, order, limits), (g.bit_cols, g.bit_len, g.col_size, g.cpc),
                                  (adj[0], adj[1], adj[2], grp),
                                  (g.c_head, g.c_next, g.c_frame, g.relevant, g.birth, g.db_norm), params,
                                  (st, self.beam, self.beam_e, self.in_beam),
                                  (self.counts, self.touched_cols, self.p1, self.p2, self.z, self.slot, self.cand,
                                   self.e_new, self.gmax, self.gmark, self.gtouch, self.acc, self.db_mark,
                                   self.db_touch), (out_ptr, self.out_idx, self.out_val))
            if done >= n:
                break
            size = max(int(st[KB.B_NEED]), 2 * self.out_idx.size)
            self.out_idx = np.resize(self.out_idx, size)
            self.out_val = np.resize(self.out_val, size)
        end = out_ptr[-1]
        return out_ptr, self.out_idx[:end].copy(), self.out_val[:end].copy()
