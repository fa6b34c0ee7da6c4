"""The verifier: the top candidates of a similarity matrix, checked by ORB matches and two-view RANSAC."""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from tqdm import tqdm

from vpr.checks import check_choice, check_float, check_int, check_similarity
from vpr.config import merge_conf
from vpr.types import MatchResult

from .features import Keypoints, extract_features, match_features
from .rerank import rerank, top_candidates
from .twoview import MODELS, check_seed, two_view_inliers

__all__ = ["Verifier", "VerifyResult"]


@dataclass(frozen=True, eq=False)
class VerifyResult:
    """Outcome of :meth:`Verifier.verify`; -1 pads queries with fewer than N candidates.

    Attributes
    ----------
    candidates : numpy.ndarray, intp (n_q, N)
        Database indices ordered by ``S``, best first.
    inliers : numpy.ndarray, int64 (n_q, N)
        RANSAC inlier counts.
    best_db : numpy.ndarray, intp (n_q,)
        The candidate with the most inliers, ties by ``S`` order.
    accepted : numpy.ndarray, bool (n_q,)
        Its inlier count >= ``min_inliers``.
    score : numpy.ndarray, float64 (n_q,)
        Its inlier count (-inf: no candidate).
    n_db : int
    """

    candidates: np.ndarray
    inliers: np.ndarray
    best_db: np.ndarray
    accepted: np.ndarray
    score: np.ndarray
    n_db: int

    def reranked(self, S):
        """``S`` (the matrix the candidates came from) re-ordered by inliers within each query's candidates.

        The verified similarity to evaluate and compare with ``S``: see :func:`rerank`.
        """
        return rerank(S, self.candidates, self.inliers)

    def result(self, res: MatchResult, seconds: float) -> MatchResult:
        """The verified twin of a method's ``res`` (named ``METHOD+verify``): its matrix :meth:`reranked`, each
        query's best match the candidate of most inliers (scored in that matrix), accepted with ``min_inliers``;
        ``seconds``: the method's and the verification's."""
        S = self.reranked(res.similarity)
        cols = np.arange(self.best_db.size)
        at = np.asarray(S[np.maximum(self.best_db, 0), cols], dtype=np.float64).ravel()
        score = np.where(self.best_db >= 0, at, -np.inf)
        return MatchResult(res.method + "+verify", S, self.best_db, score, self.accepted, seconds, res.conf)

    def similarity(self) -> sp.csc_matrix:
        """Inlier-only similarity, sparse n_db x n_q: the candidates and nothing else.

        Not comparable with the unverified matrix (every other pair is missing); use :meth:`reranked` for that.

        Each candidate's entry is its inlier count plus a bonus in (0, 1) that decreases with its rank under ``S``, so
        the ordering of every column -- and hence the best entry -- matches ``best_db``; non-candidates are not
        stored. With ``matching="single"`` the precision-recall curve then sweeps the inlier threshold.
        """
        n_q, n = self.candidates.shape
        q, r = np.nonzero(self.candidates >= 0)
        vals = self.inliers[q, r] + (n - r) / (n + 1.0)
        return sp.csc_matrix((vals, (self.candidates[q, r], q)), shape=(self.n_db, n_q))


ImageSource = Callable[[int], np.ndarray] | Sequence[np.ndarray]


