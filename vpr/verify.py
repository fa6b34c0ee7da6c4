"""Geometric verification of place-recognition candidates.

For every query, the ``N`` database images it is most similar to (according
to a similarity matrix ``S``, database x query, higher = more similar) are
checked geometrically: ORB keypoints are matched (OpenCV brute force,
Hamming distance, Lowe's ratio test and a mutual-nearest-neighbour check) and
a two-view model -- a fundamental matrix or a homography -- is fitted with
pycolmap's LO-RANSAC. The number of RANSAC inliers re-ranks the candidates
and gates acceptance: a query is accepted only if its best candidate has at
least ``min_inliers`` inliers.

Coordinate frames
-----------------
ORB needs images of a few hundred pixels to find keypoints, while VPR
systems often work with tiny thumbnails (e.g. 64 x 32). Images whose
shorter side is below ``min_side`` are therefore upscaled before detection.
:class:`Keypoints` keeps keypoints in the *original* image's pixel
coordinates, plus the upscaling factor. RANSAC's ``max_error`` is measured in
the *detection* frame (the upscaled image), so the same threshold means the
same thing for thumbnails and for full-size frames; for images that were not
upscaled the two frames coincide.

Determinism
-----------
ORB and brute-force matching are deterministic. pycolmap's
``RANSACOptions.random_seed`` is set from ``seed`` and RANSAC runs on one
thread, so inlier counts are reproducible for a given seed (``seed=None``
draws a fresh random seed per call instead).
"""
from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import pycolmap
import scipy.sparse as sp

from vpr._checks import check_int, check_similarity
from vpr.config import merge_conf
from vpr.imageproc import to_grey

__all__ = [
    "Keypoints",
    "VerifyResult",
    "Verifier",
    "MODELS",
    "extract_features",
    "match_features",
    "two_view_inliers",
    "top_candidates",
    "rerank",
]

#: Two-view models understood by :func:`two_view_inliers`, with the minimum
#: number of matches each needs (fewer give 0 inliers).
MODELS = {"fundamental": 8, "homography": 4}

_DESCRIPTOR_BYTES = 32  # ORB descriptors are 256 bits


@dataclass(frozen=True, eq=False)
class Keypoints:
    """ORB keypoints and descriptors of one image.

    Attributes
    ----------
    xy : numpy.ndarray
        float64 (K, 2) keypoint positions (x, y) in the original image's pixel
        coordinates.
    descriptors : numpy.ndarray
        uint8 (K, 32) ORB descriptors, row ``k`` belongs to ``xy[k]``.
    scale : numpy.ndarray
        float64 (2,) factors (sx, sy) from the original image to the frame the
        keypoints were detected in (1 unless the image was upscaled).
    """

    xy: np.ndarray
    descriptors: np.ndarray
    scale: np.ndarray

    def __len__(self) -> int:
        return int(self.xy.shape[0])

    def detection_xy(self) -> np.ndarray:
        """Keypoint positions in the detection (possibly upscaled) frame, (K, 2) float64."""
        # pixel centres: cv2.resize maps x_orig to (x_orig + 0.5) * s - 0.5
        return (self.xy + 0.5) * self.scale - 0.5


# --------------------------------------------------------------------------- #
# argument checks
# --------------------------------------------------------------------------- #


