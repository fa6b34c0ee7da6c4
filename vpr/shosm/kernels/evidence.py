"""Compiled kernels of the dense graded evidence (numba) and of the per-query finish."""
from __future__ import annotations

import numpy as np
from numba import njit

from .overlap import count_overlaps


@njit(cache=True, nogil=True)  # a late answer's backward pass runs on another thread (vpr.shosm.Lagged)
def evidence_frames(q_ptr, q_ind, order, bit_cols, bit_len, col_size, rel_col, e_src, e_dst,
                    db_ptr, db_ind, db_norm, decay, stay, skip, z_weight, out, e, fresh, clamp=False):
    """Graded sequence evidence of a query traverse along the learned lateral connections (dense).

    Cells are the memory's relevant cells renumbered ``0 .. n_rel-1`` (``rel_col``: each one's minicolumn). A cell's
    evidence is its minicolumn's overlap fraction ``z`` plus ``decay`` times the best evidence that predicts it: its
    incoming connections, two back minus ``skip``, or itself minus ``stay`` (negative: off). ``out[j, q] += mean over
    database code j of (evidence - z_weight * z)``. ``e`` carries the evidence between calls (``fresh``: the first);
    ``clamp`` floors the predicted term at 0 as :func:`beam_frames` does.
    """
    n_rel = rel_col.shape[0]
    n_cols = col_size.shape[0]
    n_db = db_ptr.shape[0] - 1
    n_e = e_src.shape[0]
    counts = np.zeros(n_cols, np.float64)
    touched = np.empty(n_cols, np.int64)
    z = np.zeros(n_rel, np.float64)
    p1 = np.empty(n_rel, np.float64)
    p2 = np.empty(n_rel, np.float64)
    for t in range(order.shape[0]):
        q = order[t]
        n_touch = count_overlaps(q_ind[q_ptr[q]:q_ptr[q + 1]], bit_cols, bit_len, counts, touched)
        for c in range(n_rel):
            col = rel_col[c]
            z[c] = counts[col] / col_size[col] if col_size[col] > 0 else 0.0
        for i in range(n_touch):
            counts[touched[i]] = 0.0
        if t == 0 and fresh:
            for c in range(n_rel):
                e[c] = z[c]
        else:
            p1[:] = -np.inf
            for k in range(n_e):
                if e[e_src[k]] > p1[e_dst[k]]:
                    p1[e_dst[k]] = e[e_src[k]]
            if skip >= 0.0:
                p2[:] = -np.inf
                for k in range(n_e):
                    if p1[e_src[k]] > p2[e_dst[k]]:
                        p2[e_dst[k]] = p1[e_src[k]]
            for c in range(n_rel):
                p = p1[c]
                if skip >= 0.0 and p2[c] - skip > p:
                    p = p2[c] - skip
                if stay >= 0.0 and e[c] - stay > p:
                    p = e[c] - stay
                if p == -np.inf or (clamp and p < 0.0):
                    p = 0.0  # nothing predicts this cell: no sequence evidence either way
                e[c] = z[c] + decay * p
        for j in range(n_db):
            s = 0.0
            for i in range(db_ptr[j], db_ptr[j + 1]):
                c = db_ind[i]
                s += e[c] - z_weight * z[c]
            if db_norm[j] > 0:
                out[j, q] += s / db_norm[j]
    return out


@njit(cache=True)
def moments(vals, n):
    """Mean and standard deviation of ``n`` scores of which ``vals`` are stored and the others are 0.

    The one z-score of rSHOSM-seq: every column, dense or sparse, batch or online, is standardised as ``(v - mean) /
    sd`` with these (sd 1 where the scores do not vary).
    """
    s = 0.0
    s2 = 0.0
    for v in vals:
        s += v
        s2 += v * v
    if n <= 0:
        return 0.0, 1.0
    mu = s / n
    var = s2 / n - mu * mu
    return mu, (np.sqrt(var) if var > 0 else 1.0)


@njit(cache=True)
def zscore_dense(S):
    """Standardise every column of a dense n_db x n_q matrix in place (:func:`moments`)."""
    col = np.empty(S.shape[0], np.float64)
    for q in range(S.shape[1]):
        for i in range(S.shape[0]):
            col[i] = S[i, q]
        mu, sd = moments(col, S.shape[0])
        for i in range(S.shape[0]):
            S[i, q] = (col[i] - mu) / sd
    return S


@njit(cache=True)
def finish_columns(a_ptr, a_idx, a_val, b_ptr, b_idx, b_val, n_db, top_k, normalise, acc, mark, touch):
    """Per query: sum the two passes' sparse columns (``b_ptr`` empty: one pass),
    standardise over all database frames (:func:`moments`) and keep the ``top_k`` largest (``top_k <= 0``: all).

    ``n_db`` is an array (per query, the number of database frames it is scored against). Returns (ptr, idx, val,
    best, score, mean, sd); ``best`` is -1 for a query without any evidence. Ties go to the smaller database index, as
    ``argmax`` of the dense column.
    """
    n_q = a_ptr.shape[0] - 1
    two = b_ptr.shape[0] == n_q + 1
    cap = 0
    for q in range(n_q):
        m = a_ptr[q + 1] - a_ptr[q]
        if two:
            m += b_ptr[q + 1] - b_ptr[q]
        cap += m if top_k <= 0 else min(m, top_k)
    ptr = np.zeros(n_q + 1, np.int64)
    idx = np.empty(cap, np.int64)
    val = np.empty(cap, np.float32)
    best = np.full(n_q, -1, np.int64)
    score = np.full(n_q, -np.inf, np.float64)
    mean = np.zeros(n_q, np.float64)
    sd = np.ones(n_q, np.float64)
    pos = 0
    for q in range(n_q):
        n_t = 0
        for i in range(a_ptr[q], a_ptr[q + 1]):
            j = a_idx[i]
            if not mark[j]:
                mark[j] = True
                touch[n_t] = j
                n_t += 1
            acc[j] += a_val[i]
        if two:
            for i in range(b_ptr[q], b_ptr[q + 1]):
                j = b_idx[i]
                if not mark[j]:
                    mark[j] = True
                    touch[n_t] = j
                    n_t += 1
                acc[j] += b_val[i]
        vals = np.empty(n_t, np.float64)
        for i in range(n_t):
            vals[i] = acc[touch[i]]
        mu = 0.0
        sig = 1.0
        if normalise:
            mu, sig = moments(vals, n_db[q])
        mean[q] = mu
        sd[q] = sig
        tj = touch[:n_t].copy()
        # sort by value descending, then index ascending (ties as argmax)
        o = np.argsort(tj, kind="mergesort")
        o2 = np.argsort(-vals[o], kind="mergesort")
        o = o[o2]
        k = n_t if top_k <= 0 else min(n_t, top_k)
        if n_t > 0:
            best[q] = tj[o[0]]
            score[q] = (acc[tj[o[0]]] - mu) / sig
        for i in range(k):
            j = tj[o[i]]
            idx[pos] = j
            val[pos] = (acc[j] - mu) / sig
            pos += 1
        ptr[q + 1] = pos
        for i in range(n_t):
            j = touch[i]
            acc[j] = 0.0
            mark[j] = False
    return ptr, idx[:pos], val[:pos], best, score, mean, sd
