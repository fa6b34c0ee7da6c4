"""Brute-force pairwise comparison: every database frame against every query frame."""
from __future__ import annotations

import scipy.sparse as sp

from vpr import similarity

__all__ = ["pairwise", "METRICS"]

METRICS = ("auto", "overlap", "cosine", "sad")


def pairwise(db, query=None, metric: str = "auto", top_k: int | None = None):
    """Similarity of every database row to every query row (db x query).

    Parameters
    ----------
    db, query : SDR batch (csr bool) or dense descriptors (n, d)
        ``query=None`` compares ``db`` with itself (loop closure, T x T).
    metric : {"auto", "overlap", "cosine", "sad"}
        "auto" picks "overlap" for SDR batches and "cosine" for dense arrays. "sad" is the negative mean absolute
        difference (SeqSLAM's measure).
    top_k : int, optional
        Sparse top-K result (SDR overlap only), for large inputs.
    """
    if metric not in METRICS:
        raise ValueError(f"metric must be one of {METRICS}, got {metric!r}")
    is_sdr = sp.issparse(db)
    if metric == "auto":
        metric = "overlap" if is_sdr else "cosine"
    if metric == "overlap":
        return similarity.overlap_similarity(db, query, top_k=top_k)
    if top_k is not None:
        raise ValueError("top_k is only supported for SDR overlap")
    if is_sdr or (query is not None and sp.issparse(query)):
        db = db.toarray() if sp.issparse(db) else db
        query = query.toarray() if query is not None and sp.issparse(query) else query
    if metric == "cosine":
        return similarity.cosine(db, query)
    return similarity.neg_sad(db, query)