def _check_positive(value, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return float(value)


def _check_ratio(ratio) -> float:
    if isinstance(ratio, bool) or not isinstance(ratio, numbers.Real) or not 0 < ratio <= 1:
        raise ValueError(f"ratio must be in (0, 1], got {ratio!r}")
    return float(ratio)


def _check_model(model) -> str:
    if model not in MODELS:
        raise ValueError(f"model must be one of {sorted(MODELS)}, got {model!r}")
    return model


def _check_seed(seed) -> int:
    if seed is None:
        return -1  # pycolmap: non-deterministic seed
    return check_int(seed, "seed", 0)


def _check_features(f, name: str) -> Keypoints:
    if not isinstance(f, Keypoints):
        raise ValueError(f"{name} must be a Keypoints object (see extract_features), got {type(f).__name__}")
    return f


# --------------------------------------------------------------------------- #
# features, matching, two-view geometry
# --------------------------------------------------------------------------- #
def extract_features(image, n_features: int = 1000, min_side: int = 240, name: str = "image") -> Keypoints:
    """Detect ORB keypoints and compute their descriptors.

    Parameters
    ----------
    image : array_like
        Grey (H, W) or BGR/BGRA (H, W, C) image of any size and of any dtype
        accepted by :func:`vpr.imageproc.to_grey`.
    n_features : int
        Maximum number of keypoints ORB keeps.
    min_side : int
        Images whose shorter side is smaller are upscaled (bilinear) so that
        it equals ``min_side`` before detection; keypoints are mapped back to
        the original pixel coordinates (see the module docstring).
    name : str
        Used in error messages, e.g. ``"query image 12"``.

    Returns
    -------
    Keypoints
        Possibly empty: an image without texture (e.g. blank) gives K = 0.

    Raises
    ------
    ValueError
        Invalid image (message starts with ``name``) or parameters.
    """
    n_features = check_int(n_features, "n_features", 1)
    min_side = check_int(min_side, "min_side", 1)
    grey = to_grey(image, name)
    h, w = grey.shape
    if min(h, w) < min_side:
        f = min_side / min(h, w)
        size = (max(1, round(w * f)), max(1, round(h * f)))
        grey = cv2.resize(grey, size, interpolation=cv2.INTER_LINEAR)
    scale = np.array([grey.shape[1] / w, grey.shape[0] / h], dtype=np.float64)
    orb = cv2.ORB_create(nfeatures=n_features)
    keypoints, desc = orb.detectAndCompute(grey, None)
    if desc is None or len(keypoints) == 0:
        return Keypoints(np.zeros((0, 2)), np.zeros((0, _DESCRIPTOR_BYTES), np.uint8), scale)
    xy_det = np.array([kp.pt for kp in keypoints], dtype=np.float64).reshape(-1, 2)
    xy = (xy_det + 0.5) / scale - 0.5
    return Keypoints(xy, np.ascontiguousarray(desc, dtype=np.uint8), scale)


def match_features(f1: Keypoints, f2: Keypoints, ratio: float = 0.8, mutual: bool = True) -> np.ndarray:
    """Match ORB descriptors by Hamming distance with Lowe's ratio test.

    Parameters
    ----------
    f1, f2 : Keypoints
        Keypoints of the two images.
    ratio : float
        A match ``i -> j`` is kept if its distance is below ``ratio`` times
        the distance to ``f1``'s second-nearest neighbour in ``f2``. When
        ``f2`` has a single descriptor there is no second neighbour and the
        test passes.
    mutual : bool
        Also require ``i`` to be the nearest neighbour of ``j`` in ``f1``,
        which removes many-to-one matches onto repetitive texture.

    Returns
    -------
    numpy.ndarray
        intp (M, 2) index pairs ``(i, j)`` into ``f1`` and ``f2``, sorted by
        ``i``; (0, 2) when nothing matches.
    """
    f1 = _check_features(f1, "f1")
    f2 = _check_features(f2, "f2")
    ratio = _check_ratio(ratio)
    empty = np.zeros((0, 2), dtype=np.intp)
    if len(f1) == 0 or len(f2) == 0:
        return empty
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=False)
    pairs = []
    for knn in matcher.knnMatch(f1.descriptors, f2.descriptors, k=2):
        if not knn:
            continue
        best = knn[0]
        if len(knn) > 1 and not best.distance < ratio * knn[1].distance:
            continue
        pairs.append((best.queryIdx, best.trainIdx))
    if not pairs:
        return empty
    out = np.array(pairs, dtype=np.intp)
    if mutual:
        reverse = np.full(len(f2), -1, dtype=np.intp)
        for m in matcher.match(f2.descriptors, f1.descriptors):
            reverse[m.queryIdx] = m.trainIdx
        out = out[reverse[out[:, 1]] == out[:, 0]]
    return out[np.argsort(out[:, 0], kind="stable")]


