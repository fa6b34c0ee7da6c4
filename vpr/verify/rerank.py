"""Which candidates to verify, and the similarity re-ordered by what verification found."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from vpr.checks import check_int, check_similarity

__all__ = ["top_candidates", "rerank"]


def _rank(rows: np.ndarray, vals: np.ndarray, n: int) -> np.ndarray:
    """The ``n`` rows with the highest values, ties by lower row, as a -1 padded (n,) array."""
    out = np.full(n, -1, dtype=np.intp)
    keep = vals > -np.inf  # -inf means "never matched" (vpr.evaluate convention)
    rows, vals = rows[keep], vals[keep]
    if len(rows) > n:
        # only entries at least as good as the n-th best can be chosen; keeping all ties of the n-th value lets
        # lexsort break them by row
        kth = -np.partition(-vals, n - 1)[n - 1]
        sel = vals >= kth
        rows, vals = rows[sel], vals[sel]
    order = np.lexsort((rows, -vals))[:n]
    out[:len(order)] = rows[order]
    return out


def top_candidates(S, n_candidates: int) -> np.ndarray:
    """Each query's ``n_candidates`` most similar database entries (stored, not ``-inf``).

    Returns intp (n_q, n_candidates) database indices by decreasing similarity, ties by lower index, padded with -1.
    """
    n = check_int(n_candidates, "n_candidates", 1)
    S = check_similarity(S, sparse_format="csc")
    n_db, n_q = S.shape
    out = np.empty((n_q, n), dtype=np.intp)
    if sp.issparse(S):
        for j in range(n_q):
            lo, hi = S.indptr[j], S.indptr[j + 1]
            out[j] = _rank(S.indices[lo:hi].astype(np.intp), S.data[lo:hi], n)
    else:
        rows = np.arange(n_db, dtype=np.intp)
        for j in range(n_q):
            out[j] = _rank(rows, S[:, j], n)
    return out


def rerank(S, candidates, inliers):
    """``S`` with each query's verified candidates re-ordered by inliers; every other entry unchanged.

    The values ``S[candidates[j], j]`` are handed out again in decreasing order, the highest to the candidate with the
    most inliers (ties keep the ``S`` order): each column keeps its values (``docs/internals.md``).

    Parameters
    ----------
    S : array_like or scipy.sparse matrix, (n_db, n_q)
    candidates : array_like of int, (n_q, N)
        Database rows per query (:func:`top_candidates`), -1 for padding; stored entries of a sparse ``S``.
    inliers : array_like of int, (n_q, N)

    Returns a new matrix of ``S``'s kind (float64; sparse: csc). Shapes that disagree, candidates out of range,
    repeated, not stored or at ``-inf`` raise ValueError.
    """
    S = check_similarity(S, sparse_format="csc")
    n_db, n_q = S.shape
    cand = np.asarray(candidates)
    inl = np.asarray(inliers)
    if cand.ndim != 2 or cand.shape[0] != n_q or cand.dtype.kind not in "iu":
        raise ValueError(f"candidates must be an integer (n_q={n_q}, N) array, got shape {cand.shape} "
                         f"dtype {cand.dtype}")
    if inl.shape != cand.shape:
        raise ValueError(f"inliers must have the shape of candidates {cand.shape}, got {inl.shape}")
    valid = cand >= 0
    if (cand >= n_db).any():
        raise ValueError(f"candidates index beyond the {n_db} database rows")
    srt = np.sort(np.where(valid, cand, -1 - np.arange(cand.shape[1])), axis=1)
    if (np.diff(srt, axis=1) == 0).any():
        raise ValueError("candidates: a database row is repeated within one query")
    q, r = np.nonzero(valid)
    rows = cand[q, r].astype(np.intp)
    out = S.copy()
    if sp.issparse(out):
        # csc with sorted indices: the stored entries' keys col * n_db + row increase, so search them
        keys = np.repeat(np.arange(n_q, dtype=np.int64), np.diff(out.indptr)) * n_db + out.indices
        want = q.astype(np.int64) * n_db + rows
        pos = np.searchsorted(keys, want)
        pos_c = np.minimum(pos, max(len(keys) - 1, 0))
        if want.size and (len(keys) == 0 or (keys[pos_c] != want).any()):
            raise ValueError("candidates: with a sparse S every candidate must be a stored entry")
        data = out.data
    else:
        pos = rows * n_q + q
        data = out.reshape(-1)  # a view: out is a fresh C-ordered copy
    vals = np.full(cand.shape, -np.inf)
    vals[q, r] = data[pos]
    if np.isneginf(vals[q, r]).any():
        raise ValueError("candidates: an entry with S = -inf (never matched) cannot be a candidate")
    # candidate k of each query, ordered by inliers (more first), ties by S (higher first) then by the candidates'
    # order, padding last
    neg_inl = np.where(valid, -inl.astype(np.int64), np.iinfo(np.int64).max)
    order = np.lexsort((np.broadcast_to(np.arange(cand.shape[1]), cand.shape), -vals, neg_inl), axis=-1)
    ranked_vals = -np.sort(-vals, axis=1)      # the same values, best first; padding (-inf) last
    new = np.full(cand.shape, -np.inf)
    np.put_along_axis(new, order, ranked_vals, axis=1)
    data[pos] = new[q, r]
    return out
