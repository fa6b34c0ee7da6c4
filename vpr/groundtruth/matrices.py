"""Ground-truth matrices from labels, frame numbers or positions, and the pairs a loop closure evaluates."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from vpr.checks import check_count, check_float
from vpr.similarity import candidate_limit

__all__ = ["gt_from_labels", "gt_from_frames", "gt_from_tolerance", "gt_from_positions", "loop_closure_mask",
           "loop_closure_gt", "any_true", "frame_rows"]


def _expand_ranges(starts, counts):
    """Concatenation of ``arange(s, s + c)`` for every (s, c), without a Python loop."""
    total = int(counts.sum())
    offsets = np.repeat(np.cumsum(counts) - counts, counts)
    return np.arange(total) - offsets + np.repeat(starts, counts)


def _csc_from_columns(row_idx, counts, shape):
    indptr = np.r_[0, np.cumsum(counts)].astype(np.int64)
    m = sp.csc_matrix((np.ones(len(row_idx), dtype=bool), row_idx, indptr), shape=shape)
    m.sort_indices()
    return m.tocsr()


def _check_labels(name, labels):
    a = np.asarray(labels)
    if a.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {a.shape}")
    if a.dtype.kind in "fc" and np.isnan(a).any():
        raise ValueError(f"{name} contains NaN")
    return a


def gt_from_labels(db_labels, q_labels, sparse=False):
    """Ground truth from place labels: ``gt[i, j] = db_labels[i] == q_labels[j]``.

    Parameters
    ----------
    db_labels : array_like, shape (n_db,)
    q_labels : array_like, shape (n_q,)
        Place identifiers (integers, strings, ...).
    sparse : bool
        Return a ``scipy.sparse.csr_matrix`` instead of a dense array.

    Returns
    -------
    gt : ndarray of bool or csr_matrix, shape (n_db, n_q)

    Raises
    ------
    ValueError
        If a label array is not 1-D or contains NaN.
    """
    db = _check_labels("db_labels", db_labels)
    q = _check_labels("q_labels", q_labels)
    # integer codes make the comparison cheap whatever the label type
    _, codes = np.unique(np.concatenate([db, q]), return_inverse=True)
    codes = codes.ravel()
    db_c, q_c = codes[: len(db)], codes[len(db):]
    if not sparse:
        return db_c[:, None] == q_c[None, :]
    order = np.argsort(db_c, kind="stable")
    sorted_c = db_c[order]
    lo = np.searchsorted(sorted_c, q_c, side="left")
    counts = np.searchsorted(sorted_c, q_c, side="right") - lo
    return _csc_from_columns(order[_expand_ranges(lo, counts)], counts, (len(db), len(q)))


def gt_from_frames(db_frames, q_frames, tol, sparse=False):
    """Ground truth from frame numbers: ``gt[i, j] = |db_frames[i] - q_frames[j]| <= tol``.

    For traverses aligned frame by frame (the same frame number is the same place), with the frame numbers of the
    frames read (a subsampled or partly unreadable source keeps its source numbering).

    Parameters
    ----------
    db_frames, q_frames : array_like of int, shape (n_db,) and (n_q,)
    tol : int or float
        Tolerance in frame numbers, ``>= 0``.
    sparse : bool
        Return a ``scipy.sparse.csr_matrix`` (a band, built without the dense matrix).
    """
    db_i = np.asarray(db_frames, np.int64).ravel()
    q_i = np.asarray(q_frames, np.int64).ravel()
    tol = check_float(tol, "tol", 0.0)
    if not sparse:
        return np.abs(db_i[:, None] - q_i[None, :]) <= tol
    order = np.argsort(db_i, kind="stable")
    lo = np.searchsorted(db_i[order], q_i - tol, side="left")
    counts = np.searchsorted(db_i[order], q_i + tol, side="right") - lo
    return _csc_from_columns(order[_expand_ranges(lo, counts)], counts, (db_i.size, q_i.size))


def gt_from_tolerance(n_db, n_q, tol, sparse=False):
    """Ground truth for aligned traverses: ``gt[i, j] = |i - j| <= tol`` (:func:`gt_from_frames` of 0, 1, 2, ...).

    Parameters
    ----------
    n_db, n_q : int
        Number of database and query frames.
    tol : int
        Frame tolerance, ``>= 0``.
    sparse : bool
        Return a ``scipy.sparse.csr_matrix`` instead of a dense array.

    Raises
    ------
    ValueError
        If a size or ``tol`` is not a non-negative integer.
    """
    n_db = check_count(n_db, "n_db")
    n_q = check_count(n_q, "n_q")
    tol = check_count(tol, "tol")
    return gt_from_frames(np.arange(n_db), np.arange(n_q), tol, sparse)


def _check_positions(name, xy):
    a = np.asarray(xy)
    if a.ndim != 2:
        raise ValueError(f"{name} must be 2-D (n_points x n_dims), got shape {a.shape}")
    if a.dtype.kind not in "biuf":
        raise ValueError(f"{name} must be numeric, got dtype {a.dtype}")
    a = a.astype(np.float64, copy=False)
    if not np.isfinite(a).all():
        raise ValueError(f"{name} contains NaN or inf")
    return a


def gt_from_positions(db_xy, q_xy, radius, sparse=False):
    """Ground truth from positions: ``gt[i, j] = ||db_xy[i] - q_xy[j]|| <= radius``.

    Uses a KD-tree, so time and memory grow with the number of matching pairs rather than with ``n_db * n_q`` (use
    ``sparse=True`` for large runs).

    Parameters
    ----------
    db_xy : array_like, shape (n_db, d)
    q_xy : array_like, shape (n_q, d)
        Positions (any dimension ``d``, Euclidean distance).
    radius : float
        Inclusive match radius, ``>= 0``.
    sparse : bool
        Return a ``scipy.sparse.csr_matrix`` instead of a dense array.

    Raises
    ------
    ValueError
        If the position arrays are not 2-D, differ in ``d`` or are not finite, or ``radius`` is negative or not
        finite.
    """
    db = _check_positions("db_xy", db_xy)
    q = _check_positions("q_xy", q_xy)
    if db.shape[1] != q.shape[1]:
        raise ValueError(f"db_xy has {db.shape[1]} dimensions, q_xy has {q.shape[1]}")
    radius = check_float(radius, "radius", 0.0)
    shape = (len(db), len(q))
    if len(db) and len(q):
        pairs = cKDTree(db).sparse_distance_matrix(cKDTree(q), radius, output_type="ndarray")
        rows, cols = pairs["i"].astype(np.intp), pairs["j"].astype(np.intp)
    else:
        rows = cols = np.zeros(0, dtype=np.intp)
    if sparse:
        return sp.csr_matrix((np.ones(len(rows), dtype=bool), (rows, cols)), shape=shape)
    gt = np.zeros(shape, dtype=bool)
    gt[rows, cols] = True
    return gt


def loop_closure_mask(T, exclude=0, starts=None):
    """Pairs evaluated for single-stream loop closure on a ``T x T`` matrix.

    ``mask[i, j]`` is True exactly when ``i < j`` and ``j - i >= exclude``: each query frame ``j`` (column) is
    compared only with earlier frames ``i`` (rows), and the ``exclude - 1`` frames just before it are skipped because
    they are trivially similar. ``exclude`` of 0 or 1 keeps all ``i < j``. This is ``np.triu(np.ones((T, T), bool),
    k=max(exclude, 1))``.

    ``starts``: the first frame of each session of a stream that joins several runs; ``exclude`` holds within a
    session, every frame of an earlier session is a candidate (:func:`vpr.similarity.candidate_limit`).

    Raises
    ------
    ValueError
        If ``T`` or ``exclude`` is not a non-negative integer.
    """
    T = check_count(T, "T")
    exclude = check_count(exclude, "exclude")
    return np.arange(T)[:, None] < candidate_limit(T, exclude, starts)[None, :]


def loop_closure_gt(labels_or_xy, radius=None, exclude=0, sparse=False):
    """Ground truth for single-stream loop closure, restricted to :func:`loop_closure_mask`.

    Parameters
    ----------
    labels_or_xy : array_like, shape (T,) or (T, d)
        Place labels per frame (when ``radius`` is None) or positions (1-D positions are treated as ``(T, 1)``).
    radius : float, optional
        Match radius for positions; None means ``labels_or_xy`` are labels.
    exclude : int
        As for :func:`loop_closure_mask`.
    sparse : bool
        Return a ``scipy.sparse.csr_matrix`` instead of a dense array.

    Returns
    -------
    gt : ndarray of bool or csr_matrix, shape (T, T)
        True for revisits ``(i, j)`` with ``i < j`` and ``j - i >= exclude``. With a dense ``S`` also pass
        ``mask=loop_closure_mask(T, exclude)`` to the metrics so that pairs outside the mask are not false positives;
        with a sparse ``S``, ``sp.triu(S, k=max(exclude, 1))`` has the same effect without a dense mask.

    Raises
    ------
    ValueError
        As for the underlying builders; also if labels are given as 2-D.
    """
    exclude = check_count(exclude, "exclude")
    a = np.asarray(labels_or_xy)
    if radius is None:
        if a.ndim != 1:
            raise ValueError(f"labels_or_xy must be 1-D labels when radius is None, got shape {a.shape}")
        gt = gt_from_labels(a, a, sparse=sparse)
    else:
        if a.ndim == 1:
            a = a[:, None]
        gt = gt_from_positions(a, a, radius, sparse=sparse)
    if sparse:
        return sp.triu(gt, k=max(exclude, 1), format="csr").astype(bool)
    return gt & loop_closure_mask(len(a), exclude)


def any_true(G) -> bool:
    """Whether a dense or sparse bool ground truth holds any true pair (sparse has no ``any``)."""
    return bool(G.count_nonzero()) if sp.issparse(G) else bool(np.any(G))


def frame_rows(attempted, read, offset: int = 0) -> np.ndarray:
    """The rows of the frames ``read`` (a source's frame numbers) in a ground truth built for ``attempted``."""
    row = {k: r for r, k in enumerate(attempted)}
    return np.asarray([row[k] + offset for k in read], np.int64)