def _ransac_options(max_error: float, seed: int, max_trials: int) -> pycolmap.RANSACOptions:
    opts = pycolmap.RANSACOptions()
    opts.max_error = max_error
    opts.random_seed = seed
    # colmap's default (100000 trials) makes a wrong candidate, whose matches
    # are nearly all outliers, cost ~1 s; a few thousand trials still find a
    # true pair's model, which has a high inlier ratio.
    opts.max_num_trials = max_trials
    opts.min_num_trials = min(opts.min_num_trials, max_trials)
    opts.num_threads = 1  # determinism
    return opts


def two_view_inliers(f1: Keypoints, f2: Keypoints, matches, model: str = "fundamental",
                     max_error: float = 4.0, seed: int | None = 0, max_trials: int = 2000) -> int:
    """Number of matches consistent with one two-view model (pycolmap LO-RANSAC).

    Parameters
    ----------
    f1, f2 : Keypoints
        Keypoints of the two images.
    matches : array_like
        (M, 2) integer index pairs into ``f1`` and ``f2``, e.g. from
        :func:`match_features`.
    model : {"fundamental", "homography"}
        ``"fundamental"`` (pycolmap ``estimate_fundamental_matrix``, any
        static 3-D scene) or ``"homography"`` (``estimate_homography_matrix``,
        planar or distant scenes, pure rotation; stricter, so unrelated image
        pairs get fewer chance inliers).
    max_error : float
        RANSAC inlier threshold in pixels of the detection frame (see the
        module docstring).
    seed : int or None
        RANSAC random seed; ``None`` for a non-deterministic one.
    max_trials : int
        Upper bound on RANSAC iterations.

    Returns
    -------
    int
        Inlier count; 0 with fewer than 8 (fundamental) or 4 (homography)
        matches, or when the estimation fails.
    """
    f1 = _check_features(f1, "f1")
    f2 = _check_features(f2, "f2")
    model = _check_model(model)
    max_error = _check_positive(max_error, "max_error")
    seed = _check_seed(seed)
    max_trials = check_int(max_trials, "max_trials", 1)
    m = np.asarray(matches)
    if m.size == 0:
        return 0
    if m.ndim != 2 or m.shape[1] != 2 or m.dtype.kind not in "iu":
        raise ValueError(f"matches must be an integer (M, 2) array, got shape {m.shape} dtype {m.dtype}")
    if m.min() < 0 or m[:, 0].max() >= len(f1) or m[:, 1].max() >= len(f2):
        raise ValueError(f"matches index outside f1 ({len(f1)} keypoints) or f2 ({len(f2)} keypoints)")
    if len(m) < MODELS[model]:
        return 0
    p1 = np.ascontiguousarray(f1.detection_xy()[m[:, 0]])
    p2 = np.ascontiguousarray(f2.detection_xy()[m[:, 1]])
    opts = _ransac_options(max_error, seed, max_trials)
    if model == "fundamental":
        result = pycolmap.estimate_fundamental_matrix(p1, p2, opts)
    else:
        result = pycolmap.estimate_homography_matrix(p1, p2, opts)
    if result is None:
        return 0
    return int(result["num_inliers"])


# --------------------------------------------------------------------------- #
# candidate selection
# --------------------------------------------------------------------------- #
def _rank(rows: np.ndarray, vals: np.ndarray, n: int) -> np.ndarray:
    """The ``n`` rows with the highest values, ties by lower row, as a -1 padded (n,) array."""
    out = np.full(n, -1, dtype=np.intp)
    keep = vals > -np.inf  # -inf means "never matched" (vpr.evaluate convention)
    rows, vals = rows[keep], vals[keep]
    if len(rows) > n:
        # only entries at least as good as the n-th best can be chosen; keeping
        # all ties of the n-th value lets lexsort break them by row
        kth = -np.partition(-vals, n - 1)[n - 1]
        sel = vals >= kth
        rows, vals = rows[sel], vals[sel]
    order = np.lexsort((rows, -vals))[:n]
    out[:len(order)] = rows[order]
    return out


