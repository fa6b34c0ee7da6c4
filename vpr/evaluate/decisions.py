"""Metrics of decisions, one per query (or per frame of a stream): what a robot acts on."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from vpr.checks import at
from vpr.paths import MIN_RUN, SpeedReader, path_run_speeds, path_runs, path_speed, session_speeds

__all__ = ["accepted_precision", "best_in_soft_band", "decision_curve", "session_pairs", "outcomes", "path_speed",
           "path_runs", "path_run_speeds", "SpeedReader", "session_speeds", "MIN_RUN"]


def accepted_precision(best_db, accepted, gt_hard, gt_soft=None, mask=None) -> dict:
    """Precision and recall of the accepted best matches (one decision per query).

    ``best_db`` (-1: none) and ``accepted`` per query; ``gt_hard``, ``gt_soft``, ``mask`` as :func:`evaluate` (a best
    match on a soft-only pair counts neither way; ground truth outside ``mask`` is no match).

    Returns ``n_accepted``; ``precision_accepted`` (None over none); ``recall_accepted`` (correct accepted over
    queries with a true match; None when none has one); ``n_false``; ``false_per_1000`` (per 1,000 queries).
    """
    if mask is not None:
        gt_hard, gt_soft = (None if g is None else g.multiply(mask).tocsr() if sp.issparse(g) else np.asarray(g) & mask
                            for g in (gt_hard, gt_soft))
    best_db = np.asarray(best_db)
    q = np.flatnonzero(np.asarray(accepted, bool) & (best_db >= 0))
    n_accepted = int(q.size)
    correct = at(gt_hard, best_db[q], q).astype(bool)
    if gt_soft is not None:
        keep = correct | ~at(gt_soft, best_db[q], q).astype(bool)
        q, correct = q[keep], correct[keep]
    n_with_match = int((np.asarray((gt_hard != 0).sum(axis=0)).ravel() > 0).sum())
    n_false = int((~correct).sum())
    return {"n_accepted": n_accepted, "precision_accepted": float(correct.mean()) if q.size else None,
            "recall_accepted": float(correct.sum() / n_with_match) if n_with_match else None, "n_false": n_false,
            "false_per_1000": 1000.0 * n_false / max(1, best_db.size)}


def best_in_soft_band(best_db, gt_hard, gt_soft, mask=None) -> int:
    """How many queries' best match is a soft-only pair (``gt_soft & ~gt_hard``), which every metric ignores.

    Such a best match is neither right nor wrong for R@1, AP or the accepted precision; this count says how many there
    are, so that an R@1 of 1.000 is not read as "every best match is within the true radius".
    """
    if gt_soft is None:
        return 0
    best_db = np.asarray(best_db)
    q = np.flatnonzero(best_db >= 0)
    soft_only = at(gt_soft, best_db[q], q).astype(bool) & ~at(gt_hard, best_db[q], q).astype(bool)
    if mask is not None:
        soft_only &= at(mask, best_db[q], q).astype(bool)
    return int(np.count_nonzero(soft_only))


def decision_curve(best, score, gt_hard, gt_soft=None, mask=None) -> tuple[dict, tuple]:
    """One decision per query with its own score: the metrics loop-closure users report.

    Query ``j`` decides for ``best[j]`` (-1: none) with ``score[j]``; thresholds sweep every distinct score. Precision
    is over the accepted decisions (soft-only counts neither way), recall over the queries with a true match in
    ``mask``. Returns ``(metrics, (precision, recall, thresholds))``, metrics ``ap``, ``recall_at_100p``,
    ``n_with_match``.
    """
    if mask is not None:
        gt_hard, gt_soft = (None if g is None else g.multiply(mask).tocsr() if sp.issparse(g) else np.asarray(g) & mask
                            for g in (gt_hard, gt_soft))
    best = np.asarray(best, np.int64)
    score = np.asarray(score, np.float64)
    if best.shape != score.shape or best.ndim != 1:
        raise ValueError(f"best and score must be 1-D of one length, got {best.shape} and {score.shape}")
    q = np.flatnonzero((best >= 0) & np.isfinite(score))
    correct = at(gt_hard, best[q], q).astype(bool)
    if gt_soft is not None:
        keep = correct | ~at(gt_soft, best[q], q).astype(bool)
        q, correct = q[keep], correct[keep]
    n_with = int((np.asarray((gt_hard != 0).sum(axis=0)).ravel() > 0).sum())
    order = np.argsort(-score[q], kind="stable")
    s, c = score[q][order], correct[order]
    last = np.r_[s[1:] != s[:-1], True] if s.size else np.zeros(0, bool)  # the last decision of each score
    tp, n = np.cumsum(c)[last], (np.arange(s.size) + 1)[last]
    precision = tp / np.maximum(n, 1)
    recall = tp / max(n_with, 1)
    ap = float(np.sum(np.diff(np.r_[0.0, recall]) * precision)) if n_with else 0.0
    perfect = precision >= 1.0
    first_bad = np.flatnonzero(~perfect)
    upto = first_bad[0] if first_bad.size else perfect.size
    r100 = float(recall[upto - 1]) if upto > 0 else 0.0
    return ({"ap": ap, "recall_at_100p": r100, "n_with_match": n_with},
            (np.r_[1.0, precision] if precision.size else np.ones(1), np.r_[0.0, recall], s[last]))


def session_pairs(best, accepted, gt_hard, starts, gt_soft=None, mask=None, names=None, frames=None) -> list[dict]:
    """The accepted closures of a multi-session stream per pair of sessions ``r <= s``.

    Each pair gets ``frames`` (of ``s`` with a true loop onto ``r``), ``accepted``, ``precision`` (None over none) and
    ``recall``. ``best``, ``accepted``: per frame; ``gt_hard`` (None: counts only), ``gt_soft``, ``mask``: T x T;
    ``starts``: each session's first frame; ``names``: optional; ``frames``: each column's frame number (a session
    without a column is left out).
    """
    best, accepted = np.asarray(best, np.int64), np.asarray(accepted, bool)
    T = best.size
    starts = np.asarray(sorted(starts), np.int64)
    if gt_hard is None:  # without ground truth: the accepted closures alone
        sess = np.searchsorted(starts, np.arange(T) if frames is None else np.asarray(frames, np.int64),
                               side="right") - 1
        onto = np.searchsorted(starts, best, side="right") - 1
        label = (lambda k: names[k]) if names is not None else (lambda k: k)
        return [{"session": label(s), "onto": label(r), "frames": None,
                 "accepted": int((accepted & (best >= 0) & (sess == s) & (onto == r)).sum()), "precision": None,
                 "recall": None}
                for s in range(starts.size) if frames is None or (sess == s).any() for r in range(s + 1)]
    if mask is not None:
        gt_hard, gt_soft = (None if g is None else g.multiply(mask).tocsr() if sp.issparse(g) else
                            np.asarray(g) & mask for g in (gt_hard, gt_soft))
    hard = sp.csc_matrix(gt_hard, dtype=bool)
    sess = np.searchsorted(starts, np.arange(T) if frames is None else np.asarray(frames, np.int64), side="right") - 1
    n_rows = gt_hard.shape[0]
    label = (lambda k: names[k]) if names is not None else (lambda k: k)
    out = []
    q = np.flatnonzero(accepted & (best >= 0))
    correct = at(gt_hard, best[q], q).astype(bool)
    soft_only = at(gt_soft, best[q], q).astype(bool) & ~correct if gt_soft is not None else np.zeros(q.size, bool)
    for s in range(starts.size):
        cols = np.flatnonzero(sess == s)
        if frames is not None and not cols.size:
            continue
        for r in range(s + 1):
            rows = (starts[r], starts[r + 1] if r + 1 < starts.size else n_rows)
            with_loop = np.asarray(hard[rows[0]:rows[1], cols].sum(axis=0)).ravel() > 0
            onto = (sess[q] == s) & (best[q] >= rows[0]) & (best[q] < rows[1])
            judged = onto & ~soft_only
            n_ok = int((correct & onto).sum())
            out.append({"session": label(s), "onto": label(r), "frames": int(with_loop.sum()),
                        "accepted": int(onto.sum()),
                        "precision": float(correct[judged].mean()) if judged.any() else None,
                        "recall": n_ok / int(with_loop.sum()) if with_loop.any() else None})
    return out


def outcomes(best, gt_hard, gt_soft=None, mask=None) -> tuple[np.ndarray, np.ndarray]:
    """Per query: whether its best match is right, and one true database frame to show beside it.

    Returns ``(right, truth)``: ``right`` 1 (a true pair), 0 (wrong) or -1 (no best match, or a soft-only pair, which
    counts neither way); ``truth`` the middle one of the query's true database frames inside ``mask`` (-1: it has
    none). What ``matches.csv`` and the report show beside each decision.
    """
    if mask is not None:
        gt_hard, gt_soft = (None if g is None else g.multiply(mask).tocsr() if sp.issparse(g) else np.asarray(g) & mask
                            for g in (gt_hard, gt_soft))
    best = np.asarray(best, np.int64)
    q = np.flatnonzero(best >= 0)
    right = np.full(best.size, -1, np.int64)
    correct = at(gt_hard, best[q], q).astype(bool)
    right[q] = correct
    if gt_soft is not None:
        right[q[~correct & at(gt_soft, best[q], q).astype(bool)]] = -1
    hard = sp.csc_matrix(gt_hard, dtype=bool)
    hard.sort_indices()
    counts = np.diff(hard.indptr)
    truth = np.where(counts > 0, hard.indices[np.minimum(hard.indptr[:-1] + counts // 2, max(hard.nnz - 1, 0))]
                     if hard.nnz else -1, -1)
    return right, truth.astype(np.int64)
