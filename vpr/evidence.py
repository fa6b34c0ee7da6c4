"""Graded sequence evidence of rSHOSM-seq: dense, sparse (top-K), streaming and loop closure.

**Our extension, not the paper's.** A database traverse is learned with
Algorithm 1 (:class:`vpr.memory.SequenceMemory`); a query frame is then scored
with graded evidence instead of binary winner cells: a cell's evidence is the
feed-forward overlap fraction ``z`` of its minicolumn with the query SDR plus
``decay`` times the best evidence of a cell that predicted it at the previous
query frame (plus a repeated, ``stay``, or skipped, ``skip``, database frame at
a cost). The similarity of database frame ``j`` and query frame ``q`` is the
mean evidence of ``j``'s winner cells, standardised per query.

* :func:`dense_evidence`: every cell every frame, dense n_db x n_q (what
  :meth:`SequenceMemory.evidence` returns).
* :func:`sparse_evidence`: only the cells above a floor are carried (a beam
  entered through the inverted index input bit -> minicolumns and through the
  learned connections, capped in size so that SDRs sharing many bits do not
  make it grow with the database); top-K database frames per query as a sparse matrix,
  with the z-scores of the full column (its mean and standard deviation come
  from the carried entries: absent ones are 0). For 50,000 x 50,000 frames.
* :class:`ForwardEvidence`: the causal (forward) evidence one query frame at a
  time, with a saveable state; equal to the batch forward run.
* :func:`loop_evidence`: loop closure within one stream, learned online; each
  frame is scored against the frames at least ``exclude`` back with forward
  evidence over what was learned then.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from vpr import _evidence_kernel as K
from vpr import sdr as _sdr
from vpr._checks import check_count

__all__ = ["dense_evidence", "sparse_evidence", "EvidenceResult", "ForwardEvidence", "FrameEvidence",
           "loop_evidence", "accept_loops", "stationary_closures", "BEAM_DEFAULTS", "LOOP_UNCAPPED_MAX"]

#: Floors of the sparse beam (see :func:`sparse_evidence`).
BEAM_DEFAULTS = {"floor": 0.0, "rel_floor": 0.1, "z_floor": 0.15, "max_beam": 8192, "max_enter": 256}

#: Streams up to this many frames are scored by :func:`loop_evidence` without beam caps (``"auto"``):
#: 7,152 Nordland frames take 3.3 GB and 214 s, 10,000 synthetic ones 5.1 GB and 198 s; beyond, time and
#: memory grow too fast (``benchmarks/bench_loops_scale.py``).
LOOP_UNCAPPED_MAX = 10_000

_BIG = np.iinfo(np.int64).max // 4


def _memory_arrays(mem) -> dict:
    """The only place that reads a memory's private arrays (to become ``mem.connections`` at merge).

    Returns the inverted index input bit -> minicolumns (``bit_cols`` rows of
    ``bit_len``), the lateral connections in the order they were learned
    (``e_src``, ``e_dst``: append-only, which :func:`loop_evidence` relies on to
    follow an online memory incrementally) and the sizes.
    """
    ne = mem.n_connections
    return {"bit_cols": mem._bit_cols, "bit_len": mem._bit_len, "e_src": mem._e_src[:ne], "e_dst": mem._e_dst[:ne],
            "n_columns": mem.n_columns, "cpc": mem.cells_per_column}


def _check_params(decay, stay, skip, direction=None):
    if not 0.0 <= float(decay) < 1.0:
        raise ValueError(f"decay must be in [0, 1), got {decay}")
    for name, v in (("stay", stay), ("skip", skip)):
        if v is not None and not float(v) >= 0.0:
            raise ValueError(f"{name} must be >= 0 or None, got {v}")
    if direction is not None and direction not in ("both", "forward"):
        raise ValueError(f"direction must be 'both' or 'forward', got {direction!r}")
    return (-1.0 if stay is None else float(stay)), (-1.0 if skip is None else float(skip))


def _check_codes(mem, db_codes) -> sp.csr_matrix:
    if not sp.issparse(db_codes) or db_codes.ndim != 2:
        raise ValueError("db_codes must be a sparse winner-code matrix (database frames x cells)")
    db = sp.csr_matrix(db_codes)
    if db.shape[1] > mem.n_cells and db[:, mem.n_cells:].nnz:
        raise ValueError(f"db_codes use cells beyond this memory's {mem.n_cells}: codes of another memory?")
    return db


def dense_evidence(mem, query_batch, db_codes, decay: float = 0.9, stay: float | None = 0.05,
                   skip: float | None = 0.05, direction: str = "both", progress: bool = False,
                   clamp: bool = False) -> np.ndarray:
    """Graded sequence evidence of every query frame for every database frame (dense).

    See :meth:`vpr.memory.SequenceMemory.evidence` (which calls this) for the
    parameters. ``clamp=True`` floors the predicted term at 0, the semantics of
    :func:`sparse_evidence` (for tests).

    Returns
    -------
    ndarray, float32, n_db x n_q (higher = more similar).
    """
    st, sk = _check_params(decay, stay, skip, direction)
    q = _sdr.check_batch(query_batch, n_bits=mem.n_inputs, name="query SDR batch")
    db = _check_codes(mem, db_codes)
    arr = _memory_arrays(mem)
    cpc = arr["cpc"]
    src, dst = arr["e_src"], arr["e_dst"]
    # only cells in database codes or on a connection can carry evidence to the output
    rel = np.unique(np.concatenate([db.indices.astype(np.int64), src, dst]))
    remap = lambda a: np.searchsorted(rel, a).astype(np.int64)  # noqa: E731
    db_ind = remap(db.indices.astype(np.int64))
    db_ptr = db.indptr.astype(np.int64)
    db_norm = np.diff(db_ptr).astype(np.float64)
    rs, rd = remap(src), remap(dst)
    col_size = mem.column_sizes().astype(np.float64)
    n_db, n_q = db.shape[0], q.shape[0]
    out = np.zeros((n_db, n_q), dtype=np.float32)
    passes = [(np.arange(n_q), rs, rd, 0.5 if direction == "both" else 0.0)]
    if direction == "both":
        passes.append((np.arange(n_q)[::-1].copy(), rd, rs, 0.5))
    q_ptr, q_ind = q.indptr.astype(np.int64), q.indices.astype(np.int64)
    bar = None
    if progress:
        from tqdm import tqdm  # optional, only for the progress bar

        bar = tqdm(total=n_q * len(passes), desc="rSHOSM evidence", unit="frame", leave=False)
    chunk = 256 if progress else n_q
    for order, a, b, zw in passes:
        e = np.zeros(rel.size, np.float64)
        for f0 in range(0, n_q, chunk):
            K.evidence_frames(q_ptr, q_ind, order[f0:f0 + chunk], arr["bit_cols"], arr["bit_len"], col_size,
                              rel // cpc, a, b, db_ptr, db_ind, db_norm, float(decay), st, sk, zw, out, e,
                              f0 == 0, clamp)
            if bar is not None:
                bar.update(min(chunk, n_q - f0))
    if bar is not None:
        bar.close()
    return out


# ---------------------------------------------------------------- sparse beam
def _lists(keys, vals, n_heads):
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


class _Beam:
    """State and scratch arrays of :func:`vpr._evidence_kernel.beam_frames` for one direction."""

    def __init__(self, n_cells, n_cols, n_db):
        self.st = np.zeros(K.BEAM_STATE_SIZE, np.int64)
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

    def set_beam(self, cells, values):
        self.e_cur[self.beam[: self.st[K.B_SIZE]]] = 0.0
        n = len(cells)
        self.beam[:n], self.beam_e[:n] = cells, values
        self.e_cur[cells] = values
        self.st[K.B_SIZE] = n

    def run(self, g, adj, q_ptr, q_ind, order, limits, params):
        """Run frames ``order``; return their sparse columns (ptr, idx, val)."""
        n = order.size
        out_ptr = np.zeros(n + 1, np.int64)
        st = self.st
        st[K.B_OUT_POS] = 0
        st[K.B_FRAMES] = 0
        while True:
            done = K.beam_frames(q_ptr, q_ind, order, limits, g["bit_cols"], g["bit_len"], g["col_size"], g["cpc"],
                                 adj[0], adj[1], adj[2], g["c_head"], g["c_next"], g["c_frame"], g["relevant"],
                                 g["birth"], g["db_norm"], *params, st, self.beam, self.beam_e, self.e_cur,
                                 self.counts, self.touched_cols, self.p1, self.p2, self.z, self.mark, self.cand,
                                 self.e_new, self.acc, self.db_mark, self.db_touch, out_ptr, self.out_idx,
                                 self.out_val)
            if done >= n:
                break
            size = max(int(st[K.B_NEED]), 2 * self.out_idx.size)
            self.out_idx = np.resize(self.out_idx, size)
            self.out_val = np.resize(self.out_val, size)
        end = out_ptr[-1]
        return out_ptr, self.out_idx[:end].copy(), self.out_val[:end].copy()


def _beam_params(decay, stay, skip, z_weight, floor, rel_floor, z_floor, max_beam=None, max_enter=None):
    for name, v in (("floor", floor), ("rel_floor", rel_floor), ("z_floor", z_floor)):
        if not float(v) >= 0.0:
            raise ValueError(f"{name} must be >= 0, got {v}")
    if float(rel_floor) >= 1.0:
        raise ValueError(f"rel_floor must be < 1, got {rel_floor}")
    caps = []
    for name, v in (("max_beam", max_beam), ("max_enter", max_enter)):
        if v is not None and (int(v) != v or int(v) < 1):
            raise ValueError(f"{name} must be an int >= 1 or None (no cap), got {v}")
        caps.append(0 if v is None else int(v))
    return (float(decay), stay, skip, float(z_weight), float(floor), float(rel_floor), float(z_floor), *caps)


def _db_graph(mem, db) -> dict:
    """What the beam kernel reads, for a learned memory and its database codes."""
    arr = _memory_arrays(mem)
    n_cells = max(mem.n_cells, db.shape[1], 1)
    src, dst = arr["e_src"], arr["e_dst"]
    relevant = np.zeros(n_cells, bool)
    relevant[db.indices] = True
    relevant[src] = True
    relevant[dst] = True
    coo = db.tocoo()
    c_head, c_next, c_frame = _lists(coo.col, coo.row, n_cells)
    return {"bit_cols": arr["bit_cols"], "bit_len": arr["bit_len"],
            "col_size": mem.column_sizes().astype(np.float64), "cpc": arr["cpc"], "n_cells": n_cells,
            "n_cols": max(mem.n_columns, 1), "fwd": _lists(src, dst, n_cells), "bwd": _lists(dst, src, n_cells),
            "c_head": c_head, "c_next": c_next, "c_frame": c_frame, "relevant": relevant,
            "birth": np.zeros(n_cells, np.int64), "db_norm": np.maximum(np.diff(db.indptr), 1).astype(np.float64),
            "n_db": db.shape[0]}


@dataclass
class EvidenceResult:
    """Top-K sparse evidence: ``similarity`` (n_db x n_q csr, z-scores), best database frame and score per query.

    ``best_db`` is -1 (score -inf) for a query frame that no database frame has evidence for.
    """

    similarity: sp.csr_matrix
    best_db: np.ndarray
    score: np.ndarray


def sparse_evidence(mem, query_batch, db_codes, decay: float = 0.9, stay: float | None = 0.05,
                    skip: float | None = 0.05, direction: str = "both", top_k: int | None = 50,
                    normalise: str = "query", floor: float = BEAM_DEFAULTS["floor"],
                    rel_floor: float = BEAM_DEFAULTS["rel_floor"], z_floor: float = BEAM_DEFAULTS["z_floor"],
                    max_beam: int | None = BEAM_DEFAULTS["max_beam"],
                    max_enter: int | None = BEAM_DEFAULTS["max_enter"], progress: bool = False,
                    stats: dict | None = None) -> EvidenceResult:
    """Graded sequence evidence carried only where it is; the top-K database frames per query.

    The same evidence as :func:`dense_evidence`, but per query frame only the
    cells whose evidence is above ``max(floor, rel_floor * largest)`` are
    carried (a beam), and a minicolumn's cells enter by feed-forward only when
    its overlap fraction is above ``z_floor`` (found through the memory's
    inverted index, so the cost per frame follows the beam, not the database).
    A cell outside the beam has evidence 0 (evidence is never negative here; the
    dense version lets a cell that nothing predicts drift below 0). With all
    floors 0 the result equals ``dense_evidence(..., clamp=True)``.

    Parameters
    ----------
    mem, query_batch, db_codes, decay, stay, skip, direction
        As :func:`dense_evidence`.
    top_k : int or None
        Database frames kept per query (None: all that have evidence).
    normalise : {"query", "none"}
        ``"query"``: z-scores per query over **all** database frames, exactly
        as the dense column would be standardised (the mean and standard
        deviation are sums over the carried entries; absent frames are 0).
    floor, rel_floor, z_floor : float
        The beam's floors (defaults :data:`BEAM_DEFAULTS`).
    max_beam, max_enter : int or None
        Caps (None: none) that bound the cost per query frame whatever the
        SDRs share: at most ``max_beam`` cells stay in the beam (those of
        largest evidence) and at most ``max_enter`` minicolumns enter by
        feed-forward (those of largest overlap above ``z_floor``). Defaults
        :data:`BEAM_DEFAULTS`.
    progress : bool
        tqdm progress bar.
    stats : dict, optional
        Filled with ``max_beam`` and ``max_candidates``: the largest beam and
        candidate set of any frame (to check the caps).

    Returns
    -------
    EvidenceResult (similarity: csr n_db x n_q float32).
    """
    st, sk = _check_params(decay, stay, skip, direction)
    if normalise not in ("query", "none"):
        raise ValueError(f"normalise must be 'query' or 'none', got {normalise!r}")
    if top_k is not None and int(top_k) < 1:
        raise ValueError(f"top_k must be >= 1 or None, got {top_k}")
    q = _sdr.check_batch(query_batch, n_bits=mem.n_inputs, name="query SDR batch")
    db = _check_codes(mem, db_codes)
    g = _db_graph(mem, db)
    n_q, n_db = q.shape[0], db.shape[0]
    q_ptr, q_ind = q.indptr.astype(np.int64), q.indices.astype(np.int64)
    zw = 0.5 if direction == "both" else 0.0
    params = _beam_params(decay, st, sk, zw, floor, rel_floor, z_floor, max_beam, max_enter)
    limits = np.full(n_q, _BIG, np.int64)
    seen = {"max_beam": 0, "max_candidates": 0}
    cols = []
    bar = None
    if progress:
        from tqdm import tqdm  # optional, only for the progress bar

        bar = tqdm(total=n_q * (2 if direction == "both" else 1), desc="rSHOSM evidence", unit="frame", leave=False)
    passes = [("fwd", np.arange(n_q, dtype=np.int64))]
    if direction == "both":
        passes.append(("bwd", np.arange(n_q, dtype=np.int64)[::-1].copy()))
    chunk = 2048
    for adj_name, order in passes:
        beam = _Beam(g["n_cells"], g["n_cols"], n_db)
        ptrs, idxs, vals = [np.zeros(1, np.int64)], [], []
        base = 0
        for f0 in range(0, n_q, chunk):
            p, i, v = beam.run(g, g[adj_name], q_ptr, q_ind, order[f0:f0 + chunk], limits[f0:f0 + chunk], params)
            ptrs.append(p[1:] + base)
            idxs.append(i)
            vals.append(v)
            base += i.size
            if bar is not None:
                bar.update(p.size - 1)
        ptr, idx, val = np.concatenate(ptrs), np.concatenate(idxs), np.concatenate(vals)
        if adj_name == "bwd":  # columns came in reverse query order
            ptr, idx, val = _reverse_columns(ptr, idx, val)
        cols.append((ptr, idx, val))
        seen["max_beam"] = max(seen["max_beam"], int(beam.st[K.B_MAX_BEAM]))
        seen["max_candidates"] = max(seen["max_candidates"], int(beam.st[K.B_MAX_CAND]))
        del beam
    if stats is not None:
        stats.update(seen)
    if bar is not None:
        bar.close()
    b = cols[1] if len(cols) == 2 else (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    return _finish(cols[0], b, np.full(n_q, n_db, np.int64), n_db, top_k, normalise == "query", n_db)


def _reverse_columns(ptr, idx, val):
    lens = np.diff(ptr)[::-1]
    starts = ptr[:-1][::-1]
    take = np.concatenate([np.arange(s, s + n) for s, n in zip(starts, lens, strict=True)]) if lens.sum() else \
        np.zeros(0, np.int64)
    return np.r_[0, np.cumsum(lens)].astype(np.int64), idx[take], val[take]


def _finish(a, b, n_db_per_q, n_db, top_k, normalise, n_rows) -> EvidenceResult:
    acc = np.zeros(n_rows, np.float64)
    mark = np.zeros(n_rows, bool)
    touch = np.zeros(n_rows, np.int64)
    ptr, idx, val, best, score, _, _ = K.finish_columns(a[0], a[1], a[2], b[0], b[1], b[2], n_db_per_q,
                                                        0 if top_k is None else int(top_k), normalise,
                                                        acc, mark, touch)
    n_q = ptr.size - 1
    S = sp.csc_matrix((val, idx, ptr), shape=(n_rows, n_q)).tocsr()
    S.sort_indices()
    return EvidenceResult(S, best, score)


# ---------------------------------------------------------------- streaming
@dataclass
class FrameEvidence:
    """Evidence of one query frame: the best database frame, its score, and the kept database frames.

    ``db_idx`` are the top-K database frames by score (all frames, in index
    order, when ``top_k`` is None) and ``scores`` their z-scores. ``best_db`` is
    -1 (score -inf) when no database frame has any evidence.
    """

    best_db: int
    score: float
    db_idx: np.ndarray
    scores: np.ndarray


def _row_bits(sdr_row, n_inputs) -> np.ndarray:
    """Active bit indices of one SDR row (1-row batch, dense bool vector or index array)."""
    if sp.issparse(sdr_row):
        b = _sdr.check_batch(sdr_row, n_bits=n_inputs, name="query SDR")
        if b.shape[0] != 1:
            raise ValueError(f"update() takes one SDR row, got {b.shape[0]} rows")
        return np.sort(b.indices.astype(np.int64))
    a = np.asarray(sdr_row)
    if a.dtype == bool:
        if a.ndim != 1 or a.size != n_inputs:
            raise ValueError(f"query SDR has shape {a.shape}, memory expects ({n_inputs},)")
        return np.flatnonzero(a).astype(np.int64)
    a = np.unique(a.astype(np.int64).ravel())
    if a.size and (a[0] < 0 or a[-1] >= n_inputs):
        raise ValueError(f"query SDR bit indices must be in [0, {n_inputs}), got {a[0]}..{a[-1]}")
    return a


class ForwardEvidence:
    """Causal (forward) rSHOSM-seq evidence of a query stream, one frame at a time.

    Cost per frame does not grow with the number of query frames seen: the
    state is the evidence of the last frame (the beam, or with ``exact=True``
    every relevant cell). Answers equal the batch ``direction="forward"`` run
    on the same frames: :func:`sparse_evidence` (default) or, with
    ``exact=True``, :func:`dense_evidence` standardised per query.
    The memory is read, never changed.

    Parameters
    ----------
    mem : SequenceMemory
        The memory that learned the database.
    db_codes : csr matrix (n_db x cells)
        Winner codes of the database traverse from ``mem.run``.
    decay, stay, skip : as :func:`dense_evidence`.
    top_k : int or None
        Database frames reported per query frame (None: all).
    normalise : {"query", "none"}
        z-scores over all database frames, as the batch version.
    exact : bool
        Dense evidence (cost per frame linear in the number of connections)
        instead of the beam.
    floor, rel_floor, z_floor, max_beam, max_enter : the beam's floors and caps (:func:`sparse_evidence`).
    """

    def __init__(self, mem, db_codes, decay: float = 0.9, stay: float | None = 0.05, skip: float | None = 0.05,
                 top_k: int | None = 50, normalise: str = "query", exact: bool = False,
                 floor: float = BEAM_DEFAULTS["floor"], rel_floor: float = BEAM_DEFAULTS["rel_floor"],
                 z_floor: float = BEAM_DEFAULTS["z_floor"], max_beam: int | None = BEAM_DEFAULTS["max_beam"],
                 max_enter: int | None = BEAM_DEFAULTS["max_enter"]):
        st, sk = _check_params(decay, stay, skip)
        if normalise not in ("query", "none"):
            raise ValueError(f"normalise must be 'query' or 'none', got {normalise!r}")
        if top_k is not None and int(top_k) < 1:
            raise ValueError(f"top_k must be >= 1 or None, got {top_k}")
        self.mem = mem
        self.db = _check_codes(mem, db_codes)
        self.n_db = self.db.shape[0]
        self.conf = {"decay": float(decay), "stay": stay, "skip": skip, "top_k": top_k, "normalise": normalise,
                     "exact": bool(exact), "floor": float(floor), "rel_floor": float(rel_floor),
                     "z_floor": float(z_floor), "max_beam": max_beam, "max_enter": max_enter}
        self.frames = 0
        self._acc = np.zeros(self.n_db, np.float64)
        self._mark = np.zeros(self.n_db, bool)
        self._touch = np.zeros(self.n_db, np.int64)
        if exact:
            arr = _memory_arrays(mem)
            src, dst = arr["e_src"], arr["e_dst"]
            rel = np.unique(np.concatenate([self.db.indices.astype(np.int64), src, dst]))
            self._rel = rel
            self._dense = (arr["bit_cols"], arr["bit_len"], mem.column_sizes().astype(np.float64),
                           rel // arr["cpc"], np.searchsorted(rel, src).astype(np.int64),
                           np.searchsorted(rel, dst).astype(np.int64), self.db.indptr.astype(np.int64),
                           np.searchsorted(rel, self.db.indices.astype(np.int64)).astype(np.int64),
                           np.diff(self.db.indptr).astype(np.float64))
            self._e = np.zeros(rel.size, np.float64)
            self._out = np.zeros((self.n_db, 1), np.float32)
            self._params = (float(decay), st, sk)
        else:
            self._g = _db_graph(mem, self.db)
            self._beam = _Beam(self._g["n_cells"], self._g["n_cols"], self.n_db)
            self._params = _beam_params(decay, st, sk, 0.0, floor, rel_floor, z_floor, max_beam, max_enter)

    def update(self, sdr_row) -> FrameEvidence:
        """Score one query frame (SDR row: 1-row batch, bool vector or bit indices)."""
        bits = _row_bits(sdr_row, self.mem.n_inputs)
        q_ptr = np.array([0, bits.size], np.int64)
        order = np.zeros(1, np.int64)
        if self.conf["exact"]:
            self._out[:] = 0.0
            K.evidence_frames(q_ptr, bits, order, *self._dense[:7], self._dense[7], self._dense[8],
                              *self._params, 0.0, self._out, self._e, self.frames == 0)
            col = self._out[:, 0]
            nz = np.flatnonzero(col)
            a = (np.array([0, nz.size], np.int64), nz.astype(np.int64), col[nz].astype(np.float64))
        else:
            a = self._beam.run(self._g, self._g["fwd"], q_ptr, bits, order, np.full(1, _BIG, np.int64), self._params)
        self.frames += 1
        return self._frame(a)

    def _frame(self, a) -> FrameEvidence:
        top_k = self.conf["top_k"]
        empty = np.zeros(0, np.int64)
        ptr, idx, val, best, score, mean, sd = K.finish_columns(
            a[0], a[1], a[2], empty, empty, np.zeros(0), np.full(1, self.n_db, np.int64),
            0 if top_k is None else int(top_k), self.conf["normalise"] == "query", self._acc, self._mark, self._touch)
        if top_k is None:
            scores = np.full(self.n_db, -mean[0] / sd[0], np.float64)
            scores[idx] = val
            if best[0] < 0 and self.n_db:  # no evidence anywhere: all equal, argmax's answer
                best[0], score[0] = 0, scores[0]
            return FrameEvidence(int(best[0]), float(score[0]), np.arange(self.n_db), scores)
        return FrameEvidence(int(best[0]), float(score[0]), idx.copy(), val.astype(np.float64))

    # ------------------------------------------------------------- state
    def state_dict(self) -> dict:
        """The state after the frames seen so far, as arrays (save with ``np.savez``)."""
        out = {"frames": np.array(self.frames, np.int64)}
        if self.conf["exact"]:
            out["rel"] = self._rel.copy()
            out["e"] = self._e.copy()
        else:
            n = int(self._beam.st[K.B_SIZE])
            out["beam_cells"] = self._beam.beam[:n].copy()
            out["beam_e"] = self._beam.beam_e[:n].copy()
        return out

    def load_state(self, state: dict) -> ForwardEvidence:
        """Continue from a :meth:`state_dict` of an object built on the same memory and database."""
        self.frames = int(state["frames"])
        if self.conf["exact"]:
            if "e" not in state or not np.array_equal(state["rel"], self._rel):
                raise ValueError("state is not from an exact ForwardEvidence on this memory and database")
            self._e[:] = state["e"]
        else:
            if "beam_cells" not in state:
                raise ValueError("state is not from a beam ForwardEvidence (exact=False)")
            cells = np.asarray(state["beam_cells"], np.int64)
            if cells.size and (cells.min() < 0 or cells.max() >= self._g["n_cells"]):
                raise ValueError("state has beam cells outside this memory: another memory's state?")
            self._beam.set_beam(cells, np.asarray(state["beam_e"], np.float64))
        return self

    @classmethod
    def from_state(cls, mem, db_codes, state: dict, **conf) -> ForwardEvidence:
        """A new object on ``mem`` and ``db_codes`` (with ``conf``) continuing from ``state``."""
        return cls(mem, db_codes, **conf).load_state(state)


# ---------------------------------------------------------------- loop closure
def _grown(a, size, fill):
    out = np.full(size, fill, a.dtype)
    out[: a.size] = a
    return out


def loop_evidence(sdr_batch, exclude: int = 30, decay: float = 0.9, stay: float | None = 0.05,
                  skip: float | None = 0.05, top_k: int | None = None, normalise: str = "query",
                  memory: dict | None = None, floor: float = BEAM_DEFAULTS["floor"],
                  rel_floor: float = BEAM_DEFAULTS["rel_floor"], z_floor: float = BEAM_DEFAULTS["z_floor"],
                  max_beam: int | None | str = "auto", max_enter: int | None | str = "auto",
                  dense_max: int = 20_000, progress: bool = False):
    """Loop closure within one stream with graded forward sequence evidence, learned online.

    Frame ``j`` is learned with Algorithm 1 (as the paper, one memory over the
    stream) and then scored against the frames ``i <= j - exclude`` with the
    forward (causal) evidence of :func:`sparse_evidence`: only the past counts.
    Cells first learned at a frame after ``j - exclude`` take no part in the
    evidence at ``j`` at all (not only masked in the output): within one
    traverse a frame's own evidence would otherwise linger, through the stay
    transition, on the frames just before it and win there.

    Parameters
    ----------
    sdr_batch : SDR batch (T x n_inputs), the stream.
    exclude : int >= 1
        Frames closer than this are not candidates.
    decay, stay, skip, floor, rel_floor, z_floor : as :func:`sparse_evidence`.
    max_beam, max_enter : int, None or "auto"
        Caps of the beam, as :func:`sparse_evidence`. ``"auto"``: none up to
        :data:`LOOP_UNCAPPED_MAX` frames (and while the output is dense),
        :data:`BEAM_DEFAULTS` beyond. Why: in one stream that changes condition, the frames of the
        current condition fill a capped beam and the other condition's frames
        of the same place never enter it (Nordland summer + winter, all 7,152
        frames: loop AP 0.000 capped, 0.409 without caps; ``docs/localize.md``).
    top_k : int or None
        Earlier frames kept per frame (None: dense T x T up to ``dense_max``
        frames, top-50 beyond).
    normalise : {"query", "none"}
        z-scores per frame over its candidate frames.
    memory : dict, optional
        :class:`vpr.memory.SequenceMemory` parameters (default: those of
        ``rshosm-seq``, threshold 0.75).
    progress : bool
        tqdm progress bar.

    Returns
    -------
    S : T x T (rows: earlier frame i, columns: frame j); dense float32 with
        ``-inf`` outside ``i <= j - exclude``, or a top-K csr matrix.
    codes : csr bool (T x cells), the winner codes learned online.
    """
    from vpr.memory import SequenceMemory  # vpr.memory imports this module lazily; no cycle at import time

    st, sk = _check_params(decay, stay, skip)
    if int(exclude) < 1:
        raise ValueError(f"exclude must be >= 1, got {exclude}")
    if normalise not in ("query", "none"):
        raise ValueError(f"normalise must be 'query' or 'none', got {normalise!r}")
    if top_k is not None and int(top_k) < 1:
        raise ValueError(f"top_k must be >= 1 or None, got {top_k}")
    exclude = int(exclude)
    mem = SequenceMemory(**{"threshold": 0.75, **(memory or {})})
    x = _sdr.check_batch(sdr_batch, n_bits=mem.n_inputs, name="stream SDR batch")
    T = x.shape[0]
    if top_k is None and T > int(dense_max):
        top_k = 50  # a dense T x T would not fit (the project's limit on dense matrices)
    caps = {}
    for name, value in (("max_beam", max_beam), ("max_enter", max_enter)):
        if isinstance(value, str):
            if value != "auto":
                raise ValueError(f"{name} must be a positive integer, None or 'auto', got {value!r}")
            value = None if T <= min(int(dense_max), LOOP_UNCAPPED_MAX) else BEAM_DEFAULTS[name]
        caps[name] = value
    q_ptr, q_ind = x.indptr.astype(np.int64), x.indices.astype(np.int64)
    params = _beam_params(decay, st, sk, 0.0, floor, rel_floor, z_floor, caps["max_beam"], caps["max_enter"])
    cpc = mem.cells_per_column
    cap = 1024 * cpc
    g = {"cpc": cpc, "n_cells": cap, "col_size": np.zeros(cap // cpc), "relevant": np.zeros(cap, bool),
         "birth": np.full(cap, _BIG, np.int64), "c_head": np.full(cap, -1, np.int64),
         "c_next": np.zeros(16 * T + 16, np.int64), "c_frame": np.zeros(16 * T + 16, np.int64),
         "db_norm": np.ones(max(T, 1), np.float64)}
    a_head, a_next, a_dst = np.full(cap, -1, np.int64), np.zeros(4096, np.int64), np.zeros(4096, np.int64)
    beam = _Beam(cap, cap // cpc, max(T, 1))
    n_nodes = 0
    ptrs, idxs, vals = [np.zeros(1, np.int64)], [], []
    base = 0
    codes_ptr, codes_idx = np.zeros(T + 1, np.int64), []
    bar = None
    if progress:
        from tqdm import tqdm  # optional, only for the progress bar

        bar = tqdm(total=T, desc="rSHOSM loops", unit="frame", leave=False)
    for j in range(T):
        arr = _memory_arrays(mem)
        old_len, ne_old = arr["bit_len"].copy(), mem.n_connections
        w = mem.run(x[j]).indices.astype(np.int64)
        codes_idx.append(w)
        codes_ptr[j + 1] = codes_ptr[j] + w.size
        arr = _memory_arrays(mem)
        n_cells = mem.n_cells
        if n_cells > g["n_cells"]:  # grow everything indexed by cell or minicolumn
            new = max(n_cells, 2 * g["n_cells"])

            for name, fill in (("relevant", False), ("birth", _BIG), ("c_head", -1), ("col_size", 0.0)):
                g[name] = _grown(g[name], new if name != "col_size" else new // cpc, fill)
            a_head = _grown(a_head, new, -1)
            g["n_cells"] = new
            beam.grow(new, new // cpc, max(T, 1))
        K.count_new_entries(g["col_size"], q_ind[q_ptr[j]:q_ptr[j + 1]], old_len, arr["bit_len"], arr["bit_cols"])
        ne = mem.n_connections
        if ne > a_next.size:
            a_next, a_dst = np.resize(a_next, max(ne, 2 * a_next.size)), np.resize(a_dst, max(ne, 2 * a_dst.size))
        K.append_lists(a_head, a_next, a_dst, ne_old, arr["e_src"][ne_old:], arr["e_dst"][ne_old:])
        if n_nodes + w.size > g["c_next"].size:
            g["c_next"] = np.resize(g["c_next"], 2 * (n_nodes + w.size))
            g["c_frame"] = np.resize(g["c_frame"], 2 * (n_nodes + w.size))
        K.append_lists(g["c_head"], g["c_next"], g["c_frame"], n_nodes, w, np.full(w.size, j, np.int64))
        n_nodes += w.size
        g["relevant"][w] = True
        g["birth"][w] = np.minimum(g["birth"][w], j)
        g["db_norm"][j] = max(w.size, 1)
        g["bit_cols"], g["bit_len"] = arr["bit_cols"], arr["bit_len"]
        p, i, v = beam.run(g, (a_head, a_next, a_dst), q_ptr, q_ind, np.array([j], np.int64),
                           np.array([j - exclude], np.int64), params)
        ptrs.append(p[1:] + base)
        idxs.append(i)
        vals.append(v)
        base += i.size
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    codes = sp.csr_matrix((np.ones(int(codes_ptr[-1]), bool), np.concatenate(codes_idx + [np.zeros(0, np.int64)]),
                           codes_ptr), shape=(T, max(mem.n_cells, 1)))
    cols = (np.concatenate(ptrs), np.concatenate(idxs + [np.zeros(0, np.int64)]),
            np.concatenate(vals + [np.zeros(0)]))
    empty = np.zeros(0, np.int64)
    n_cand = np.maximum(np.arange(T) - exclude + 1, 0).astype(np.int64)
    acc, mark, touch = np.zeros(max(T, 1)), np.zeros(max(T, 1), bool), np.zeros(max(T, 1), np.int64)
    ptr, idx, val, _, _, mean, sd = K.finish_columns(cols[0], cols[1], cols[2], empty, empty, np.zeros(0), n_cand,
                                                     0 if top_k is None else int(top_k), normalise == "query",
                                                     acc, mark, touch)
    if top_k is not None:
        S = sp.csc_matrix((val, idx, ptr), shape=(T, T)).tocsr()
        S.sort_indices()
        return S, codes
    S = np.full((T, T), -np.inf, np.float32)
    i, jj = np.indices((T, T))
    valid = i <= jj - exclude
    S[valid] = np.broadcast_to((-mean / sd).astype(np.float32), (T, T))[valid]
    S[idx, np.repeat(np.arange(T), np.diff(ptr))] = val
    return S, codes


#: Steps of the best earlier frame between two frames that still continue one closure: a stop (0),
#: a faster revisit (up to 6 frames per frame) or a small step back where neighbouring frames tie.
_CONTINUES = (-2, 6)


def accept_loops(S, z_min: float = 6.0, confirm: int = 8, sdr=None, stop_ratio: float = 0.35):
    """Best earlier frame per frame of a :func:`loop_evidence` matrix and whether it is accepted.

    A closure at frame ``j`` is accepted when its z-score (how far the best
    earlier frame's evidence stands out from all candidate frames') is at least
    ``z_min`` at ``j`` and at the ``confirm`` frames before it, and the best
    earlier frame moved on consistently over them (as a revisit does: between
    -2 and +6 frames per frame). Causal: only frames up to ``j`` are used.
    With the stream's SDRs (``sdr``), a closure onto a place the camera never
    left is not a loop but a stop, and is refused (:func:`stationary_closures`).

    Why: on forward-only drives a wrong earlier frame can stand out for a few
    frames (a repeated facade, a tunnel), a revisit keeps standing out; and a vehicle
    standing at a station or a traffic light for longer than ``exclude`` sees
    the same place again without any loop (``studies/loops_acceptance.py``,
    ``docs/localize.md``).

    Parameters
    ----------
    S : dense or sparse T x T loop matrix (rows earlier frame, columns frame).
    z_min : float
        z-score the closure must reach at every frame of the confirmation.
    confirm : int >= 0
        Frames before ``j`` that must also pass (0: ``j`` alone).
    sdr : SDR batch (T rows), optional
        The stream; without it stops are not checked.
    stop_ratio : float in [0, 1)
        See :func:`stationary_closures` (0: stops are not checked).

    Returns
    -------
    best : int64 per frame (-1: no candidate), score : float64, accepted : bool
    """
    from vpr.methods import best_matches  # methods imports the memory; only needed here

    confirm = check_count(confirm, "confirm")
    if not 0.0 <= float(stop_ratio) < 1.0:
        raise ValueError(f"stop_ratio must be in [0, 1) (0: stops are not checked), got {stop_ratio}")
    best, score = best_matches(S)
    best = np.where(np.isfinite(score), best, -1)
    ok = (best >= 0) & (score >= float(z_min))
    step = np.diff(best, prepend=-1)
    link = np.zeros_like(ok)  # frame j continues frame j - 1's closure
    link[1:] = ok[1:] & ok[:-1] & (step[1:] >= _CONTINUES[0]) & (step[1:] <= _CONTINUES[1])
    run = np.zeros(len(ok), np.int64)  # frames in a row that pass, ending at j
    for j in np.flatnonzero(ok):
        run[j] = run[j - 1] + 1 if j and link[j] else 1
    ok = run > confirm
    if sdr is not None and float(stop_ratio) > 0:
        ok &= ~stationary_closures(sdr, best, ok, stop_ratio)
    return best, score, ok


def stationary_closures(sdr, best, accepted, ratio: float = 0.35, chunk: int = 256) -> np.ndarray:
    """Which accepted closures ``best[j] -> j`` are onto a place the camera never left.

    A loop closure means the camera went elsewhere and came back: some frame
    between ``i = best[j]`` and ``j`` looks less like ``j`` than ``ratio`` times
    the overlap of ``i`` and ``j`` (SDR overlap, as a fraction of ``j``'s
    bits). When every frame in between keeps at least that much, the vehicle
    stood still or crept (a station, a traffic light) and the "closure" is a
    stop. Measured (``docs/localize.md``): stops on Nordland 0.45-1.0 of the
    match's overlap at the lowest frame in between, revisits and false
    closures on the renders 0.0-0.32.

    Parameters
    ----------
    sdr : SDR batch (T rows), the stream.
    best : int per frame, the closure's earlier frame (-1: none).
    accepted : bool per frame, the closures to check.
    ratio : float in (0, 1)
    chunk : int
        Frames compared at once (the scan stops at the first frame that left).

    Returns
    -------
    bool per frame: accepted and stationary.
    """
    ratio = float(ratio)
    if not 0.0 < ratio < 1.0:
        raise ValueError(f"stop_ratio must be in (0, 1), got {ratio}")
    x = _sdr.check_batch(sdr, name="sdr").astype(np.float32).tocsr()
    best, accepted = np.asarray(best), np.asarray(accepted, bool)
    if len(best) != x.shape[0] or len(accepted) != x.shape[0]:
        raise ValueError(f"best and accepted need one entry per frame of the stream ({x.shape[0]}), "
                         f"got {len(best)} and {len(accepted)}")
    out = np.zeros(x.shape[0], bool)
    for j in np.flatnonzero(accepted & (best >= 0)):
        i = int(best[j])
        xj = x[j].T
        o_i = (x[i] @ xj).toarray()[0, 0]
        left = False
        for a in range(i + 1, j, chunk):
            o = (x[a:min(a + chunk, j)] @ xj).toarray().ravel()
            if np.any(o < ratio * o_i):
                left = True
                break
        out[j] = not left
    return out
