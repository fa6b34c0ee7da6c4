"""Rankings: average precision, precision-recall curves, recall at 100 % precision, recall@K."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from vpr.checks import at, check_int, check_similarity

__all__ = ["recall_at_n", "RECALL_AT", "average_precision", "pr_curve", "thin_pr", "auc_pr", "auc_from_pr",
           "recall_at_100p", "recall_at_k", "evaluate"]

_MATCHINGS = ("multi", "single")


class _Problem(NamedTuple):
    """Validated inputs reduced to what the metrics need; sparse: the candidate entries in ranking order."""

    shape: tuple
    sparse: bool
    S: np.ndarray | None          # dense only, float64
    hard: np.ndarray | None       # dense only, bool
    cand: np.ndarray | None       # dense only, bool: may be decided / ranked
    rows: np.ndarray | None       # sparse only, candidate entries
    cols: np.ndarray | None
    vals: np.ndarray | None
    is_hard: np.ndarray | None
    n_pos: int                    # gt_hard pairs inside the mask
    pos_queries: np.ndarray       # bool (n_q,): query has a gt_hard pair in the mask
    n_pairs: int                  # evaluated pairs (inside the mask, not soft-only), never-matched included


def _check_bool(name, G, shape, dense):
    """Return ``G`` as a bool ndarray (``dense``) or as-given bool ndarray / canonical CSR."""
    if G is None:
        return None
    if sp.issparse(G):
        if G.dtype != bool:
            raise ValueError(f"{name} must be boolean, got dtype {G.dtype}")
        if G.shape != shape:
            raise ValueError(f"{name} has shape {G.shape}, but S has shape {shape}")
        if dense:
            return G.toarray()
        G = sp.csr_matrix(G, copy=True)
        G.eliminate_zeros()
        return G
    G = np.asarray(G)
    if G.dtype != bool:
        raise ValueError(f"{name} must be boolean, got dtype {G.dtype}")
    if G.shape != shape:
        raise ValueError(f"{name} has shape {G.shape}, but S has shape {shape}")
    return G


def _prepare(S, gt_hard, gt_soft=None, mask=None) -> _Problem:
    S = check_similarity(S, sparse_format="coo")
    shape = S.shape
    sparse = sp.issparse(S)
    if sparse:
        S = (S.row.astype(np.intp), S.col.astype(np.intp), S.data)
    hard = _check_bool("gt_hard", gt_hard, shape, dense=not sparse)
    if hard is None:
        raise ValueError("gt_hard is required")
    soft = _check_bool("gt_soft", gt_soft, shape, dense=not sparse)
    mask = _check_bool("mask", mask, shape, dense=not sparse)
    n_q = shape[1]

    if not sparse:
        evaluated = np.ones(shape, dtype=bool) if mask is None else mask.copy()
        if soft is not None:
            evaluated &= ~(soft & ~hard)
        cand = evaluated & (S > -np.inf)
        pos = hard if mask is None else hard & mask
        return _Problem(shape, False, S, hard, cand, None, None, None, None,
                        int(np.count_nonzero(pos)), pos.any(axis=0), int(np.count_nonzero(evaluated)))

    rows, cols, vals = S
    is_hard = at(hard, rows, cols)
    keep = vals > -np.inf
    if soft is not None:
        keep &= ~(at(soft, rows, cols) & ~is_hard)
    if mask is not None:
        keep &= at(mask, rows, cols)
    rows, cols, vals, is_hard = rows[keep], cols[keep], vals[keep], is_hard[keep]
    # ranking order within each query: similarity descending, then db index
    order = np.lexsort((rows, -vals, cols))
    rows, cols, vals, is_hard = rows[order], cols[order], vals[order], is_hard[order]

    # positives that S never stored still count in the recall denominators
    if sp.issparse(hard):
        hc = hard.tocoo()
        h_rows, h_cols = hc.row.astype(np.intp), hc.col.astype(np.intp)
    else:
        h_rows, h_cols = np.nonzero(hard)
    if mask is not None:
        inside = at(mask, h_rows, h_cols)
        h_rows, h_cols = h_rows[inside], h_cols[inside]
    pos_queries = np.bincount(h_cols, minlength=n_q) > 0
    return _Problem(shape, True, None, None, None, rows, cols, vals, is_hard,
                    int(len(h_rows)), pos_queries, _count_evaluated(shape, hard, soft, mask))


def _count_evaluated(shape, hard, soft, mask) -> int:
    """Pairs inside ``mask`` that are not soft-only, counted from the nonzeros (never ``n_db x n_q`` work)."""
    if mask is None:
        n = shape[0] * shape[1]
    else:
        n = int(mask.nnz) if sp.issparse(mask) else int(np.count_nonzero(mask))
    if soft is None:
        return n
    if sp.issparse(soft):
        sc = soft.tocoo()
        s_rows, s_cols = sc.row.astype(np.intp), sc.col.astype(np.intp)
    else:
        s_rows, s_cols = np.nonzero(soft)
    soft_only = ~at(hard, s_rows, s_cols)
    if mask is not None:
        soft_only &= at(mask, s_rows, s_cols)
    return n - int(np.count_nonzero(soft_only))


def _check_matching(matching):
    if matching not in _MATCHINGS:
        raise ValueError(f"matching must be one of {_MATCHINGS}, got {matching!r}")


def _decisions(p: _Problem, matching: str):
    """Similarity and correctness of every decision, plus the recall denominator."""
    if matching == "multi":
        n_pos = p.n_pos
        if p.sparse:
            vals, is_hard = p.vals, p.is_hard
        else:
            vals, is_hard = p.S[p.cand], p.hard[p.cand]
    else:
        n_pos = int(np.count_nonzero(p.pos_queries))
        if p.sparse:
            # entries are in ranking order, so each query's first one is its best
            first = np.r_[True, p.cols[1:] != p.cols[:-1]] if len(p.cols) else np.zeros(0, bool)
            vals, is_hard = p.vals[first], p.is_hard[first]
        else:
            Sc = np.where(p.cand, p.S, -np.inf)
            best = np.argmax(Sc, axis=0)  # first maximum = lowest db index on ties
            q = np.arange(p.shape[1])
            vals = Sc[best, q]
            decided = vals > -np.inf
            vals, is_hard = vals[decided], p.hard[best, q][decided]
    if n_pos == 0:
        where = "inside mask " if matching == "multi" else ""
        raise ValueError(f"gt_hard has no true match {where}to evaluate: recall is undefined")
    return vals, is_hard, n_pos


def _counts(vals, is_hard):
    """Thresholds (decreasing, with +inf first) and cumulative TP / FP counts."""
    # A plain sort of the values plus a search among the (few) true ones is much faster than an argsort of all
    # decisions with cumulative sums.
    v = np.sort(vals)
    first = np.flatnonzero(np.r_[True, v[1:] != v[:-1]]) if len(v) else np.zeros(0, np.intp)
    distinct = v[first]
    n_ge = len(v) - first  # a threshold admits every tied decision at once
    hard_sorted = np.sort(vals[is_hard])
    tp = len(hard_sorted) - np.searchsorted(hard_sorted, distinct, side="left")
    fp = n_ge - tp
    return np.r_[np.inf, distinct[::-1]], np.r_[0, tp[::-1]], np.r_[0, fp[::-1]]


def _curve(p: _Problem, matching: str):
    vals, is_hard, n_pos = _decisions(p, matching)
    thresholds, tp, fp = _counts(vals, is_hard)
    predicted = tp + fp
    precision = np.zeros(len(tp))
    precision[1:] = tp[1:] / predicted[1:]  # every real threshold predicts >= 1 pair
    # The start point (recall 0) takes the precision of the first threshold: an invented precision 1 there would add
    # area that no threshold achieves (a constant S would score (1 + share of true pairs) / 2 instead of the share).
    if len(tp) > 1:
        precision[0] = precision[1]
    recall = tp / n_pos
    return precision, recall, thresholds, fp, tp


def _average_precision(p: _Problem, precision, recall, tp) -> float:
    """Non-interpolated AP of the multi-matching curve plus the final block of never-matched pairs."""
    ap = float(np.sum(np.diff(recall) * precision[1:]))
    # Pairs that are never matched (unstored / -inf) rank last, tied: one final threshold that predicts every
    # evaluated pair, at precision n_pos / n_pairs.
    missed = p.n_pos - int(tp[-1])
    if missed:
        ap += missed / p.n_pairs
    return ap


def _auc(precision, recall):
    return float(np.sum(np.diff(recall) * (precision[1:] + precision[:-1]) / 2.0))


def _recall_at_k(p: _Problem, k: int) -> float:
    n_pos = int(np.count_nonzero(p.pos_queries))
    if n_pos == 0:
        raise ValueError("gt_hard has no query with a true match to evaluate: recall@k is undefined")
    return float(np.count_nonzero(_hits_at_k(p, k)) / n_pos)


def _hits_at_k(p: _Problem, k: int) -> np.ndarray:
    """Per query: whether one of its ``k`` first-ranked evaluated entries is a true match."""
    if p.sparse:
        hit = np.zeros(p.shape[1], dtype=bool)
        if len(p.cols) == 0:
            return hit
        start = np.searchsorted(p.cols, p.cols, side="left")
        rank = np.arange(len(p.cols)) - start
        hit[p.cols[p.is_hard & (rank < k)]] = True
        return hit & p.pos_queries

    # Rank of each query's best true match under the order (similarity desc, db index asc): entries strictly more
    # similar, plus ties with a lower index.
    hc = p.hard & p.cand
    v = np.where(hc, p.S, -np.inf).max(axis=0)
    r_best = np.argmax(hc & (p.S == v), axis=0)
    above = np.count_nonzero(p.cand & (p.S > v), axis=0)
    rows = np.arange(p.shape[0])[:, None]
    tied_before = np.count_nonzero(p.cand & (p.S == v) & (rows < r_best), axis=0)
    hit = (v > -np.inf) & (above + tied_before < k)
    return hit & p.pos_queries


#: The N of Recall@N the field reports (VPR-methods-evaluation, the published tables).
RECALL_AT = (1, 5, 10, 20)


def recall_at_n(S, gt_hard, gt_soft=None, ns=RECALL_AT, mask=None) -> dict:
    """Recall@N as the field computes it, and over the queries with a true match.

    A query is a hit at N when one of its N first-ranked evaluated entries (similarity descending, ties by lower
    index; soft-only and masked-out entries left out, as :func:`recall_at_k`) is a true match. Returns
    ``every_query`` (N -> hits over every query: the field's denominator, VPR-methods-evaluation's), ``with_true_match``
    (N -> hits over the queries with a true match: :func:`recall_at_k`'s; None without one), ``queries`` and
    ``queries_with_true_match``. N: positive integers (ValueError otherwise).
    """
    ns = [int(n) for n in ns]
    if not ns or any(n < 1 for n in ns):
        raise ValueError(f"recall at N: positive integers, got {list(ns)}")
    p = _prepare(S, gt_hard, gt_soft, mask)
    n_q, n_pos = p.shape[1], int(np.count_nonzero(p.pos_queries))
    hits = {n: int(np.count_nonzero(_hits_at_k(p, n))) for n in ns}
    return {"every_query": {str(n): h / n_q if n_q else None for n, h in hits.items()},
            "with_true_match": {str(n): h / n_pos if n_pos else None for n, h in hits.items()},
            "queries": n_q, "queries_with_true_match": n_pos}


def pr_curve(S, gt_hard, gt_soft=None, matching="multi", mask=None):
    """Precision-recall curve at every distinct similarity threshold.

    A pair (``"single"`` matching: each query's best pair, lowest index on ties) is predicted at threshold ``t`` if
    its similarity is ``>= t``. Conventions on ``S``, ``gt_soft`` and ``mask``: ``docs/internals.md``.

    Parameters
    ----------
    S : array_like or scipy.sparse matrix, shape (n_db, n_q)
        Higher = more similar.
    gt_hard, gt_soft, mask : bool array or sparse bool matrix, shape (n_db, n_q)
        True matches; pairs ``gt_soft & ~gt_hard`` are ignored; only pairs in ``mask`` are evaluated.
    matching : {"multi", "single"}

    Returns
    -------
    precision, recall, thresholds : ndarray of float, shape (n_thresholds + 1,)
        By decreasing threshold, after a start point ``thresholds[0] = +inf``, ``recall[0] = 0``, ``precision[0] =
        precision[1]`` (0 when nothing is ever predicted).

    Raises ValueError on shape mismatch, NaN or +inf in ``S``, non-boolean ground truth or mask, unknown ``matching``,
    or no true match to evaluate.
    """
    _check_matching(matching)
    precision, recall, thresholds, _, _ = _curve(_prepare(S, gt_hard, gt_soft, mask), matching)
    return precision, recall, thresholds


def average_precision(S, gt_hard, gt_soft=None, mask=None) -> float:
    """Non-interpolated average precision over all evaluated pairs (the headline metric).

    ``AP = sum_n (R_n - R_{n-1}) P_n`` over the distinct thresholds, decreasing (scikit-learn's
    ``average_precision_score`` of the evaluated pairs, ties together). Never-matched pairs rank last, tied, so a
    top-K ``S`` scores as the dense one with its missing entries lowest; cost grows with the stored entries. Arguments
    and errors as :func:`pr_curve` (``"multi"`` only).
    """
    p = _prepare(S, gt_hard, gt_soft, mask)
    precision, recall, _, _, tp = _curve(p, "multi")
    return _average_precision(p, precision, recall, tp)


def thin_pr(precision, recall) -> np.ndarray:
    """Indices (increasing) of the points of a precision-recall curve its shape needs.

    The first, the last and the ends of each run of equal recall: the same AP, area, recall at 100 % precision and
    drawing, at most two points per true positive.
    """
    recall = np.asarray(recall)
    if np.shape(precision) != recall.shape or recall.ndim != 1:
        raise ValueError(f"precision and recall must be 1-D of equal length, got shapes {np.shape(precision)} "
                         f"and {recall.shape}")
    if recall.size <= 2:
        return np.arange(recall.size)
    step = recall[1:] != recall[:-1]
    keep = np.r_[True, step] | np.r_[step, True]
    return np.flatnonzero(keep)


def auc_from_pr(precision, recall) -> float:
    """Area under a precision-recall curve (points by non-decreasing recall) by the trapezoidal rule.

    Arrays not 1-D of equal length, NaN or a decreasing recall raise ValueError.
    """
    precision = np.asarray(precision, dtype=np.float64)
    recall = np.asarray(recall, dtype=np.float64)
    if precision.ndim != 1 or recall.shape != precision.shape:
        raise ValueError(f"precision and recall must be 1-D of equal length, got shapes "
                         f"{precision.shape} and {recall.shape}")
    if np.isnan(precision).any() or np.isnan(recall).any():
        raise ValueError("precision / recall contain NaN")
    if np.any(np.diff(recall) < 0):
        raise ValueError("recall must be non-decreasing (order points by decreasing threshold)")
    return _auc(precision, recall)


def auc_pr(S, gt_hard, gt_soft=None, matching="multi", mask=None) -> float:
    """Area under the precision-recall curve of :func:`pr_curve` (trapezoid over recall).

    For comparison with earlier results and ``"single"`` matching; prefer
    :func:`average_precision` (``docs/internals.md``). Arguments and errors
    as for :func:`pr_curve`.
    """
    _check_matching(matching)
    precision, recall, _, _, _ = _curve(_prepare(S, gt_hard, gt_soft, mask), matching)
    return _auc(precision, recall)


def recall_at_100p(S, gt_hard, gt_soft=None, matching="multi", mask=None) -> float:
    """Largest recall on the :func:`pr_curve` reached without any false positive.

    Thresholds admit tied decisions together, so a block of tied pairs that holds a false one ends the 100 % precision
    range before it. Returns 0 when the most similar decision (or tie block) is already wrong. Arguments and errors as
    for :func:`pr_curve`.
    """
    _check_matching(matching)
    _, recall, _, fp, _ = _curve(_prepare(S, gt_hard, gt_soft, mask), matching)
    # fp is non-decreasing, so the last fp == 0 point has the largest recall
    return float(recall[fp == 0][-1])


def recall_at_k(S, gt_hard, gt_soft=None, k=1, mask=None) -> float:
    """Fraction of queries with a true match (inside ``mask``) whose top-``k`` database entries hold one.

    Each query ranks its evaluated entries by decreasing similarity, ties by lower index; soft-only, masked-out and
    never-matched entries leave the ranking (Schubert et al.'s ``recallAtK``). Arguments and errors as
    :func:`pr_curve`; ``k >= 1``.
    """
    k = check_int(k, "k", minimum=1)
    return _recall_at_k(_prepare(S, gt_hard, gt_soft, mask), k)


def evaluate(S, gt_hard, gt_soft=None, mask=None, return_curve: bool = False):
    """Standard metric set for one similarity matrix, arguments and errors as :func:`pr_curve`.

    Returns ``ap`` (first key), ``auc_pr``, ``recall_at_100p`` (multi matching), ``recall_at_1``, ``recall_at_5``,
    ``auc_pr_single``; with ``return_curve`` also the multi-matching ``(precision, recall, thresholds)``.
    """
    p = _prepare(S, gt_hard, gt_soft, mask)
    precision, recall, thresholds, fp, tp = _curve(p, "multi")
    precision_s, recall_s, _, _, _ = _curve(p, "single")
    metrics = {
        "ap": _average_precision(p, precision, recall, tp),
        "auc_pr": _auc(precision, recall),
        "recall_at_100p": float(recall[fp == 0][-1]),
        "recall_at_1": _recall_at_k(p, 1),
        "recall_at_5": _recall_at_k(p, 5),
        "auc_pr_single": _auc(precision_s, recall_s),
    }
    return (metrics, (precision, recall, thresholds)) if return_curve else metrics
