"""The beam of the sparse evidence: what its kernel reads and the scratch it writes, shared by every use.

Internal to :mod:`vpr.shosm`: :func:`vpr.shosm.sparse_evidence` (a query
traverse), :class:`vpr.shosm.ForwardEvidence` (one frame at a time) and
:func:`vpr.shosm.loop_evidence` (one stream learned online) all run
:func:`vpr.shosm.kernels.beam.beam_frames` through a :class:`Beam` over a
:func:`db_graph`, and finish the columns with :func:`finish`.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .conf import BeamConf, EvidenceConf
from .kernels import beam as KB
from .kernels import evidence as KE
from .memory import SequenceMemory

__all__ = ["BIG", "Beam", "db_graph", "beam_params", "check_codes", "finish", "reverse_columns", "linked_lists",
           "grouped_lists"]

#: "Never": a birth frame or a limit beyond any frame.
BIG = np.iinfo(np.int64).max // 4


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
    if ks.size:
        first = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
        head[ks[first]] = first
    nxt = np.arange(1, ks.size + 1, dtype=np.int64)
    if ks.size:
        nxt[np.r_[ks[1:] != ks[:-1], True]] = -1
    return head, nxt, np.asarray(vals, np.int64)[order]


def grouped_lists(keys, vals, n_heads):
    """Linked lists key -> values, one per group of keys with the same set of values: (head, next, value, group).

    ``group[k]`` is key ``k``'s group (-1: no values); ``head``, ``next``, ``value`` are
    :func:`linked_lists` per group. The beam relaxes a group's largest evidence once
    (:func:`vpr.shosm.kernels.beam.beam_frames`): the same maxima as key by key.
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


def beam_params(evidence: EvidenceConf, beam: BeamConf, z_weight: float) -> tuple:
    """The scalar arguments of ``beam_frames`` (``z_weight``: 0.5 when two directions are added, else 0)."""
    stay, skip = evidence.costs
    return (float(evidence.decay), stay, skip, float(z_weight), float(beam.floor), float(beam.rel_floor),
            float(beam.z_floor), *beam.caps)


def db_graph(mem: SequenceMemory, db: sp.csr_matrix, backward: bool = True) -> dict:
    """What the beam kernel reads, for a learned memory and its database codes.

    ``backward``: also the reversed connections (``"bwd"``) that a backward pass relaxes.
    """
    v = mem.view()
    n_cells = max(v.n_cells, db.shape[1], 1)
    relevant = np.zeros(n_cells, bool)
    relevant[db.indices] = True
    relevant[v.e_src] = True
    relevant[v.e_dst] = True
    coo = db.tocoo()
    c_head, c_next, c_frame = linked_lists(coo.col, coo.row, n_cells)
    return {"bit_cols": v.bit_cols, "bit_len": v.bit_len, "col_size": v.column_sizes.astype(np.float64),
            "cpc": v.cells_per_column, "n_cells": n_cells, "n_cols": max(v.n_columns, 1),
            "fwd": grouped_lists(v.e_src, v.e_dst, n_cells),
            "bwd": grouped_lists(v.e_dst, v.e_src, n_cells) if backward else None,
            "c_head": c_head, "c_next": c_next, "c_frame": c_frame, "relevant": relevant,
            "birth": np.zeros(n_cells, np.int64), "db_norm": np.maximum(np.diff(db.indptr), 1).astype(np.float64),
            "n_db": db.shape[0]}


