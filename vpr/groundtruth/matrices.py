"""Ground-truth matrices from labels, frame numbers or positions, and the pairs a loop closure evaluates."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from vpr.checks import check_count, check_float
from vpr.similarity import candidate_limit

__all__ = ["gt_from_labels", "gt_from_frames", "gt_from_tolerance", "gt_from_positions", "loop_closure_mask",
           "loop_closure_gt", "loop_pairs", "any_true", "frame_rows"]


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
    """Ground truth from 1-D place labels: ``gt[i, j] = db_labels[i] == q_labels[j]`` (``sparse``: a csr_matrix).

    Labels not 1-D or holding NaN raise ValueError.
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

    For traverses aligned frame by frame, with the source numbers of the frames read. ``sparse``: a csr_matrix band.
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

    Sizes and ``tol`` are non-negative integers (else ValueError); ``sparse``: a csr_matrix.
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
    """Ground truth from positions (n, d): ``gt[i, j] = ||db_xy[i] - q_xy[j]|| <= radius``.

    Cost grows with the matching pairs (a KD-tree; ``sparse=True``: a csr_matrix). Positions not 2-D, of unequal ``d``
    or not finite, or a negative or infinite ``radius`` raise ValueError.
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
    """Pairs evaluated for one stream's loop closure on a ``T x T`` matrix.

    ``mask[i, j]`` is True exactly when ``i < j`` and ``j - i >= exclude`` (``np.triu(np.ones((T, T), bool),
    k=max(exclude, 1))``). ``starts``: each session's first frame; ``exclude`` holds within a session, every frame of
    an earlier session is a candidate. ``T`` or ``exclude`` not a non-negative integer raise ValueError.
    """
    T = check_count(T, "T")
    exclude = check_count(exclude, "exclude")
    return np.arange(T)[:, None] < candidate_limit(T, exclude, starts)[None, :]


def loop_closure_gt(labels_or_xy, radius=None, exclude=0, sparse=False):
    """Ground truth for one stream's loop closure (T, T), restricted to :func:`loop_closure_mask`.

    ``labels_or_xy``: place labels (T,) when ``radius`` is None, else positions (T,) or (T, d) matched within
    ``radius``. True for revisits ``(i, j)`` with ``i < j`` and ``j - i >= exclude``; score a dense ``S`` with
    ``mask=loop_closure_mask(T, exclude)`` (a sparse one: ``sp.triu(S, k=max(exclude, 1))``). ``sparse``: a
    csr_matrix. Bad input raises ValueError as the builders do (2-D labels too).
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


def loop_pairs(G, exclude=0, starts=None):
    """The pairs of a T x T ground truth ``G`` (dense or sparse bool) that :func:`loop_closure_mask` evaluates.

    Dense ``G`` gives ``G & loop_closure_mask(T, exclude, starts)``; sparse ``G`` a csr_matrix of its entries inside
    the mask, with no dense T x T built.
    """
    T = G.shape[1]
    if not sp.issparse(G):
        return np.asarray(G) & loop_closure_mask(T, exclude, starts)
    n = candidate_limit(T, check_count(exclude, "exclude"), starts)
    C = sp.coo_matrix(G)
    keep = (C.row < n[C.col]) & (C.data != 0)
    return sp.csr_matrix((np.ones(int(keep.sum()), bool), (C.row[keep], C.col[keep])), shape=G.shape)


def any_true(G) -> bool:
    """Whether a dense or sparse bool ground truth holds any true pair (sparse has no ``any``)."""
    return bool(G.count_nonzero()) if sp.issparse(G) else bool(np.any(G))


def frame_rows(attempted, read, offset: int = 0) -> np.ndarray:
    """The rows of the frames ``read`` (a source's frame numbers) in a ground truth built for ``attempted``."""
    row = {k: r for r, k in enumerate(attempted)}
    return np.asarray([row[k] + offset for k in read], np.int64)