class Verifier:
    """Geometric verification of the top candidates of a similarity matrix.

    Parameters
    ----------
    db_images, q_images : callable or sequence
        ``i -> image`` callables or sequences of images (:func:`extract_features`); sequences let :meth:`verify` check
        ``S``'s shape.
    **conf
        Over ``Verifier.default_conf`` (:func:`vpr.config.merge_conf`): ``n_features`` ORB keypoints per image;
        ``model`` and ``max_error, seed, max_trials`` as :func:`two_view_inliers`; ``ratio``, ``mutual`` and
        ``distinct`` as :func:`match_features` (distinct: a pattern repeated within an image, such as a crossing's
        stripes, matches nothing); ``min_side`` as :func:`extract_features`; ``min_inliers`` the best candidate needs;
        ``cache``: keep each image's features after first use (about 48 kB at 1000 features); ``max_cached``: at most
        this many images' per side, the least recently used dropped (0: every image); ``missing``: an image given as
        None is an error (``"error"``) or has no keypoints (``"blind"``).
    """

    default_conf = {"n_features": 1000, "model": "fundamental", "ratio": 0.8, "min_inliers": 15, "cache": True,
                    "max_error": 4.0, "seed": 0, "max_trials": 2000, "mutual": True, "min_side": 240,
                    "distinct": False, "max_cached": 0, "missing": "error"}

    def __init__(self, db_images: ImageSource, q_images: ImageSource, **conf):
        self._db = self._check_images(db_images, "db_images")
        self._q = self._check_images(q_images, "q_images")
        # strings (from a command line) are read as the default's type, then every value is checked
        self.conf = c = merge_conf(self.default_conf, conf, "verifier", nullable=("seed",))
        self.n_features = check_int(c["n_features"], "n_features", 1)
        self.model = check_choice(c["model"], "model", MODELS)
        self.ratio = check_float(c["ratio"], "ratio", 0.0, 1.0, open_min=True)
        self.min_inliers = check_int(c["min_inliers"], "min_inliers", 0)
        self.cache = c["cache"]
        self.max_error = check_float(c["max_error"], "max_error", 0.0, open_min=True)
        check_seed(c["seed"])
        self.seed = c["seed"]
        self.max_trials = check_int(c["max_trials"], "max_trials", 1)
        self.mutual = c["mutual"]
        self.distinct = bool(c["distinct"])
        self.min_side = check_int(c["min_side"], "min_side", 1)
        self.max_cached = check_int(c["max_cached"], "max_cached", 0)
        self.missing_blind = check_choice(c["missing"], "missing", ("error", "blind")) == "blind"
        self._cache = {"database": OrderedDict(), "query": OrderedDict()}
        if self._db is self._q:  # one sequence (a stream against itself): each image's features once
            self._cache["query"] = self._cache["database"]
        # (db, query) -> inliers: several methods often propose the same candidates
        self._pairs: dict[tuple[int, int], int] = {}

    @staticmethod
    def _check_images(images, name):
        if callable(images):
            return images
        if hasattr(images, "__getitem__") and hasattr(images, "__len__"):
            return images
        raise ValueError(f"{name} must be a callable i -> image or a sequence of images, "
                         f"got {type(images).__name__}")

    def _features(self, which: str, images, i: int) -> Keypoints:
        store = self._cache[which]
        f = store.get(i)
        if f is None:
            name = f"{which} image {i}"
            img = images(i) if callable(images) else images[i]
            if img is None and not self.missing_blind:
                raise ValueError(f"{name}: could not be loaded (got None)")
            f = Keypoints.empty() if img is None else extract_features(img, self.n_features, self.min_side, name=name)
            if self.cache:
                store[i] = f
                if self.max_cached and len(store) > self.max_cached:  # the least recently used goes
                    store.popitem(last=False)
        else:
            store.move_to_end(i)
        return f

    def db_features(self, i: int) -> Keypoints:
        """Keypoints of database image ``i`` (computed on first use when caching)."""
        return self._features("database", self._db, int(i))

    def query_features(self, j: int) -> Keypoints:
        """Keypoints of query image ``j`` (computed on first use when caching)."""
        return self._features("query", self._q, int(j))

    def pair_inliers(self, db_index: int, q_index: int) -> int:
        """RANSAC inliers between database image ``db_index`` and query ``q_index``."""
        key = (int(db_index), int(q_index))
        n = self._pairs.get(key)
        if n is None:
            fd, fq = self.db_features(db_index), self.query_features(q_index)
            m = match_features(fq, fd, self.ratio, self.mutual, self.distinct)
            n = two_view_inliers(fq, fd, m, self.model, self.max_error, self.seed, self.max_trials)
            if self.cache:
                self._pairs[key] = n
        return n

    def verify(self, S, n_candidates: int, progress: bool = True) -> VerifyResult:
        """Verify each query's ``n_candidates`` best database entries under ``S`` (sparse: stored, not ``-inf``).

        Returns a :class:`VerifyResult`; ``n_candidates < 1``, a bad ``S`` (not 2-D, NaN, shape unlike the image
        sequences') or an unreadable image raise ValueError. ``progress``: a tqdm bar over the queries.
        """
        n_candidates = check_int(n_candidates, "n_candidates", 1)
        S = check_similarity(S, sparse_format="csc")
        n_db, n_q = S.shape
        for images, n, what, axis in ((self._db, n_db, "db_images", "rows"),
                                      (self._q, n_q, "q_images", "columns")):
            if not callable(images) and len(images) != n:
                raise ValueError(f"S has {n} {axis} (shape {S.shape}) but {what} has {len(images)} images")
        cand = top_candidates(S, n_candidates)
        inl = np.full(cand.shape, -1, dtype=np.int64)

        for j in tqdm(range(n_q), desc="verify", unit="query", disable=not progress):
            if cand[j, 0] < 0:
                continue
            for r, i in enumerate(cand[j]):
                if i < 0:
                    break
                inl[j, r] = self.pair_inliers(i, j)

        # argmax returns the first maximum, i.e. ties go to the candidate S ranks higher
        best_r = np.argmax(inl, axis=1)
        rows = np.arange(n_q)
        has = cand[:, 0] >= 0
        best_db = np.where(has, cand[rows, best_r], -1)
        best_inl = inl[rows, best_r]
        score = np.where(has, best_inl.astype(np.float64), -np.inf)
        accepted = has & (best_inl >= self.min_inliers)
        return VerifyResult(cand, inl, best_db, accepted, score, n_db)
