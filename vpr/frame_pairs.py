"""Brute-force pairwise comparison: every database frame against every query frame."""
from __future__ import annotations

import scipy.sparse as sp

from vpr import similarity

__all__ = ["pairwise", "METRICS"]

METRICS = ("auto", "overlap", "cosine", "sad")


def pairwise(db, query=None, metric: str = "auto", top_k: int | None = None):
    """Similarity of every database row to every query row (db x query; ``query=None``: T x T).

    ``metric``: ``"auto"`` (``"overlap"`` for SDR batches, ``"cosine"`` for dense arrays), or ``"sad"`` (negative mean
    absolute difference). ``top_k``: a sparse result (SDR overlap only).
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
