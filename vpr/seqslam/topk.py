"""SeqSLAM beyond a dense matrix: by blocks of queries, top-K per query, exact or around candidate matches."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from vpr import sdr as _sdr
from vpr.checks import check_int, check_top_k
from vpr.similarity import TOP_K, bitsets_pay, mean_abs_diff, overlap_similarity, sdr_candidates, sdr_overlap_rows

from . import kernels as K
from .dense import SeqSlamConf, SeqSLAMResult, check_sequence_params
from .difference import as_descriptors, unit_rows

__all__ = ["seqslam_topk", "SEARCH"]


class _Descriptors:
    """Database and query descriptors with the block difference of :func:`difference_matrix`.

    SDR batches (sparse bool) are never densified: ``|a - b|`` summed over 0/1 rows is ``|a| + |b| - 2 |a & b|``, an
    exact identity, so the SAD of a block costs an overlap count through the queries' inverted index.
    """

    def __init__(self, db_desc, q_desc, metric: str):
        if metric not in ("sad", "cosine"):
            raise ValueError(f"metric: expected 'sad' or 'cosine', got {metric!r}")
        self.metric = metric
        if sp.issparse(db_desc) != sp.issparse(q_desc):
            raise ValueError("q_desc: db_desc and q_desc must both be SDR batches (scipy.sparse) "
                             "or both dense descriptor arrays")
        self.sdr = sp.issparse(db_desc)
        if self.sdr:
            self.a = _sdr.check_batch(db_desc, name="db_desc")
            self.b = _sdr.check_batch(q_desc, n_bits=self.a.shape[1], name="q_desc")
            if self.a.shape[0] == 0 or self.b.shape[0] == 0:
                raise ValueError("db_desc, q_desc: need at least one row each")
            self.na = np.diff(self.a.indptr).astype(np.int64)
            self.nb = np.diff(self.b.indptr).astype(np.int64)
            self.a_indptr = self.a.indptr.astype(np.int64)
            self.a_indices = self.a.indices.astype(np.int64)
        else:
            self.a = as_descriptors(db_desc, "db_desc")
            self.b = as_descriptors(q_desc, "q_desc")
            if self.a.shape[1] != self.b.shape[1]:
                raise ValueError(f"q_desc: descriptor length {self.b.shape[1]} differs from "
                                 f"db_desc's {self.a.shape[1]}")
            if metric == "cosine":
                self.au, self.bu = unit_rows(self.a), unit_rows(self.b)
        self.n_db, self.n_q = self.a.shape[0], self.b.shape[0]
        self._qb_cols = None
        self.dim = self.a.shape[1]

    def block(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """Difference matrix rows r0..r1, columns c0..c1 (float32), as difference_matrix computes it."""
        if not self.sdr:
            if self.metric == "sad":
                return mean_abs_diff(self.a[r0:r1], self.b[c0:c1])
            out = self.au[r0:r1] @ self.bu[c0:c1].T
            np.subtract(np.float32(1.0), out, out=out)
            return np.clip(out, 0.0, 2.0, out=out)
        if self._qb_cols != (c0, c1):            # one inverted index per query block, shared by its windows
            qb = self.b[c0:c1].tocsc()
            self._qb = (qb.indptr.astype(np.int64), qb.indices.astype(np.int64))
            self._qb_cols = (c0, c1)
        ov = np.zeros((r1 - r0, c1 - c0), dtype=np.int64)
        sdr_overlap_rows(self.a_indptr, self.a_indices, r0, r1, self._qb[0], self._qb[1], ov)
        na = self.na[r0:r1, None]
        nb = self.nb[None, c0:c1]
        if self.metric == "sad":
            return ((na + nb - 2 * ov) / self.dim).astype(np.float32)
        denom = np.sqrt((na * nb).astype(np.float64))
        cos = np.divide(ov, denom, out=np.zeros(ov.shape), where=denom > 0)
        return np.clip(1.0 - cos, 0.0, 2.0).astype(np.float32)

    def candidates(self, k: int, stride: int = 1, chunk: int = 512) -> tuple[np.ndarray, np.ndarray]:
        """Single-frame candidates of every ``stride``-th query: its k most similar database rows.

        Returns (ptr, rows) per query column, csc-like; skipped queries have none.
        """
        k = min(k, self.n_db)
        sampled = np.arange(0, self.n_q, stride)
        if self.sdr and bitsets_pay(self.a, self.b, against="index"):
            # the k largest overlaps by popcounts of packed rows, the cheaper way for SDRs that share many bits (ties:
            # a fixed order spread over the database); a row sharing no bit is no candidate
            T = overlap_similarity(self.a, self.b[sampled], top_k=k, normalise=False).tocsc()
            T.eliminate_zeros()
            T.sort_indices()
            n_per = np.zeros(self.n_q, dtype=np.int64)
            n_per[sampled] = np.diff(T.indptr)
            return np.concatenate([[0], np.cumsum(n_per)]).astype(np.int64), T.indices.astype(np.int64)
        if self.sdr:
            post = self.a.tocsc()
            qs = self.b[sampled]
            out = np.full((len(sampled), k), -1, dtype=np.int64)
            counts = np.zeros(self.n_db, dtype=np.uint16 if self.nb.max(initial=0) < 2**16 - 1 else np.int64)
            sdr_candidates(post.indptr.astype(np.int64), post.indices.astype(np.int32),
                            qs.indptr.astype(np.int64), qs.indices.astype(np.int64), k, counts, out)
        else:
            out = np.empty((len(sampled), k), dtype=np.int64)
            for c0 in range(0, len(sampled), chunk):
                idx = sampled[c0:c0 + chunk]
                if self.metric == "sad":
                    D = mean_abs_diff(self.a, self.b[idx])
                else:
                    D = 1.0 - self.au @ self.bu[idx].T
                out[c0:c0 + len(idx)] = np.argpartition(D, k - 1, axis=0)[:k].T if k < self.n_db else \
                    np.arange(self.n_db)
        n_per = np.zeros(self.n_q, dtype=np.int64)
        n_per[sampled] = (out >= 0).sum(axis=1)
        return np.concatenate([[0], np.cumsum(n_per)]).astype(np.int64), out[out >= 0]


def _candidate_pattern(candidates, n_db: int, n_q: int) -> tuple[np.ndarray, np.ndarray]:
    """(ptr, rows) per query column of a caller's candidate matrix (stored / nonzero entries)."""
    if sp.issparse(candidates):
        C = sp.csc_matrix(candidates)
    else:
        a = np.asarray(candidates)
        if a.ndim != 2:
            raise ValueError(f"candidates: expected a (n_db x n_q) matrix, 'pairwise' or None, got {candidates!r}")
        C = sp.csc_matrix(a != 0)
    if C.shape != (n_db, n_q):
        raise ValueError(f"candidates: expected shape {(n_db, n_q)} (database x query), got {C.shape}")
    C.sort_indices()
    return C.indptr.astype(np.int64), C.indices.astype(np.int64)


