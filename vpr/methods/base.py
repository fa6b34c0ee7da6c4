"""What every place-recognition method shares: inputs, result, size limit and the base class.

A method is a small class (:class:`Method`) with a ``name``, a ``default_conf``
that user configuration is merged into (:func:`vpr.config.merge_conf`: unknown
keys are an error, strings are coerced to the default's type), and two entry
points: :meth:`Method.match` compares a query traverse with a database
traverse, :meth:`Method.loops` finds loop closures within one traverse (only
earlier frames, at least ``exclude`` frames back). Both take encoded traverses
(:class:`EncodedTraverse`) and return a :class:`MatchResult`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from vpr.config import merge_conf
from vpr.similarity import DENSE_PAIRS_LIMIT

__all__ = ["DENSE_PAIRS_LIMIT", "EncodedTraverse", "MatchResult", "Method", "best_matches", "check_dense",
           "need", "top_k_or_dense"]

# DENSE_PAIRS_LIMIT (one limit, in vpr.similarity): above this many database x query pairs
# similarity matrices are top-K sparse, and methods that need the whole dense matrix refuse to run.


@dataclass
class EncodedTraverse:
    """An encoded traverse: frame names, SDR batch (frames x bits), dense descriptors, SeqSLAM pixels.

    Each method needs some of them (it says which when one is missing).
    """

    names: list
    sdr: sp.csr_matrix | None = None
    desc: np.ndarray | None = None
    pixels: np.ndarray | None = None

    def __len__(self):
        return len(self.names)


@dataclass
class MatchResult:
    """Database x query similarity (dense, or top-K sparse), best database frame per query, its score,
    the accept decision, the matching time in seconds and the conf used."""

    method: str
    similarity: np.ndarray | sp.csr_matrix
    best_db: np.ndarray
    score: np.ndarray
    accepted: np.ndarray
    seconds: float
    conf: dict = field(default_factory=dict)


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


def need(feat: EncodedTraverse, attr: str, method: str, role: str):
    """``feat.<attr>``, or a ValueError saying that ``method`` needs it for the ``role`` traverse."""
    value = getattr(feat, attr)
    if value is None:
        what = {"sdr": "SDRs", "desc": "dense descriptors", "pixels": "SeqSLAM pixel descriptors"}[attr]
        raise ValueError(f"{method} needs {what} of the {role} traverse, but the encoder produced none")
    return value


def top_k_or_dense(n_db: int, n_q: int, top_k: int) -> int | None:
    """``top_k`` when a dense ``n_db x n_q`` matrix would exceed :data:`DENSE_PAIRS_LIMIT`, else None."""
    return top_k if n_db * n_q > DENSE_PAIRS_LIMIT else None


def check_dense(what: str, n_db: int, n_q: int, hint: str = "subsample the traverses (--step)") -> None:
    """Refuse a dense ``n_db x n_q`` matrix above :data:`DENSE_PAIRS_LIMIT` (before any work is done)."""
    if n_db * n_q > DENSE_PAIRS_LIMIT:
        raise ValueError(f"{what} needs a dense {n_db} x {n_q} matrix ({n_db * n_q * 4 / 2**30:.1f} GiB, above "
                         f"the limit of {DENSE_PAIRS_LIMIT} pairs); {hint}")


def mask_recent(S, exclude: int):
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


class Method:
    """A place-recognition method, configured once, run on encoded traverses.

    Subclasses set ``name`` and ``default_conf`` (``nullable_conf``: keys that
    also accept ``None``; ``no_loops_reason``: why loop closure is refused),
    and implement :meth:`_match` and, if they support loop closure,
    :meth:`_loops`; :meth:`check_size` refuses inputs too large for the method
    before any work is done and :meth:`warm_up` compiles its kernels outside
    the timed region.

    Parameters
    ----------
    **conf
        Overrides of ``default_conf``; strings are coerced to the default's type.
    """

    name: str = "base"
    default_conf: dict = {}
    nullable_conf: frozenset = frozenset()
    #: why :meth:`loops` is refused, for methods that do not override :meth:`_loops`
    no_loops_reason: str = ""

    def __init__(self, **conf):
        self.conf = merge_conf(self.default_conf, conf, self.name, nullable=self.nullable_conf)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({', '.join(f'{k}={v!r}' for k, v in self.conf.items())})"

    # ----------------------------------------------------------- to override
    def inputs(self) -> set[str]:
        """Which :class:`EncodedTraverse` fields the method reads (``"sdr"``, ``"desc"``, ``"pixels"``)."""
        raise NotImplementedError

    def check_size(self, n_db: int, n_q: int) -> None:
        """Raise ValueError if ``n_db x n_q`` is too large for this method (default: any size)."""

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) the method's kernels.

        The first run after an install otherwise spends seconds compiling,
        which would be reported as the method's matching time.
        """

    def accept(self, best: np.ndarray, score: np.ndarray) -> np.ndarray:
        """Accept a best match when there is one with a finite score (subclasses add their evidence test)."""
        return (best >= 0) & np.isfinite(score)

    def _match(self, db: EncodedTraverse, query: EncodedTraverse, progress: bool):
        """(similarity, best_db, score, accepted or None to use :meth:`accept`)."""
        raise NotImplementedError

    def _loops(self, seq: EncodedTraverse, exclude: int, progress: bool):
        """(similarity before masking, accepted or None to use :meth:`accept`); not overridden: unsupported."""
        raise NotImplementedError

    # ---------------------------------------------------------------- public
    def match(self, db: EncodedTraverse, query: EncodedTraverse, progress: bool = False) -> MatchResult:
        """Match every query frame against the database traverse."""
        self.check_size(len(db), len(query))
        self.warm_up()
        t = time.perf_counter()
        S, best, score, accepted = self._match(db, query, progress)
        if accepted is None:
            accepted = self.accept(best, score)
        return MatchResult(self.name, S, best, score, np.asarray(accepted, bool), time.perf_counter() - t,
                           dict(self.conf))

    def loops(self, seq: EncodedTraverse, exclude: int = 1, progress: bool = False) -> MatchResult:
        """Loop closures within one traverse: for each frame, the best earlier frame.

        Only pairs ``i <= j - exclude`` are candidates (``exclude >= 1``); other
        entries of the returned similarity are ``-inf`` (dense) or absent
        (sparse). Methods that cannot do this raise ValueError.
        """
        if int(exclude) < 1:
            raise ValueError(f"exclude must be >= 1, got {exclude}")
        if type(self)._loops is Method._loops:
            raise ValueError(self.no_loops_reason or f"{self.name} does not support loop closure within one traverse")
        self.check_size(len(seq), len(seq))
        self.warm_up()
        t = time.perf_counter()
        S, accepted = self._loops(seq, int(exclude), progress)
        S = mask_recent(S, exclude)
        best, score = best_matches(S)
        if accepted is None:
            accepted = self.accept(best, score)
        else:
            accepted = np.asarray(accepted, bool) & np.isfinite(score)
        best[~np.isfinite(score)] = -1
        return MatchResult(self.name, S, best, score, accepted, time.perf_counter() - t, dict(self.conf))
