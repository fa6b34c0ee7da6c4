"""Place-recognition methods behind one interface: rSHOSM, SeqSLAM and pairwise.

``rshosm`` is the paper's memory: winner codes compared by overlap.
``rshosm-seq`` is our extension for matching a query traverse against a
learned database (:meth:`vpr.memory.SequenceMemory.evidence`): the same learned
memory, but the query's feed-forward overlaps and predictions are graded
evidence accumulated along the learned connections in both directions, and
each query's scores are standardised (``normalise="query"``); see
``docs/experiments.md`` for what each part contributes on Nordland.

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
    # stay / skip < 0 disable those transitions; threshold 0.75 (paper: 0.25) keeps a database
    # frame from reusing minicolumns sampled from other frames (docs/experiments.md)
    "rshosm-seq": {**SequenceMemory().get_params(), "threshold": 0.75, "decay": 0.9, "stay": 0.05,
                   "skip": 0.05, "direction": "both", "normalise": "query"},
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


def _normalise_columns(S: np.ndarray, how: str) -> np.ndarray:
    """Standardise every query column of a dense S in place (``how="query"``) or leave it."""
    if how == "none":
        return S
    if how != "query":
        raise ValueError(f"rshosm-seq: normalise must be 'query' or 'none', got {how!r}")
    # each query's evidence has its own scale (how well that winter frame matches anything);
    # z-scores make one threshold mean the same for every query, as SeqSLAM's enhancement does
    for c0 in range(0, S.shape[1], 1024):
        blk = S[:, c0:c0 + 1024]
        sd = blk.std(axis=0)
        blk -= blk.mean(axis=0)
        blk /= np.where(sd > 0, sd, 1.0)
    return S


def _rshosm_seq(conf, db_sdr, q_sdr, progress):
    """Learn ``db_sdr``, then the graded sequence evidence of ``q_sdr``."""
    n_db, n_q = db_sdr.shape[0], q_sdr.shape[0]
    if n_db * n_q > DENSE_PAIRS_LIMIT:
        raise ValueError(f"rshosm-seq builds a dense {n_db} x {n_q} matrix, above the limit of "
                         f"{DENSE_PAIRS_LIMIT} pairs; split the traverses")
    mem = SequenceMemory(**{k: conf[k] for k in SequenceMemory().get_params()})
    db_codes = mem.run(db_sdr, progress=progress)
    mem.reset()
    opt = lambda v: None if float(v) < 0 else float(v)  # noqa: E731
    S = mem.evidence(q_sdr, db_codes, decay=conf["decay"], stay=opt(conf["stay"]),
                     skip=opt(conf["skip"]), direction=conf["direction"], progress=progress)
    return _normalise_columns(S, conf["normalise"])


def _top_k_or_dense(n_db, n_q, top_k):
    return top_k if n_db * n_q > DENSE_PAIRS_LIMIT else None


def _seqslam_descriptors(feat: Features, conf: dict, role: str):
    return _need(feat, "pixels" if conf["descriptor"] == "pixel" else "desc", "seqslam", role)


def _check_dense(method: str, n_db: int, n_q: int) -> None:
    # SeqSLAM's contrast enhancement and trajectory search need the whole difference matrix
    if n_db * n_q > DENSE_PAIRS_LIMIT:
        raise ValueError(f"{method} needs a dense {n_db} x {n_q} difference matrix "
                         f"({n_db * n_q * 4 / 2**30:.1f} GiB); subsample the traverses (--step)")


def _run_seqslam(D, conf):
    from vpr.baselines.seqslam import seqslam

    kw = {k: conf[k] for k in ("ds", "v_min", "v_max", "v_step", "R", "rwindow", "ratio_threshold", "causal")}
    res = seqslam(D, **kw)
    return res.similarity, res.best_db.astype(np.int64), -res.best_score.astype(np.float64), res.accepted


def _warm_up(method: str) -> None:
    """Compile (or load from numba's cache) the method's kernels outside the timed region.

    The first run after an install otherwise spends seconds compiling, which
    would be reported as the method's matching time.
    """
    from vpr import sdr

    if method.startswith("rshosm"):
        tiny = sdr.from_indices([[0, 1, 2, 3]] * 2, 64)
        mem = SequenceMemory(n_inputs=64, cells_per_column=2, new_columns=1)
        codes = mem.run(tiny)
        if method == "rshosm-seq":
            mem.evidence(tiny, codes)
    else:  # SeqSLAM's difference matrix and pairwise SAD share one compiled kernel
        similarity.mean_abs_diff(np.zeros((2, 2), np.float32))


def match(method: str, db: Features, query: Features, conf: dict | None = None,
          progress: bool = False) -> MatchResult:
    """Match every query frame against the database traverse with ``method``."""
    conf = merge_conf(method, conf)
    _warm_up(method)
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
    elif method == "rshosm-seq":
        S = _rshosm_seq(conf, _need(db, "sdr", method, "database"), _need(query, "sdr", method, "query"), progress)
        best, score = best_matches(S)
    elif method == "seqslam":
        from vpr.baselines.seqslam import difference_matrix

        _check_dense(method, len(db), len(query))
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
    if attr != "sdr":
        _check_dense("pairwise comparison of dense descriptors", len(db), n_q)
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
    if method == "rshosm-seq":
        # within one traverse every frame's own evidence leaks, through the stay/skip and
        # backward paths, onto the frames just before it, which loop closure must not see
        raise ValueError("rshosm-seq matches a query traverse against a database; "
                         "for loop closure within one traverse use rshosm")
    conf = merge_conf(method, conf)
    _warm_up(method)
    t = time.perf_counter()
    accepted = None
    n = len(seq)
    if method == "rshosm":
        mem_kw = {k: conf[k] for k in SequenceMemory().get_params()}
        codes = SequenceMemory(**mem_kw).run(_need(seq, "sdr", method, "sequence"), progress=progress)
        S = similarity.overlap(codes, top_k=_top_k_or_dense(n, n, conf["top_k"]))
    elif method == "seqslam":
        from vpr.baselines.seqslam import difference_matrix

        _check_dense(method, n, n)
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