def _windows(ptr, rows, q0: int, q1: int, n_db: int, n_windows: int, v_min: float, v_max: float,
             margin: int) -> list[tuple[int, int]]:
    """Database row intervals searched for queries q0..q1, voted by the candidates.

    Each candidate (row i, query q) votes for the anchor ``i - (q - q0)``: the block's first query's row if the speed
    were 1. A sequence seen by the block's queries piles its votes into one or two adjacent bins of width ``(w - 1) *
    max speed deviation + 1``, single-frame aliases scatter. The ``n_windows`` best bins (widened by one bin each
    side) become the rows every trajectory anchored there can reach in the block, at any speed in ``[v_min, v_max]``,
    plus ``margin``.
    """
    w = q1 - q0
    lo, hi = ptr[q0], ptr[q1]
    if hi == lo:
        return []
    q_of = np.repeat(np.arange(w), np.diff(ptr[q0:q1 + 1]))
    anchors = rows[lo:hi] - q_of
    dev = max(v_max - 1.0, 1.0 - v_min, 0.0)
    bw = int(np.ceil((w - 1) * dev)) + 1
    bins, votes = np.unique(np.floor_divide(anchors, bw), return_counts=True)
    order = np.lexsort((bins, -votes))[:n_windows]
    below = int(np.ceil((w - 1) * max(0.0, v_max - 1.0))) + margin
    above = int(np.ceil((w - 1) * max(1.0, v_max))) + margin
    iv = sorted(((int(b) - 1) * bw - below, (int(b) + 2) * bw + above) for b in bins[order])
    out: list[tuple[int, int]] = []
    for a, b in iv:
        a, b = max(a, 0), min(b, n_db)
        if a >= b:
            continue
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


#: how :func:`seqslam_topk` searches by default (its ``**params`` beside SeqSLAM's own)
SEARCH = {"block": None, "n_candidates": TOP_K, "candidate_stride": 4, "n_windows": 4}


