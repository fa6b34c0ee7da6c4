"""Place-recognition methods behind one interface: rSHOSM, SeqSLAM and pairwise.

Each method takes the encoded traverses (:class:`Features`: SDRs and/or dense
descriptors) and returns a :class:`MatchResult` with a database x query
similarity matrix (dense, or a top-K sparse matrix for large inputs), the best
database frame per query, its score and an accept flag. ``match`` compares a
query traverse with a database traverse; ``loops`` finds loop closures within
one traverse (only earlier frames, at least ``exclude`` frames back).

Configuration follows hloc: each method has a ``default_conf`` that user
configuration is merged into (unknown keys are an error).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from vpr import similarity
from vpr.memory import SequenceMemory, pad_codes

__all__ = ["Features", "MatchResult", "DEFAULT_CONF", "METHODS", "merge_conf", "match", "loops",
           "best_matches"]

#: Above this many database x query pairs results are top-K sparse.
DENSE_PAIRS_LIMIT = 20_000 * 20_000

DEFAULT_CONF = {
    "rshosm": {**SequenceMemory().get_params(), "top_k": 50},
    "seqslam": {"ds": 10, "v_min": 0.8, "v_max": 1.2, "v_step": 0.1, "R": 10, "rwindow": 10,
                "ratio_threshold": 0.9, "causal": False, "metric": "sad", "descriptor": "pixel"},
    "pairwise": {"on": "sdr", "metric": "auto", "top_k": 50},
}
METHODS = tuple(DEFAULT_CONF)


@dataclass
class Features:
    """An encoded traverse: SDR batch (frames x bits), dense descriptors, SeqSLAM pixels, names."""

    names: list
    sdr: sp.csr_matrix | None = None
    desc: np.ndarray | None = None
    pixels: np.ndarray | None = None

    def __len__(self):
        return len(self.names)


@dataclass
class MatchResult:
    method: str
    similarity: np.ndarray | sp.csr_matrix
    best_db: np.ndarray
    score: np.ndarray
    accepted: np.ndarray
    seconds: float
    conf: dict = field(default_factory=dict)


def merge_conf(method: str, conf: dict | None) -> dict:
    """``DEFAULT_CONF[method]`` updated with ``conf``; unknown methods or keys raise ValueError."""
    if method not in DEFAULT_CONF:
        raise ValueError(f"unknown method {method!r}; available: {', '.join(METHODS)}")
    conf = dict(conf or {})
    unknown = set(conf) - set(DEFAULT_CONF[method])
    if unknown:
        raise ValueError(f"unknown {method} option(s) {sorted(unknown)}; valid: {sorted(DEFAULT_CONF[method])}")
    return {**DEFAULT_CONF[method], **conf}


def best_matches(S):
    """Best database index and its score per query of a dense or sparse db x query matrix.

    Queries without any stored entry (sparse) get ``best_db = -1`` and score ``-inf``.
    """
    if sp.issparse(S):
        S = sp.csc_matrix(S)
        n_q = S.shape[1]
        best = np.full(n_q, -1, dtype=np.int64)
        score = np.full(n_q, -np.inf, dtype=np.float64)
        for j in range(n_q):
            a, b = S.indptr[j], S.indptr[j + 1]
            if b > a:
                k = a + int(np.argmax(S.data[a:b]))
                best[j], score[j] = S.indices[k], S.data[k]
        return best, score
    S = np.asarray(S)
    best = np.argmax(S, axis=0).astype(np.int64)
    return best, S[best, np.arange(S.shape[1])].astype(np.float64)


def _need(feat: Features, attr: str, method: str, role: str):
    value = getattr(feat, attr)
    if value is None:
        what = {"sdr": "SDRs", "desc": "dense descriptors", "pixels": "SeqSLAM pixel descriptors"}[attr]
        raise ValueError(f"{method} needs {what} of the {role} traverse, but the encoder produced none")
    return value


def _top_k_or_dense(n_db, n_q, top_k):
    return top_k if n_db * n_q > DENSE_PAIRS_LIMIT else None


def _seqslam_descriptors(feat: Features, conf: dict, role: str):
    return _need(feat, "pixels" if conf["descriptor"] == "pixel" else "desc", "seqslam", role)


def _run_seqslam(D, conf):
    from vpr.baselines.seqslam import seqslam

    kw = {k: conf[k] for k in ("ds", "v_min", "v_max", "v_step", "R", "rwindow", "ratio_threshold", "causal")}
    res = seqslam(D, **kw)
    return res.similarity, res.best_db.astype(np.int64), -res.best_score.astype(np.float64), res.accepted


def match(method: str, db: Features, query: Features, conf: dict | None = None,
          progress: bool = False) -> MatchResult:
    """Match every query frame against the database traverse with ``method``."""
    conf = merge_conf(method, conf)
    t = time.perf_counter()
    accepted = None
    if method == "rshosm":
        mem_kw = {k: conf[k] for k in SequenceMemory().get_params()}
        mem = SequenceMemory(**mem_kw)
        db_codes = mem.run(_need(db, "sdr", method, "database"), progress=progress)
        mem.reset()
        q_codes = mem.run(_need(query, "sdr", method, "query"), learn=False, progress=progress)
        db_codes, q_codes = pad_codes(db_codes, q_codes)
        S = similarity.overlap(db_codes, q_codes, top_k=_top_k_or_dense(len(db), len(query), conf["top_k"]))
        best, score = best_matches(S)
    elif method == "seqslam":
        from vpr.baselines.seqslam import difference_matrix

        D = difference_matrix(_seqslam_descriptors(db, conf, "database"),
                              _seqslam_descriptors(query, conf, "query"), metric=conf["metric"])
        S, best, score, accepted = _run_seqslam(D, conf)
    else:
        S, best, score = _pairwise(db, query, conf)
    if accepted is None:
        accepted = _evidence(method, conf, best, score)
    return MatchResult(method, S, best, score, np.asarray(accepted, bool), time.perf_counter() - t, conf)


def _evidence(method, conf, best, score):
    """Accept a best match only if there is evidence: an overlap of zero is none."""
    ok = (best >= 0) & np.isfinite(score)
    if method == "rshosm" or (method == "pairwise" and conf["on"] == "sdr"):
        ok &= score > 0
    return ok


def _pairwise(db: Features, query: Features | None, conf):
    from vpr.baselines.pairwise import pairwise

    attr = "sdr" if conf["on"] == "sdr" else "desc"
    a = _need(db, attr, "pairwise", "database")
    b = None if query is None else _need(query, attr, "pairwise", "query")
    n_q = len(db) if query is None else len(query)
    top_k = _top_k_or_dense(len(db), n_q, conf["top_k"]) if attr == "sdr" else None
    S = pairwise(a, b, metric=conf["metric"], top_k=top_k)
    best, score = best_matches(S)
    return S, best, score


def _mask_recent(S, exclude: int):
    """Keep only pairs (i, j) with i <= j - exclude: earlier frames, far enough back."""
    exclude = max(int(exclude), 1)
    if sp.issparse(S):
        C = sp.coo_matrix(S)
        keep = C.row <= C.col - exclude
        return sp.csr_matrix((C.data[keep], (C.row[keep], C.col[keep])), shape=S.shape)
    S = np.array(S, dtype=np.float32, copy=True)
    i, j = np.indices(S.shape)
    S[i > j - exclude] = -np.inf
    return S


def loops(method: str, seq: Features, exclude: int = 1, conf: dict | None = None,
          progress: bool = False) -> MatchResult:
    """Loop closures within one traverse: for each frame, the best earlier frame.

    Only pairs ``i <= j - exclude`` are candidates (``exclude >= 1``); other
    entries of the returned similarity are ``-inf`` (dense) or absent (sparse).
    rSHOSM learns while it runs, as in the paper.
    """
    if int(exclude) < 1:
        raise ValueError(f"exclude must be >= 1, got {exclude}")
    conf = merge_conf(method, conf)
    t = time.perf_counter()
    accepted = None
    n = len(seq)
    if method == "rshosm":
        mem_kw = {k: conf[k] for k in SequenceMemory().get_params()}
        codes = SequenceMemory(**mem_kw).run(_need(seq, "sdr", method, "sequence"), progress=progress)
        S = similarity.overlap(codes, top_k=_top_k_or_dense(n, n, conf["top_k"]))
    elif method == "seqslam":
        from vpr.baselines.seqslam import difference_matrix

        x = _seqslam_descriptors(seq, conf, "sequence")
        D = difference_matrix(x, x, metric=conf["metric"])
        # recent frames must not win the sequence search: give them the worst difference
        i, j = np.indices(D.shape)
        D[np.abs(i - j) < exclude] = D.max()
        S, _, _, accepted = _run_seqslam(D, conf)
    else:
        S, _, _ = _pairwise(seq, None, conf)
    S = _mask_recent(S, exclude)
    best, score = best_matches(S)
    if accepted is None:
        accepted = _evidence(method, conf, best, score)
    else:
        accepted = np.asarray(accepted, bool) & np.isfinite(score)
    best[~np.isfinite(score)] = -1
    return MatchResult(method, S, best, score, accepted, time.perf_counter() - t, conf)