class Beam:
    """State and scratch arrays of :func:`vpr.shosm.kernels.beam.beam_frames` for one direction."""

    def __init__(self, n_cells, n_cols, n_db):
        self.st = np.zeros(KB.BEAM_STATE_SIZE, np.int64)
        self.beam = np.zeros(n_cells, np.int64)
        self.beam_e = np.zeros(n_cells, np.float64)
        self.e_cur = np.zeros(n_cells, np.float64)
        self.p1 = np.zeros(n_cells, np.float64)
        self.p2 = np.zeros(n_cells, np.float64)
        self.z = np.zeros(n_cells, np.float64)
        self.mark = np.zeros(n_cells, bool)
        self.cand = np.zeros(n_cells, np.int64)
        self.e_new = np.zeros(n_cells, np.float64)
        self.counts = np.zeros(n_cols, np.float64)
        self.touched_cols = np.zeros(n_cols, np.int64)
        self.acc = np.zeros(n_db, np.float64)
        self.db_mark = np.zeros(n_db, bool)
        self.db_touch = np.zeros(n_db, np.int64)
        self.out_idx = np.zeros(4096, np.int64)
        self.out_val = np.zeros(4096, np.float64)
        self.gmax, self.gmark, self.gtouch = np.zeros(0), np.zeros(0, bool), np.zeros(0, np.int64)

    @property
    def size(self) -> int:
        """Cells in the beam now."""
        return int(self.st[KB.B_SIZE])

    @property
    def largest(self) -> tuple[int, int]:
        """(largest beam, largest candidate set) of any frame so far (to check the caps)."""
        return int(self.st[KB.B_MAX_BEAM]), int(self.st[KB.B_MAX_CAND])

    def grow(self, n_cells, n_cols, n_db):
        """Make room for a memory / database that has grown (online learning)."""
        def g(a, n):
            if a.size >= n:
                return a
            out = np.zeros(max(n, 2 * a.size), a.dtype)
            out[: a.size] = a
            return out

        for name in ("beam", "beam_e", "e_cur", "p1", "p2", "z", "mark", "cand", "e_new"):
            setattr(self, name, g(getattr(self, name), n_cells))
        self.counts, self.touched_cols = g(self.counts, n_cols), g(self.touched_cols, n_cols)
        self.acc, self.db_mark, self.db_touch = g(self.acc, n_db), g(self.db_mark, n_db), g(self.db_touch, n_db)

    def cells(self) -> tuple[np.ndarray, np.ndarray]:
        """(cells, evidence) of the beam now (copies)."""
        n = self.size
        return self.beam[:n].copy(), self.beam_e[:n].copy()

    def set_beam(self, cells, values):
        """Replace the beam (e.g. a saved state)."""
        self.e_cur[self.beam[: self.size]] = 0.0
        n = len(cells)
        self.beam[:n], self.beam_e[:n] = cells, values
        self.e_cur[cells] = values
        self.st[KB.B_SIZE] = n

    def run(self, g, adj, q_ptr, q_ind, order, limits, params):
        """Run frames ``order``; return their sparse columns (ptr, idx, val).

        ``adj``: (head, next, dst) per cell, or (head, next, dst, group) per group of cells
        (:func:`grouped_lists`).
        """
        grp = adj[3] if len(adj) == 4 else np.zeros(0, np.int64)
        if grp.size and self.gmax.size < adj[0].size:
            self.gmax, self.gmark = np.zeros(adj[0].size), np.zeros(adj[0].size, bool)
            self.gtouch = np.zeros(adj[0].size, np.int64)
        n = order.size
        out_ptr = np.zeros(n + 1, np.int64)
        st = self.st
        st[KB.B_OUT_POS] = 0
        st[KB.B_FRAMES] = 0
        while True:
            done = KB.beam_frames(q_ptr, q_ind, order, limits, g["bit_cols"], g["bit_len"], g["col_size"], g["cpc"],
                                  adj[0], adj[1], adj[2], grp, g["c_head"], g["c_next"], g["c_frame"], g["relevant"],
                                  g["birth"], g["db_norm"], *params, st, self.beam, self.beam_e, self.e_cur,
                                  self.counts, self.touched_cols, self.p1, self.p2, self.z, self.mark, self.cand,
                                  self.e_new, self.gmax, self.gmark, self.gtouch, self.acc, self.db_mark,
                                  self.db_touch, out_ptr, self.out_idx, self.out_val)
            if done >= n:
                break
            size = max(int(st[KB.B_NEED]), 2 * self.out_idx.size)
            self.out_idx = np.resize(self.out_idx, size)
            self.out_val = np.resize(self.out_val, size)
        end = out_ptr[-1]
        return out_ptr, self.out_idx[:end].copy(), self.out_val[:end].copy()


def reverse_columns(ptr, idx, val):
    """Sparse columns given in reverse query order, put back in order."""
    lens = np.diff(ptr)[::-1]
    starts = ptr[:-1][::-1]
    take = np.concatenate([np.arange(s, s + n) for s, n in zip(starts, lens, strict=True)]) if lens.sum() else \
        np.zeros(0, np.int64)
    return np.r_[0, np.cumsum(lens)].astype(np.int64), idx[take], val[take]


def finish(a, b, n_db_per_q, n_rows, top_k, normalise: bool):
    """Columns of one or two passes (``b`` empty: one) summed, standardised and cut to ``top_k``.

    Returns (similarity csr n_rows x n_q float32, best row per query, its score, mean, sd).
    """
    acc = np.zeros(max(n_rows, 1), np.float64)
    mark = np.zeros(max(n_rows, 1), bool)
    touch = np.zeros(max(n_rows, 1), np.int64)
    ptr, idx, val, best, score, mean, sd = KE.finish_columns(a[0], a[1], a[2], b[0], b[1], b[2], n_db_per_q,
                                                             0 if top_k is None else int(top_k), normalise,
                                                             acc, mark, touch)
    S = sp.csc_matrix((val, idx, ptr), shape=(n_rows, ptr.size - 1)).tocsr()
    S.sort_indices()
    return S, best, score, mean, sd


#: A second pass that holds nothing (one direction).
NO_PASS = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