def seqslam_topk(db_desc, q_desc, top_k: int = TOP_K, metric: str = "sad", candidates=None,
                 conf: SeqSlamConf | None = None, **params) -> SeqSLAMResult:
    """SeqSLAM from descriptors, by blocks of queries, keeping the top-K per query.

    Memory is ``O(searched rows x block)``. ``candidates=None``: every row searched, :func:`seqslam`'s result up to
    float32 rounding; otherwise only row windows around candidate pairs (a db x query matrix, or ``"pairwise"``: the
    ``n_candidates`` best single-frame matches of every ``candidate_stride``-th query), ``n_windows`` alignments per
    block, and ``exact`` says whether they covered every row (``docs/internals.md``). Bad descriptors or parameters
    raise ValueError naming the argument.

    Parameters
    ----------
    db_desc, q_desc : SDR batches (scipy.sparse, bool) or arrays (n, ...)
        Both of one kind; SDRs are compared as dense 0/1 rows, never densified.
    top_k : int
        Database entries kept per query.
    candidates
        See above.
    metric
        As :func:`difference_matrix`.
    conf, params
        SeqSLAM's parameters, as :func:`seqslam` takes them (``enhance=False``: the raw differences), and by name
        the search's (:data:`SEARCH`): ``block`` (queries per block: 256 exact, 64 with candidates),
        ``n_candidates``, ``candidate_stride``, ``n_windows`` (see above).

    Returns
    -------
    SeqSLAMResult
    """
    desc = _Descriptors(db_desc, q_desc, metric)
    n_db, n_q = desc.n_db, desc.n_q
    top_k = check_top_k(top_k, nullable=False)
    search = {**SEARCH, **{k: params.pop(k) for k in SEARCH if k in params}}
    block, n_candidates, candidate_stride, n_windows = (search[k] for k in SEARCH)
    c = SeqSlamConf.of(conf, **params)
    causal, enhance = c.causal, c.enhance
    ds, velocities, offsets, R, rwindow, ratio_threshold = check_sequence_params(
        c.ds, causal, c.v_min, c.v_max, c.v_step, c.R, c.rwindow, c.ratio_threshold)
    n_windows = check_int(n_windows, "n_windows", 1)
    n_candidates = check_int(n_candidates, "n_candidates", 1)
    candidate_stride = check_int(candidate_stride, "candidate_stride", 1)
    if candidates is None:
        ptr = rows = None
    elif isinstance(candidates, str):
        if candidates != "pairwise":
            raise ValueError(f"candidates: expected None, 'pairwise' or a matrix, got {candidates!r}")
        ptr, rows = desc.candidates(n_candidates, candidate_stride)
    else:
        ptr, rows = _candidate_pattern(candidates, n_db, n_q)
    block = check_int(256 if block is None and ptr is None else 64 if block is None else block, "block", 1)

    causal = bool(causal)
    h = R // 2 if enhance else 0
    a = ds if causal else ds // 2
    anchor = offsets[:, ds] if causal else np.full(len(offsets), ds // 2)
    rel = np.ascontiguousarray(offsets - anchor[:, None])
    rmin, rmax = int(rel.min()), int(rel.max())
    n_pts = ds + 1
    hw = rwindow // 2

    zmin = np.inf                         # global minimum of the enhanced matrix (over what was computed)
    s_max, p_min, p_max = -np.inf, np.inf, -np.inf
    any_nothing = False
    best = np.full(n_q, -1, dtype=np.int64)       # -1: no candidate, nothing searched
    best_raw = np.full(n_q, np.inf, dtype=np.float32)
    second_raw = np.full(n_q, np.inf, dtype=np.float32)
    complete = np.zeros(n_q, dtype=bool)
    kept_r, kept_c, kept_cls, kept_v = [], [], [], []
    exact = True
    cells = 0
    for q0 in range(0, n_q, block):
        q1 = min(q0 + block, n_q)
        w = q1 - q0
        if ptr is None:
            ivs = [(0, n_db)]
        else:
            ivs = _windows(ptr, rows, q0, q1, n_db, n_windows, float(velocities[0]), float(velocities[-1]), hw)
        exact &= ivs == [(0, n_db)]
        if not ivs:
            continue
        # query columns the block's trajectories read: j + k for k = 0..ds
        c_lo, c_hi = q0 - a, q1 - a + ds
        c0, c1 = max(c_lo, 0), min(c_hi, n_q)
        colvalid = np.zeros(w + ds, dtype=np.bool_)
        colvalid[c0 - c_lo:c1 - c_lo] = True
        S_parts, P_parts, row_parts = [], [], []
        for o0, o1 in ivs:
            z0, z1 = max(o0 + rmin, 0), min(o1 + rmax, n_db)
            d0, d1 = max(z0 - h, 0), min(z1 + h, n_db)
            Z = np.zeros((z1 - z0, w + ds), dtype=np.float32)
            if c1 > c0:
                D = desc.block(d0, d1, c0, c1)
                if enhance:
                    Zc = np.empty((z1 - z0, c1 - c0), dtype=np.float32)
                    K.enhance_rows(D, d0, z0, z1, n_db, h, Zc)
                else:
                    Zc = D[z0 - d0:z1 - d0]
                Z[:, c0 - c_lo:c1 - c_lo] = Zc
                if Zc.size:
                    zmin = min(zmin, float(Zc.min()))
            S = np.empty((o1 - o0, w), dtype=np.float32)
            P = np.empty((o1 - o0, w), dtype=np.float32)
            K.trajectories(Z, z0, o0, o1, n_db, rel, colvalid, S, P)
            S_parts.append(S)
            P_parts.append(P)
            row_parts.append(np.arange(o0, o1))
        S = np.concatenate(S_parts) if len(S_parts) > 1 else S_parts[0]
        P = np.concatenate(P_parts) if len(P_parts) > 1 else P_parts[0]
        rws = np.concatenate(row_parts) if len(row_parts) > 1 else row_parts[0]
        L = len(rws)
        cells += L * w
        feas = np.isfinite(S)
        part = ~feas & np.isfinite(P)
        nothing = ~feas & ~part
        if feas.any():
            s_max = max(s_max, float(S[feas].max()))
        if part.any():
            p_min = min(p_min, float(P[part].min()))
            p_max = max(p_max, float(P[part].max()))
        any_nothing |= bool(nothing.any())
        comp = feas.any(axis=0)
        complete[q0:q1] = comp
        T = np.where(comp[None, :], S, P)
        b = np.argmin(T, axis=0)
        cols = np.arange(w)
        best[q0:q1] = rws[b]
        best_raw[q0:q1] = T[b, cols]
        T[np.abs(rws[:, None] - rws[b][None, :]) <= hw] = np.inf
        second_raw[q0:q1] = T.min(axis=0)
        # top-K in the dense order: feasible by score, then partial by partial score, then the rest
        key = np.where(feas, S.astype(np.float64), np.inf)
        if part.any():
            off = (float(S[feas].max()) if feas.any() else 0.0) - float(P[part].min()) + 1.0
            key[part] = P[part].astype(np.float64) + off
        k = min(top_k, L)
        idx = np.argpartition(key, k - 1, axis=0)[:k] if k < L else np.broadcast_to(np.arange(L)[:, None], (L, w))
        cls = np.where(feas, 0, np.where(part, 1, 2)).astype(np.int8)
        kept_r.append(rws[idx].ravel())
        kept_c.append(np.broadcast_to(q0 + cols, idx.shape).ravel())
        kept_cls.append(np.take_along_axis(cls, idx, axis=0).ravel())
        kept_v.append(np.take_along_axis(np.where(feas, S, P), idx, axis=0).ravel())

    # OpenSeqSLAM's shift of the enhanced matrix to minimum 0, applied to the sums
    shift = n_pts * zmin if (enhance and np.isfinite(zmin)) else 0.0
    best_score = (best_raw.astype(np.float64) - shift).astype(np.float32)
    second = (second_raw.astype(np.float64) - shift).astype(np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(np.isinf(second), 0.0, best_score / second)
    ratio = np.where((second == 0) | ~np.isfinite(best_score), 1.0, ratio).astype(np.float32)
    accepted = np.isfinite(best_score) & (ratio <= ratio_threshold)

    r = np.concatenate(kept_r) if kept_r else np.zeros(0, np.int64)
    c = np.concatenate(kept_c) if kept_c else np.zeros(0, np.int64)
    cls = np.concatenate(kept_cls) if kept_cls else np.zeros(0, np.int8)
    v = np.concatenate(kept_v).astype(np.float64) - shift if kept_v else np.zeros(0)
    # the dense _similarity's mapping, with its global constants taken over the searched cells
    hi = float(np.float32(s_max - shift)) if np.isfinite(s_max) else 0.0
    gap = max(1.0, 1e-3 * abs(hi))
    sim = np.empty(len(v), dtype=np.float32)
    sim[cls == 0] = -v[cls == 0].astype(np.float32)
    if np.isfinite(p_min):
        lo_p = float(np.float32(p_min - shift))
        sim[cls == 1] = -(hi + gap + (v[cls == 1].astype(np.float32).astype(np.float64) - lo_p))
        floor = float(np.float32(-(hi + gap + (float(np.float32(p_max - shift)) - lo_p))))
    else:
        floor = -hi if np.isfinite(s_max) else 0.0
    if any_nothing:
        sim[cls == 2] = floor - gap
    similarity = sp.coo_matrix((sim, (r, c)), shape=(n_db, n_q)).tocsr()
    return SeqSLAMResult(similarity=similarity, best_db=best, best_score=best_score, ratio=ratio,
                         accepted=accepted, complete=complete, velocities=velocities, exact=bool(exact),
                         cells=int(cells))
