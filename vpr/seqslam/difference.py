"""SeqSLAM's difference matrix and its local contrast enhancement (OpenSeqSLAM steps 2 and 3)."""
from __future__ import annotations

import numpy as np

from vpr.checks import check_int
from vpr.similarity import mean_abs_diff

__all__ = ["difference_matrix", "enhance_contrast", "check_difference", "as_descriptors", "unit_rows"]


def check_difference(D, name: str = "D") -> np.ndarray:
    """A difference matrix (database x query, real, finite, not empty)."""
    a = np.asarray(D)
    if a.ndim != 2:
        raise ValueError(f"{name}: expected a 2-D (database x query) matrix, got shape {a.shape}")
    if a.shape[0] == 0 or a.shape[1] == 0:
        raise ValueError(f"{name}: empty matrix (shape {a.shape})")
    if a.dtype == bool or a.dtype.kind not in "iuf":
        raise ValueError(f"{name}: expected a real numeric matrix, got dtype {a.dtype}")
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        raise ValueError(f"{name}: contains NaN or infinite values")
    return a


def as_descriptors(desc, name: str) -> np.ndarray:
    """Descriptors as a contiguous float32 (n, dims) array (one per row; real, finite, not empty)."""
    a = np.asarray(desc)
    if a.dtype == object:
        raise ValueError(f"{name}: descriptors of unequal shapes (or non-numeric)")
    if a.ndim < 2:
        raise ValueError(f"{name}: expected shape (n, ...) with one descriptor per row, got {a.shape}")
    if a.shape[0] == 0:
        raise ValueError(f"{name}: no descriptors")
    if a.dtype == bool or a.dtype.kind not in "iuf":
        raise ValueError(f"{name}: expected real numeric descriptors, got dtype {a.dtype}")
    a = np.ascontiguousarray(a.reshape(a.shape[0], -1), dtype=np.float32)
    if a.shape[1] == 0:
        raise ValueError(f"{name}: descriptors have zero length")
    if not np.isfinite(a).all():
        raise ValueError(f"{name}: contains NaN or infinite values")
    return a


def difference_matrix(db_desc, q_desc, metric: str = "sad", chunk: int = 512) -> np.ndarray:
    """Difference matrix between database and query descriptors, float32 (n_db, n_q), lower = more similar.

    Descriptors are rows (trailing axes flattened, equal lengths). ``metric``: ``"sad"`` the mean absolute difference
    (OpenSeqSLAM's divisor differs by a constant, to which enhancement and ratio are invariant), ``"cosine"`` ``1 -
    cosine`` in [0, 2] (a zero descriptor: 1). ``chunk``: database rows at once (cosine's temporary ``chunk * n_q``).
    Empty, non-finite or mismatched descriptors, an unknown metric or a bad chunk raise ValueError.
    """
    if metric not in ("sad", "cosine"):
        raise ValueError(f"metric: expected 'sad' or 'cosine', got {metric!r}")
    chunk = check_int(chunk, "chunk", 1)
    a = as_descriptors(db_desc, "db_desc")
    b = as_descriptors(q_desc, "q_desc")
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"q_desc: descriptor length {b.shape[1]} differs from db_desc's {a.shape[1]}")
    if metric == "sad":
        return mean_abs_diff(a, b)
    out = np.empty((a.shape[0], b.shape[0]), dtype=np.float32)
    an = unit_rows(a)
    bn = unit_rows(b)
    for r0 in range(0, a.shape[0], chunk):
        blk = out[r0:r0 + chunk]
        np.matmul(an[r0:r0 + chunk], bn.T, out=blk)
        np.subtract(np.float32(1.0), blk, out=blk)
        np.clip(blk, 0.0, 2.0, out=blk)
    return out


def unit_rows(x: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(x.astype(np.float64), axis=1, keepdims=True)
    return (x / np.where(norm > 0, norm, 1.0)).astype(np.float32)


def enhance_contrast(D, R: int = 10, chunk: int = 256) -> np.ndarray:
    """OpenSeqSLAM's local contrast enhancement along the database axis; float32 (n_db, n_q), minimum 0.

    Each ``D[i, q]`` becomes its z-score against rows ``i - R//2 .. i + R//2`` of its column (clipped at the ends,
    ``ddof=1``, the entry included), then the matrix is shifted to a minimum of 0. A constant window gives z = 0
    (OpenSeqSLAM divides by zero). ``chunk``: query columns at once.
    """
    D = check_difference(D, "D")
    R = check_int(R, "R", 2)
    chunk = check_int(chunk, "chunk", 1)
    h = R // 2
    n_db, n_q = D.shape
    rows = np.arange(n_db)
    count = (np.minimum(rows + h, n_db - 1) - np.maximum(rows - h, 0) + 1).astype(np.float64)[:, None]
    out = np.empty((n_db, n_q), dtype=np.float32)
    for c0 in range(0, n_q, chunk):
        x = D[:, c0:c0 + chunk].astype(np.float64)
        # Two passes over shifted slices rather than cumulative sums: the variance then has no cancellation, so
        # constant windows give exactly (or nearly) zero and the guard below is reliable.
        s = np.zeros_like(x)
        for d in range(-min(h, n_db - 1), min(h, n_db - 1) + 1):
            lo, hi = max(0, -d), n_db - max(0, d)
            s[lo:hi] += x[lo + d:hi + d]
        mean = s / count
        ss = np.zeros_like(x)
        for d in range(-min(h, n_db - 1), min(h, n_db - 1) + 1):
            lo, hi = max(0, -d), n_db - max(0, d)
            ss[lo:hi] += (x[lo + d:hi + d] - mean[lo:hi]) ** 2
        std = np.sqrt(ss / np.maximum(count - 1.0, 1.0))
        # relative guard: rounding in the mean leaves ~1e-16 * |mean| of spurious spread in a constant window
        flat = (std <= 1e-10 * np.abs(mean)) | (std == 0.0) | (count == 1.0)
        z = np.where(flat, 0.0, (x - mean) / np.where(flat, 1.0, std))
        out[:, c0:c0 + chunk] = z
    out -= out.min()
    return out