def top_candidates(S, n_candidates: int) -> np.ndarray:
    """Each query's ``n_candidates`` most similar database entries.

    Parameters
    ----------
    S : array_like or scipy.sparse matrix
        Similarity, database x query, higher = more similar. For a sparse
        matrix only stored entries are candidates; entries equal to ``-inf``
        are never candidates.
    n_candidates : int
        Candidates per query (>= 1).

    Returns
    -------
    numpy.ndarray
        intp (n_q, n_candidates) database indices in decreasing similarity,
        ties by lower index; padded with -1 when a query has fewer candidates.
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

    For query ``j`` the values ``S[candidates[j], j]`` are sorted in
    decreasing order and handed out again, the highest to the candidate with
    the most inliers, the next to the second, and so on (equal inlier counts
    keep the order under ``S``). So the column holds the same set of values as
    before, its verified candidates still sit above all its other entries
    (they were its ``N`` best), and the pairs that were not verified keep their
    scores. Average precision with and without verification then measures the
    same ranking, changed only where verification disagreed with ``S``; it is
    identical when the inlier order equals the ``S`` order.

    Why not scores made from inliers: inlier counts and similarities are on
    unrelated scales, and giving only the candidates new scores drops every
    other pair below them (or out of the matrix), which is what made the
    verified AP incomparable before.

    Parameters
    ----------
    S : array_like or scipy.sparse matrix
        Similarity, database x query (n_db x n_q), higher = more similar.
    candidates : array_like of int, (n_q, N)
        Database rows per query (as from :func:`top_candidates`), -1 for padding.
        For a sparse ``S`` every candidate must be a stored entry.
    inliers : array_like of int, (n_q, N)
        Inlier count of each candidate; padding is ignored.

    Returns
    -------
    numpy.ndarray (float64) or scipy.sparse.csc_matrix (float64)
        A new matrix of ``S``'s kind and shape.

    Raises
    ------
    ValueError
        Shapes disagree, a candidate is out of range, repeated within a query or
        (sparse) not stored, or a candidate's ``S`` value is ``-inf``.
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
    # candidate k of each query, ordered by inliers (more first), ties by S (higher first) then by the
    # candidates' order, padding last
    neg_inl = np.where(valid, -inl.astype(np.int64), np.iinfo(np.int64).max)
    order = np.lexsort((np.broadcast_to(np.arange(cand.shape[1]), cand.shape), -vals, neg_inl), axis=-1)
    ranked_vals = -np.sort(-vals, axis=1)      # the same values, best first; padding (-inf) last
    new = np.full(cand.shape, -np.inf)
    np.put_along_axis(new, order, ranked_vals, axis=1)
    data[pos] = new[q, r]
    return out


# --------------------------------------------------------------------------- #
# verifier
# --------------------------------------------------------------------------- #
@dataclass(frozen=True, eq=False)
class VerifyResult:
    """Outcome of :meth:`Verifier.verify`.

    Attributes
    ----------
    candidates : numpy.ndarray
        intp (n_q, N) database indices ordered by ``S`` (best first); -1 pads
        queries with fewer than N candidates.
    inliers : numpy.ndarray
        int64 (n_q, N) RANSAC inlier counts, -1 at padding.
    best_db : numpy.ndarray
        intp (n_q,) candidate with the most inliers, ties by ``S`` order; -1
        for a query without candidates.
    accepted : numpy.ndarray
        bool (n_q,) ``best`` inlier count >= ``min_inliers``.
    score : numpy.ndarray
        float64 (n_q,) inlier count of ``best_db``; -inf for a query without
        candidates. Thresholding it sweeps ``min_inliers``.
    n_db : int
        Number of database entries (rows of ``S``).
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

    def similarity(self) -> sp.csc_matrix:
        """Inlier-only similarity, sparse n_db x n_q: the candidates and nothing else.

        Not comparable with the unverified matrix (every other pair is
        missing); use :meth:`reranked` for that.

        Each candidate's entry is its inlier count plus a bonus in (0, 1)
        that decreases with its rank under ``S``, so the ordering of every
        column -- and hence the best entry -- matches ``best_db``;
        non-candidates are not stored. With ``matching="single"`` the
        precision-recall curve then sweeps the inlier threshold.
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
        ``i -> image`` callables, or sequences (lists, stacked arrays) of
        images; any layout accepted by :func:`extract_features`. Sequences
        also let :meth:`verify` check the shape of ``S``.
    **conf
        Overrides of ``Verifier.default_conf``, merged by
        :func:`vpr.config.merge_conf` (unknown keys raise; strings are read as
        the default's type):
    n_features : int
        ORB keypoints per image.
    model : {"fundamental", "homography"}
        Two-view model, see :func:`two_view_inliers`.
    ratio : float
        Lowe ratio, see :func:`match_features`.
    min_inliers : int
        Inliers the best candidate needs for the query to be accepted.
    cache : bool
        Keep every image's features after first use, so each image is
        processed once even across several :meth:`verify` calls (about
        48 kB per image at 1000 features). Without it, database features are
        recomputed for every query that lists them.
    max_error, seed, max_trials
        RANSAC settings, see :func:`two_view_inliers`.
    mutual : bool
        Mutual nearest-neighbour check, see :func:`match_features`.
    min_side : int
        Upscaling threshold, see :func:`extract_features`.
    """

    default_conf = {"n_features": 1000, "model": "fundamental", "ratio": 0.8, "min_inliers": 15, "cache": True,
                    "max_error": 4.0, "seed": 0, "max_trials": 2000, "mutual": True, "min_side": 240}

    def __init__(self, db_images: ImageSource, q_images: ImageSource, **conf):
        self._db = self._check_images(db_images, "db_images")
        self._q = self._check_images(q_images, "q_images")
        # strings (from a command line) are read as the default's type, then every value is checked
        self.conf = c = merge_conf(self.default_conf, conf, "verifier", nullable=("seed",))
        self.n_features = check_int(c["n_features"], "n_features", 1)
        self.model = _check_model(c["model"])
        self.ratio = _check_ratio(c["ratio"])
        self.min_inliers = check_int(c["min_inliers"], "min_inliers", 0)
        self.cache = c["cache"]
        self.max_error = _check_positive(c["max_error"], "max_error")
        _check_seed(c["seed"])
        self.seed = c["seed"]
        self.max_trials = check_int(c["max_trials"], "max_trials", 1)
        self.mutual = c["mutual"]
        self.min_side = check_int(c["min_side"], "min_side", 1)
        self._cache = {"database": {}, "query": {}}
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
            if img is None:
                raise ValueError(f"{name}: could not be loaded (got None)")
            f = extract_features(img, self.n_features, self.min_side, name=name)
            if self.cache:
                store[i] = f
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
            n = self._inliers(self.db_features(db_index), self.query_features(q_index))
            if self.cache:
                self._pairs[key] = n
        return n

    def _inliers(self, fd: Keypoints, fq: Keypoints) -> int:
        m = match_features(fq, fd, self.ratio, self.mutual)
        return two_view_inliers(fq, fd, m, self.model, self.max_error, self.seed, self.max_trials)

    def verify(self, S, n_candidates: int, progress: bool = True) -> VerifyResult:
        """Verify each query's ``n_candidates`` best database entries under ``S``.

        Parameters
        ----------
        S : array_like or scipy.sparse matrix
            Similarity, database x query (n_db x n_q), higher = more similar.
            With a sparse (e.g. top-K) matrix only stored entries are
            candidates; ``-inf`` entries never are.
        n_candidates : int
            Candidates per query (>= 1).
        progress : bool
            Show a tqdm progress bar over the queries.

        Returns
        -------
        VerifyResult

        Raises
        ------
        ValueError
            ``n_candidates < 1``, ``S`` not 2-D or containing NaN, ``S``'s
            shape differs from the image sequences' lengths, or an image
            cannot be read.
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

        from tqdm import tqdm

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
