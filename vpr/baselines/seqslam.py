"""SeqSLAM (Milford & Wyeth, ICRA 2012) as in Sünderhauf's OpenSeqSLAM, vectorised.

Pipeline, with OpenSeqSLAM's defaults:

1. images -> grey 64 x 32 -> 8 x 8 patch normalisation
   (:func:`vpr.imageproc.seqslam_preprocess`);
2. difference matrix ``D`` (database x query), mean absolute difference of the
   flattened descriptors (:func:`difference_matrix`);
3. local contrast enhancement along the database axis (:func:`enhance_contrast`);
4. trajectory search: for every query and database row, the minimum over a set
   of constant velocities of the summed enhanced differences along a straight
   line through ``ds + 1`` query frames (:func:`seqslam`);
5. uniqueness test: best score divided by the best score outside a window around
   it, accepted when the ratio is at most 0.9.

Any difference matrix can be fed to :func:`seqslam`, e.g. one built from CNN or
random-projection descriptors (``metric="cosine"``).

Beyond a dense ``n_db x n_q`` matrix (20,000 x 20,000 float32 is 1.6 GB),
:func:`seqslam_topk` goes from descriptors (dense, or SDR batches compared
through bit overlaps) by blocks of queries and keeps the top-K per query:
exactly the dense result when it searches every row (time still
``n_db * n_q``), or, with candidate windows, only the rows near candidate
alignments (time about linear; approximate, see its docstring).

Where OpenSeqSLAM leaves a value undefined (the first and last ``ds / 2``
queries, databases shorter than a trajectory) this module defines one; every
such choice is listed in the docstring of :func:`seqslam`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numba import njit

from vpr import sdr as _sdr
from vpr._checks import check_int
from vpr.imageproc import seqslam_descriptors
from vpr.similarity import mean_abs_diff

__all__ = [
    "SeqSLAMResult",
    "difference_matrix",
    "enhance_contrast",
    "trajectory_offsets",
    "seqslam",
    "match_images",
    "SeqSLAMTopK",
    "seqslam_topk",
]

# Floor tolerance for k * v: 0.1-step velocities are not exact in binary, and
# without it k * v could land just below an integer it is meant to equal.
_FLOOR_EPS = 1e-9


# --------------------------------------------------------------------------- #
# validation helpers
# --------------------------------------------------------------------------- #
def _check_matrix(D, name: str = "D") -> np.ndarray:
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




def _check_float(value, name: str) -> float:
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number, got {value!r}") from None
    if not np.isfinite(f):
        raise ValueError(f"{name}: must be finite, got {value!r}")
    return f


def _descriptors(desc, name: str) -> np.ndarray:
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


# --------------------------------------------------------------------------- #
# difference matrix
# --------------------------------------------------------------------------- #
def difference_matrix(db_desc, q_desc, metric: str = "sad", chunk: int = 512) -> np.ndarray:
    """Difference matrix between database and query descriptors (lower = more similar).

    Parameters
    ----------
    db_desc, q_desc : array_like, shape (n_db, ...) and (n_q, ...)
        One descriptor per row; trailing axes are flattened (so a stack of
        preprocessed 32 x 64 images works directly). Same flattened length.
    metric : {"sad", "cosine"}
        ``"sad"``: mean absolute difference over the descriptor elements.
        OpenSeqSLAM divides the sum by the number of database images instead of
        the descriptor length; the two differ by a constant factor, which the
        contrast enhancement and the uniqueness ratio are both invariant to.
        ``"cosine"``: ``1 - cosine similarity``, clipped to [0, 2]; a zero
        descriptor has cosine 0 with everything (difference 1).
    chunk : int
        Database rows processed at once; bounds the temporary memory of the
        cosine product to ``chunk * n_q`` floats. ``"sad"`` needs none.

    Returns
    -------
    numpy.ndarray
        float32, shape (n_db, n_q).

    Raises
    ------
    ValueError
        Empty, non-finite or mismatched descriptors, unknown metric, bad chunk.
    """
    if metric not in ("sad", "cosine"):
        raise ValueError(f"metric: expected 'sad' or 'cosine', got {metric!r}")
    chunk = check_int(chunk, "chunk", 1)
    a = _descriptors(db_desc, "db_desc")
    b = _descriptors(q_desc, "q_desc")
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"q_desc: descriptor length {b.shape[1]} differs from db_desc's {a.shape[1]}")
    if metric == "sad":
        return mean_abs_diff(a, b)
    out = np.empty((a.shape[0], b.shape[0]), dtype=np.float32)
    an = _unit_rows(a)
    bn = _unit_rows(b)
    for r0 in range(0, a.shape[0], chunk):
        blk = out[r0:r0 + chunk]
        np.matmul(an[r0:r0 + chunk], bn.T, out=blk)
        np.subtract(np.float32(1.0), blk, out=blk)
        np.clip(blk, 0.0, 2.0, out=blk)
    return out


def _unit_rows(x: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(x.astype(np.float64), axis=1, keepdims=True)
    return (x / np.where(norm > 0, norm, 1.0)).astype(np.float32)


# --------------------------------------------------------------------------- #
# contrast enhancement
# --------------------------------------------------------------------------- #
def enhance_contrast(D, R: int = 10, chunk: int = 256) -> np.ndarray:
    """OpenSeqSLAM's local contrast enhancement along the database axis.

    Each entry ``D[i, q]`` is replaced by its z-score against the database rows
    ``max(0, i - R//2) .. min(n_db - 1, i + R//2)`` of the same column (11 rows
    for R = 10, clipped, not padded, at the ends of the database), using the
    sample standard deviation (``ddof=1``, MATLAB's ``std``) and a mean that
    includes the entry itself. The whole matrix is then shifted so that its
    minimum is 0, as OpenSeqSLAM does.

    OpenSeqSLAM divides by zero when a window is constant (or has one row); here
    such entries get z = 0, so the output is always finite.

    Parameters
    ----------
    D : array_like, shape (n_db, n_q)
        Difference matrix (finite).
    R : int
        Window length; ``R // 2`` rows on each side (OpenSeqSLAM needs R even).
    chunk : int
        Query columns processed at once (float64 temporaries of ``n_db * chunk``).

    Returns
    -------
    numpy.ndarray
        float32, shape (n_db, n_q), minimum 0.
    """
    D = _check_matrix(D, "D")
    R = check_int(R, "R", 2)
    chunk = check_int(chunk, "chunk", 1)
    h = R // 2
    n_db, n_q = D.shape
    rows = np.arange(n_db)
    count = (np.minimum(rows + h, n_db - 1) - np.maximum(rows - h, 0) + 1).astype(np.float64)[:, None]
    out = np.empty((n_db, n_q), dtype=np.float32)
    for c0 in range(0, n_q, chunk):
        x = D[:, c0:c0 + chunk].astype(np.float64)
        # Two passes over shifted slices rather than cumulative sums: the
        # variance then has no cancellation, so constant windows give exactly
        # (or nearly) zero and the guard below is reliable.
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
        # relative guard: rounding in the mean leaves ~1e-16 * |mean| of
        # spurious spread in a constant window
        flat = (std <= 1e-10 * np.abs(mean)) | (std == 0.0) | (count == 1.0)
        z = np.where(flat, 0.0, (x - mean) / np.where(flat, 1.0, std))
        out[:, c0:c0 + chunk] = z
    out -= out.min()
    return out


# --------------------------------------------------------------------------- #
# trajectory search
# --------------------------------------------------------------------------- #
def trajectory_offsets(ds: int = 10, v_min: float = 0.8, v_max: float = 1.2,
                       v_step: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Velocities searched and the distinct database offsets of their trajectories.

    The database row of trajectory point k (k = 0 .. ds, one per query frame)
    is ``start + floor(k * v)``, as in OpenSeqSLAM. Velocities are
    ``v_min, v_min + v_step, ...`` up to ``v_max`` (inclusive, with a 1e-9
    tolerance). OpenSeqSLAM ignores its ``vskip`` and uses steps of ``1 / ds``;
    with the defaults (ds = 10, step 0.1) the two are the same. Velocities that
    produce identical offset rows are searched once.

    Returns
    -------
    velocities : numpy.ndarray, float64, shape (n_v,)
    offsets : numpy.ndarray, int64, shape (n_distinct, ds + 1)
    """
    ds = check_int(ds, "ds", 0)
    v_min = _check_float(v_min, "v_min")
    v_max = _check_float(v_max, "v_max")
    v_step = _check_float(v_step, "v_step")
    if v_min < 0:
        raise ValueError(f"v_min: must be >= 0 (forward trajectories only), got {v_min}")
    if v_max < v_min:
        raise ValueError(f"v_max: must be >= v_min ({v_min}), got {v_max}")
    if v_step <= 0:
        raise ValueError(f"v_step: must be > 0, got {v_step}")
    n_v = int(np.floor((v_max - v_min) / v_step + _FLOOR_EPS)) + 1
    if n_v > 10_000:
        raise ValueError(f"v_step: {v_step} gives {n_v} velocities between v_min and v_max (limit 10,000)")
    vel = v_min + v_step * np.arange(n_v)
    k = np.arange(ds + 1, dtype=np.float64)
    off = np.floor(k[None, :] * vel[:, None] + _FLOOR_EPS).astype(np.int64)
    return vel, np.unique(off, axis=0)


@dataclass(frozen=True)
class SeqSLAMResult:
    """Output of :func:`seqslam` (database x query layout).

    Attributes
    ----------
    similarity : numpy.ndarray, float32, (n_db, n_q)
        Higher = better; finite everywhere. ``-score`` where ``score`` is
        finite; entries with no complete trajectory sit below every finite one
        (see :func:`seqslam`, "Edges").
    score : numpy.ndarray, float32, (n_db, n_q)
        OpenSeqSLAM's sequence score (lower = better): the minimum over
        velocities of the summed enhanced differences along the trajectory;
        ``inf`` where no velocity keeps the trajectory inside the database.
    best_db : numpy.ndarray, int64, (n_q,)
        Best database row per query (first one on ties, like MATLAB's ``min``).
    best_score : numpy.ndarray, float32, (n_q,)
        Score of the best row (the partial-trajectory score where ``complete``
        is False; ``inf`` only if no trajectory touches the database at all).
    ratio : numpy.ndarray, float32, (n_q,)
        Uniqueness ratio ``best / second best outside the window``; lower =
        more distinctive; 0 when there is no finite competitor, 1 for ``0 / 0``
        or when the column has no candidate at all.
    accepted : numpy.ndarray, bool, (n_q,)
        ``ratio <= ratio_threshold`` (and a finite ``best_score``).
    complete : numpy.ndarray, bool, (n_q,)
        Whether the best match comes from a trajectory that stays inside the
        database (always true for OpenSeqSLAM-definable cases).
    velocities : numpy.ndarray, float64
        The velocities searched.
    """

    similarity: np.ndarray
    score: np.ndarray
    best_db: np.ndarray
    best_score: np.ndarray
    ratio: np.ndarray
    accepted: np.ndarray
    complete: np.ndarray
    velocities: np.ndarray


def _trajectory_scores(DD: np.ndarray, offsets: np.ndarray, ds: int, causal: bool,
                       chunk: int) -> tuple[np.ndarray, np.ndarray]:
    """Complete-trajectory scores ``S`` and partial-trajectory scores ``P``.

    Both are rescaled to ``ds + 1`` frames: ``(ds + 1) * mean`` over the points
    used. ``S`` is ``inf`` unless every point whose query frame exists lies in
    the database; ``P`` uses the points inside the matrix (``inf`` if none).
    """
    n_db, n_q = DD.shape
    n_pts = ds + 1
    k = np.arange(n_pts)
    a = ds if causal else ds // 2               # window position of the anchor query
    anchor = offsets[:, ds] if causal else np.full(len(offsets), ds // 2)
    rel = offsets - anchor[:, None]             # row of point k = anchor row + rel[v, k]
    pad = int(np.abs(rel).max()) if rel.size else 0
    # Zero padding makes out-of-matrix points contribute nothing; the point
    # counts below say which trajectories were cut.
    zp = np.zeros((n_db + 2 * pad, n_q + 2 * ds), dtype=np.float32)
    zp[pad:pad + n_db, ds:ds + n_q] = DD
    cols = np.arange(n_q)[:, None] - a + k[None, :]
    col_ok = ((cols >= 0) & (cols < n_q)).astype(np.float32)      # (n_q, n_pts)
    n_frames = col_ok.sum(axis=1)
    rows = np.arange(n_db)[:, None, None] + rel[None, :, :]
    row_ok = ((rows >= 0) & (rows < n_db)).astype(np.float32)     # (n_db, n_v, n_pts)

    S = np.empty((n_db, n_q), dtype=np.float32)
    P = np.empty((n_db, n_q), dtype=np.float32)
    for q0 in range(0, n_q, chunk):
        w = min(chunk, n_q - q0)
        s_blk = np.full((n_db, w), np.inf, dtype=np.float32)
        p_blk = np.full((n_db, w), np.inf, dtype=np.float32)
        acc = np.empty((n_db, w), dtype=np.float32)
        for iv in range(len(offsets)):
            acc[:] = 0.0
            for kk in range(n_pts):
                r0 = pad + rel[iv, kk]
                c0 = ds + q0 - a + kk
                acc += zp[r0:r0 + n_db, c0:c0 + w]
            cnt = row_ok[:, iv, :] @ col_ok[q0:q0 + w].T                # points inside, exact
            has = cnt > 0
            # factor is exactly 1 for uncut trajectories, so interior scores stay plain sums
            factor = np.divide(np.float32(n_pts), cnt, out=np.zeros_like(cnt), where=has)
            pv = acc * factor
            pv[~has] = np.inf
            np.minimum(p_blk, pv, out=p_blk)
            pv[cnt != n_frames[None, q0:q0 + w]] = np.inf
            np.minimum(s_blk, pv, out=s_blk)
        S[:, q0:q0 + w] = s_blk
        P[:, q0:q0 + w] = p_blk
    return S, P


def _check_sequence_params(ds, causal, v_min, v_max, v_step, R, rwindow, ratio_threshold):
    """The trajectory and enhancement parameters shared by :func:`seqslam` and :func:`seqslam_topk`."""
    ds = check_int(ds, "ds", 0)
    if not causal and ds % 2:
        raise ValueError(f"ds: must be even for the centred window (OpenSeqSLAM rounds it up), got {ds}")
    velocities, offsets = trajectory_offsets(ds, v_min, v_max, v_step)
    R = check_int(R, "R", 2)
    rwindow = check_int(rwindow, "rwindow", 0)
    return ds, velocities, offsets, R, rwindow, _check_float(ratio_threshold, "ratio_threshold")


def seqslam(D, ds: int = 10, v_min: float = 0.8, v_max: float = 1.2, v_step: float = 0.1,
            R: int = 10, rwindow: int = 10, ratio_threshold: float = 0.9, causal: bool = False,
            enhance: bool = True, chunk: int = 256) -> SeqSLAMResult:
    """SeqSLAM trajectory search and uniqueness test on a difference matrix.

    Parameters
    ----------
    D : array_like, shape (n_db, n_q)
        Difference matrix, database x query, lower = more similar, finite
        (e.g. from :func:`difference_matrix`, any descriptor).
    ds : int
        Sequence length minus one: each trajectory visits ``ds + 1`` query
        frames. Must be even unless ``causal`` (OpenSeqSLAM silently rounds an
        odd ``ds`` up; here that is an error).
    v_min, v_max, v_step : float
        Velocities searched, in database rows per query frame
        (:func:`trajectory_offsets`).
    R : int
        Contrast-enhancement window (:func:`enhance_contrast`).
    rwindow : int
        Uniqueness window: the second best is searched outside rows
        ``best - rwindow//2 .. best + rwindow//2``.
    ratio_threshold : float
        Accept a match when ``ratio <= ratio_threshold`` (OpenSeqSLAM's demo
        discards matches with ratio > 0.9).
    causal : bool
        False (OpenSeqSLAM): query frames ``q - ds/2 .. q + ds/2``. True
        (online use, described in the paper, not in OpenSeqSLAM): frames
        ``q - ds .. q``.
    enhance : bool
        Apply :func:`enhance_contrast` first. Without it ``D`` must be
        non-negative, since the uniqueness ratio assumes so.
    chunk : int
        Query columns processed at once (memory / cache trade-off only).

    Returns
    -------
    SeqSLAMResult

    Notes
    -----
    **Trajectories.** For velocity v the trajectory's point k (k = 0 .. ds)
    pairs query frame ``q - a + k`` with database row ``start + floor(k * v)``
    (OpenSeqSLAM's rounding). ``score[i, q]`` is the minimum over velocities of
    the sum of the (enhanced) differences at those points. Rows are indexed as
    OpenSeqSLAM reports its match:

    * centred (``a = ds/2``): ``i = start + ds/2``, i.e. where a v = 1
      trajectory is at the query, whatever v (OpenSeqSLAM's
      ``min_idx + ds/2``);
    * causal (``a = ds``): ``i`` is the trajectory's row at the current query,
      ``start + floor(ds * v)``, so the estimate has no velocity-dependent lag.

    With ``v = 1`` only, the interior of ``score`` is the (enhanced) difference
    matrix convolved with a ``(ds+1) x (ds+1)`` identity kernel.

    **Edges.** OpenSeqSLAM gives no match for the first and last ``ds/2``
    queries and, through an appended row of ``inf``, an infinite score to any
    trajectory that leaves the database. Here:

    * query frames outside the query sequence are dropped and the sum over the
      remaining frames is scaled by ``(ds + 1) / n_frames``, so edge columns are
      on the scale of interior ones (interior columns are unscaled sums);
    * a trajectory with any remaining point outside the database is infeasible
      for that velocity; ``score`` is ``inf`` where every velocity is
      infeasible, exactly as in OpenSeqSLAM (this includes rows
      ``i < ds/2`` of interior columns, which OpenSeqSLAM cannot report);
    * ``similarity`` is ``-score`` where that is finite. Infeasible entries are
      ranked below every finite one: by their partial score (the in-database
      points only, as a mean scaled to ``ds + 1`` frames) at
      ``-(max finite score + gap + partial - min partial)``, and entries with
      no point in the database lowest of all (``gap = max(1, 1e-3 |max|)``);
    * a query column with no complete trajectory at all (a database shorter
      than ``floor(ds * v_min) + 1`` rows) falls back to the partial scores for
      ``best_db``, ``best_score`` and the ratio, and ``complete`` is False.

    **Uniqueness.** As OpenSeqSLAM: ``ratio = best / second`` where ``second``
    is the minimum score over the rows outside ``best +- rwindow//2`` (window
    clipped to the database). Infeasible rows count as ``inf``, and no row
    outside the window means ``second = inf`` (OpenSeqSLAM's extra ``inf`` row),
    so ``ratio = 0``. ``0 / 0`` gives 1 (no evidence of distinctiveness).

    OpenSeqSLAM cases this module cannot represent: with ``v_min < 0.5`` a
    centred trajectory can start inside the database yet report a row past its
    end; such candidates are dropped.

    Raises
    ------
    ValueError
        Non-finite or non 2-D ``D``, negative ``D`` with ``enhance=False``,
        odd ``ds`` in centred mode, or out-of-range parameters (the message
        names the argument).
    """
    D = _check_matrix(D, "D")
    ds, velocities, offsets, R, rwindow, ratio_threshold = _check_sequence_params(
        ds, causal, v_min, v_max, v_step, R, rwindow, ratio_threshold)
    chunk = check_int(chunk, "chunk", 1)
    if enhance:
        DD = enhance_contrast(D, R)
    else:
        DD = np.asarray(D, dtype=np.float32)
        if DD.min() < 0:
            raise ValueError("D: has negative entries; the uniqueness ratio needs non-negative "
                             "differences (use enhance=True or shift D)")
    n_db, n_q = DD.shape
    S, P = _trajectory_scores(DD, offsets, ds, bool(causal), chunk)

    feasible = np.isfinite(S)
    complete = feasible.any(axis=0)
    best = np.empty(n_q, dtype=np.int64)
    best_val = np.empty(n_q, dtype=np.float32)
    second = np.empty(n_q, dtype=np.float32)
    rows = np.arange(n_db)[:, None]
    # column blocks keep the temporaries at n_db x chunk
    for c0 in range(0, n_q, chunk):
        c1 = min(c0 + chunk, n_q)
        # OpenSeqSLAM's scores where a complete trajectory exists, else the partial ones
        T = np.where(complete[None, c0:c1], S[:, c0:c1], P[:, c0:c1])
        b = np.argmin(T, axis=0)
        best[c0:c1] = b
        best_val[c0:c1] = T[b, np.arange(c1 - c0)]
        T[np.abs(rows - b[None, :]) <= rwindow // 2] = np.inf
        second[c0:c1] = T.min(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(np.isinf(second), 0.0, best_val / second)
    ratio = np.where((second == 0) | ~np.isfinite(best_val), 1.0, ratio).astype(np.float32)
    accepted = np.isfinite(best_val) & (ratio <= ratio_threshold)

    similarity = _similarity(S, P, feasible)
    return SeqSLAMResult(similarity=similarity, score=S, best_db=best, best_score=best_val,
                         ratio=ratio, accepted=accepted, complete=complete, velocities=velocities)


def _similarity(S: np.ndarray, P: np.ndarray, feasible: np.ndarray) -> np.ndarray:
    sim = np.empty(S.shape, dtype=np.float32)
    np.negative(S, out=sim, where=feasible)
    hi = float(np.max(S, where=feasible, initial=-np.inf)) if feasible.any() else 0.0
    gap = max(1.0, 1e-3 * abs(hi))
    partial = ~feasible & np.isfinite(P)
    if partial.any():
        lo_p = float(np.min(P, where=partial, initial=np.inf))
        sim[partial] = -(hi + gap + (P[partial].astype(np.float64) - lo_p))
    nothing = ~feasible & ~np.isfinite(P)
    if nothing.any():
        floor = float(np.min(sim, where=~nothing, initial=np.inf)) if not nothing.all() else 0.0
        sim[nothing] = floor - gap
    return sim


def match_images(db_images, q_images, size: tuple[int, int] = (64, 32), patch: int = 8,
                 metric: str = "sad", **kw) -> SeqSLAMResult:
    """SeqSLAM end to end on two image sequences.

    Each image goes through :func:`vpr.imageproc.seqslam_preprocess` (grey,
    resize to ``size`` = (w, h), ``patch`` x ``patch`` normalisation), then
    :func:`difference_matrix` with ``metric`` and :func:`seqslam` with ``**kw``.

    Parameters
    ----------
    db_images, q_images : sequence of images
        A list (or iterable, or an (n, H, W[, C]) array) of images accepted by
        :func:`vpr.imageproc.to_grey`.

    Returns
    -------
    SeqSLAMResult
    """
    db = _preprocess_all(db_images, size, patch, "db_images")
    q = _preprocess_all(q_images, size, patch, "q_images")
    return seqslam(difference_matrix(db, q, metric=metric), **kw)


def _preprocess_all(images, size, patch, name) -> np.ndarray:
    return seqslam_descriptors(images, size, patch, name).reshape(-1, size[1], size[0])


# --------------------------------------------------------------------------- #
# blocked top-K SeqSLAM (large inputs)
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class SeqSLAMTopK:
    """Output of :func:`seqslam_topk`: :class:`SeqSLAMResult` without dense matrices.

    Attributes
    ----------
    similarity : scipy.sparse.csr_matrix, float32, (n_db, n_q)
        The ``top_k`` highest entries per query column of the dense
        :attr:`SeqSLAMResult.similarity` (same values; explicit zeros kept),
        among the cells searched.
    best_db, best_score, ratio, accepted, complete, velocities
        As in :class:`SeqSLAMResult`, over the cells searched. A query for
        which nothing was searched (candidate mode, no candidate in its block)
        has ``best_db = -1``, ``best_score = inf``, ``ratio = 1``, not accepted.
    exact : bool
        True when every database row was searched for every query: then every
        field equals the dense :func:`seqslam` up to float32 rounding.
    cells : int
        Number of (database, query) cells whose trajectory score was computed.
    """

    similarity: sp.csr_matrix
    best_db: np.ndarray
    best_score: np.ndarray
    ratio: np.ndarray
    accepted: np.ndarray
    complete: np.ndarray
    velocities: np.ndarray
    exact: bool
    cells: int


@njit(cache=True, nogil=True)
def _enhance_rows(D, d0, z0, z1, n_db, h, out):  # pragma: no cover - compiled
    # Same arithmetic, in the same order, as enhance_contrast (float64 two-pass
    # sums over the rows ascending), so each z equals the dense one bit for bit;
    # the loops run over columns innermost so that they vectorise.
    C = D.shape[1]
    s = np.empty(C)
    ss = np.empty(C)
    for i in range(z0, z1):
        j0 = max(0, i - h)
        j1 = min(n_db - 1, i + h)
        cnt = float(j1 - j0 + 1)
        s[:] = 0.0
        ss[:] = 0.0
        for j in range(j0, j1 + 1):
            for c in range(C):
                s[c] += np.float64(D[j - d0, c])
        for c in range(C):
            s[c] = s[c] / cnt
        for j in range(j0, j1 + 1):
            for c in range(C):
                d = np.float64(D[j - d0, c]) - s[c]
                ss[c] += d * d
        for c in range(C):
            mean = s[c]
            std = np.sqrt(ss[c] / max(cnt - 1.0, 1.0))
            if std <= 1e-10 * abs(mean) or std == 0.0 or cnt == 1.0:
                out[i - z0, c] = 0.0
            else:
                out[i - z0, c] = np.float32((np.float64(D[i - d0, c]) - mean) / std)


@njit(cache=True, nogil=True)
def _trajectories(Z, z0, o0, o1, n_db, rel, colvalid, S, P):  # pragma: no cover - compiled
    # Z holds enhanced rows z0.. (global) and the block's query columns shifted so
    # that point k of the trajectory of output column j is column j + k; columns
    # outside the query sequence are zero, as in _trajectory_scores' padding, so
    # sums are the same float32 sums in the same order.
    w = S.shape[1]
    n_v, n_pts = rel.shape
    interior = True
    for c in range(colvalid.shape[0]):
        if not colvalid[c]:
            interior = False
    nfr = np.zeros(w, np.int64)
    for j in range(w):
        for k in range(n_pts):
            if colvalid[j + k]:
                nfr[j] += 1
    acc = np.empty(w, np.float32)
    rowin = np.empty(n_pts, np.bool_)
    inf = np.float32(np.inf)
    fpts = np.float32(n_pts)
    for i in range(o0, o1):
        li = i - o0
        for j in range(w):
            S[li, j] = inf
            P[li, j] = inf
        for v in range(n_v):
            acc[:] = 0.0
            nin = 0
            for k in range(n_pts):
                r = i + rel[v, k]
                rowin[k] = 0 <= r < n_db
                if rowin[k]:
                    nin += 1
                    zr = r - z0
                    for j in range(w):
                        acc[j] += Z[zr, j + k]
            if nin == 0:
                continue
            if interior:
                # every query frame exists: one factor for the row, branch-free minima (vectorised)
                f = fpts / np.float32(nin)
                full = nin == n_pts
                if full:
                    for j in range(w):
                        pv = acc[j] * f
                        P[li, j] = min(P[li, j], pv)
                        S[li, j] = min(S[li, j], pv)
                else:
                    for j in range(w):
                        P[li, j] = min(P[li, j], acc[j] * f)
                continue
            for j in range(w):
                cnt = 0
                for k in range(n_pts):
                    if rowin[k] and colvalid[j + k]:
                        cnt += 1
                if cnt == 0:
                    continue
                pv = acc[j] * (fpts / np.float32(cnt))
                if pv < P[li, j]:
                    P[li, j] = pv
                if cnt == nfr[j] and pv < S[li, j]:
                    S[li, j] = pv


@njit(cache=True, nogil=True)
def _sdr_overlap_rows(indptr, indices, r0, r1, qptr, qcols, out):  # pragma: no cover - compiled
    # overlap counts of database rows r0..r1 with the block's queries, through
    # the block's inverted index (bit -> query columns): cost ~ active bits x postings
    for r in range(r0, r1):
        lr = r - r0
        for p in range(indptr[r], indptr[r + 1]):
            b = indices[p]
            for t in range(qptr[b], qptr[b + 1]):
                out[lr, qcols[t]] += 1


@njit(cache=True, nogil=True)
def _sdr_candidates(post_ptr, post_rows, q_indptr, q_indices, k, counts, out):  # pragma: no cover - compiled
    # Single-frame candidates: per query the k database rows of largest overlap,
    # through the database's inverted index (bit -> rows). Rows reaching an
    # overlap of 2 are listed as they do (random rows rarely do, so the list is
    # short); a histogram of their counts gives the k-th largest without
    # sorting. Only if fewer than k rows reach 2 are rows with overlap 1 added.
    # ``counts`` (n_db, zeros) is uint16 when overlaps fit: half the cache footprint.
    n_db = counts.shape[0]
    listed = np.empty(n_db + 1, np.int64)
    max_bits = 0
    for q in range(q_indptr.shape[0] - 1):
        max_bits = max(max_bits, q_indptr[q + 1] - q_indptr[q])
    hist = np.zeros(max_bits + 2, np.int64)
    for q in range(q_indptr.shape[0] - 1):
        counts[:] = 0
        nl = 0
        for p in range(q_indptr[q], q_indptr[q + 1]):
            b = q_indices[p]
            for t in range(post_ptr[b], post_ptr[b + 1]):
                r = post_rows[t]
                c = counts[r] + 1
                counts[r] = c
                listed[nl] = r                   # branch-free: 1.5-2x faster than an if
                nl += c == 2
        for t in range(nl):
            hist[counts[listed[t]]] += 1
        thr = 2
        cum = 0
        for c in range(max_bits, 1, -1):
            if cum + hist[c] >= k:
                thr = c
                break
            cum += hist[c]
        n_out = 0
        for t in range(nl):                      # strictly above the threshold: all fit
            if counts[listed[t]] > thr:
                out[q, n_out] = listed[t]
                n_out += 1
        for t in range(nl):                      # at the threshold: in listing order until k
            if n_out == k:
                break
            if counts[listed[t]] == thr:
                out[q, n_out] = listed[t]
                n_out += 1
        if n_out < k:                            # few rows share 2 bits: fill with overlap 1, lowest rows first
            for r in range(n_db):
                if n_out == k:
                    break
                if counts[r] == 1:
                    out[q, n_out] = r
                    n_out += 1
        hist[:] = 0


class _Descriptors:
    """Database and query descriptors with the block difference of :func:`difference_matrix`.

    SDR batches (sparse bool) are never densified: ``|a - b|`` summed over 0/1
    rows is ``|a| + |b| - 2 |a & b|``, an exact identity, so the SAD of a block
    costs an overlap count through the queries' inverted index.
    """

    def __init__(self, db_desc, q_desc, metric: str):
        if metric not in ("sad", "cosine"):
            raise ValueError(f"metric: expected 'sad' or 'cosine', got {metric!r}")
        self.metric = metric
        if sp.issparse(db_desc) != sp.issparse(q_desc):
            raise ValueError("q_desc: db_desc and q_desc must both be SDR batches (scipy.sparse) "
                             "or both dense descriptor arrays")
        self.sdr = sp.issparse(db_desc)
        if self.sdr:
            self.a = _sdr.check_batch(db_desc, name="db_desc")
            self.b = _sdr.check_batch(q_desc, n_bits=self.a.shape[1], name="q_desc")
            if self.a.shape[0] == 0 or self.b.shape[0] == 0:
                raise ValueError("db_desc, q_desc: need at least one row each")
            self.na = np.diff(self.a.indptr).astype(np.int64)
            self.nb = np.diff(self.b.indptr).astype(np.int64)
            self.a_indptr = self.a.indptr.astype(np.int64)
            self.a_indices = self.a.indices.astype(np.int64)
        else:
            self.a = _descriptors(db_desc, "db_desc")
            self.b = _descriptors(q_desc, "q_desc")
            if self.a.shape[1] != self.b.shape[1]:
                raise ValueError(f"q_desc: descriptor length {self.b.shape[1]} differs from "
                                 f"db_desc's {self.a.shape[1]}")
            if metric == "cosine":
                self.au, self.bu = _unit_rows(self.a), _unit_rows(self.b)
        self.n_db, self.n_q = self.a.shape[0], self.b.shape[0]
        self._qb_cols = None
        self.dim = self.a.shape[1]

    def block(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """Difference matrix rows r0..r1, columns c0..c1 (float32), as difference_matrix computes it."""
        if not self.sdr:
            if self.metric == "sad":
                return mean_abs_diff(self.a[r0:r1], self.b[c0:c1])
            out = self.au[r0:r1] @ self.bu[c0:c1].T
            np.subtract(np.float32(1.0), out, out=out)
            return np.clip(out, 0.0, 2.0, out=out)
        if self._qb_cols != (c0, c1):            # one inverted index per query block, shared by its windows
            qb = self.b[c0:c1].tocsc()
            self._qb = (qb.indptr.astype(np.int64), qb.indices.astype(np.int64))
            self._qb_cols = (c0, c1)
        ov = np.zeros((r1 - r0, c1 - c0), dtype=np.int64)
        _sdr_overlap_rows(self.a_indptr, self.a_indices, r0, r1, self._qb[0], self._qb[1], ov)
        na = self.na[r0:r1, None]
        nb = self.nb[None, c0:c1]
        if self.metric == "sad":
            return ((na + nb - 2 * ov) / self.dim).astype(np.float32)
        denom = np.sqrt((na * nb).astype(np.float64))
        cos = np.divide(ov, denom, out=np.zeros(ov.shape), where=denom > 0)
        return np.clip(1.0 - cos, 0.0, 2.0).astype(np.float32)

    def candidates(self, k: int, stride: int = 1, chunk: int = 512) -> tuple[np.ndarray, np.ndarray]:
        """Single-frame candidates of every ``stride``-th query: its k most similar database rows.

        Returns (ptr, rows) per query column, csc-like; skipped queries have none.
        """
        k = min(k, self.n_db)
        sampled = np.arange(0, self.n_q, stride)
        if self.sdr:
            post = self.a.tocsc()
            qs = self.b[sampled]
            out = np.full((len(sampled), k), -1, dtype=np.int64)
            counts = np.zeros(self.n_db, dtype=np.uint16 if self.nb.max(initial=0) < 2**16 - 1 else np.int64)
            _sdr_candidates(post.indptr.astype(np.int64), post.indices.astype(np.int32),
                            qs.indptr.astype(np.int64), qs.indices.astype(np.int64), k, counts, out)
        else:
            out = np.empty((len(sampled), k), dtype=np.int64)
            for c0 in range(0, len(sampled), chunk):
                idx = sampled[c0:c0 + chunk]
                if self.metric == "sad":
                    D = mean_abs_diff(self.a, self.b[idx])
                else:
                    D = 1.0 - self.au @ self.bu[idx].T
                out[c0:c0 + len(idx)] = np.argpartition(D, k - 1, axis=0)[:k].T if k < self.n_db else \
                    np.arange(self.n_db)
        n_per = np.zeros(self.n_q, dtype=np.int64)
        n_per[sampled] = (out >= 0).sum(axis=1)
        return np.concatenate([[0], np.cumsum(n_per)]).astype(np.int64), out[out >= 0]


def _candidate_pattern(candidates, n_db: int, n_q: int) -> tuple[np.ndarray, np.ndarray]:
    """(ptr, rows) per query column of a caller's candidate matrix (stored / nonzero entries)."""
    if sp.issparse(candidates):
        C = sp.csc_matrix(candidates)
    else:
        a = np.asarray(candidates)
        if a.ndim != 2:
            raise ValueError(f"candidates: expected a (n_db x n_q) matrix, 'pairwise' or None, got {candidates!r}")
        C = sp.csc_matrix(a != 0)
    if C.shape != (n_db, n_q):
        raise ValueError(f"candidates: expected shape {(n_db, n_q)} (database x query), got {C.shape}")
    C.sort_indices()
    return C.indptr.astype(np.int64), C.indices.astype(np.int64)


def _windows(ptr, rows, q0: int, q1: int, n_db: int, n_windows: int, v_min: float, v_max: float,
             margin: int) -> list[tuple[int, int]]:
    """Database row intervals searched for queries q0..q1, voted by the candidates.

    Each candidate (row i, query q) votes for the anchor ``i - (q - q0)``: the
    block's first query's row if the speed were 1. A sequence seen by the
    block's queries piles its votes into one or two adjacent bins of width
    ``(w - 1) * max speed deviation + 1``, single-frame aliases scatter. The
    ``n_windows`` best bins (widened by one bin each side) become the rows every
    trajectory anchored there can reach in the block, at any speed in
    ``[v_min, v_max]``, plus ``margin``.
    """
    w = q1 - q0
    lo, hi = ptr[q0], ptr[q1]
    if hi == lo:
        return []
    q_of = np.repeat(np.arange(w), np.diff(ptr[q0:q1 + 1]))
    anchors = rows[lo:hi] - q_of
    dev = max(v_max - 1.0, 1.0 - v_min, 0.0)
    bw = int(np.ceil((w - 1) * dev)) + 1
    bins, votes = np.unique(np.floor_divide(anchors, bw), return_counts=True)
    order = np.lexsort((bins, -votes))[:n_windows]
    below = int(np.ceil((w - 1) * max(0.0, v_max - 1.0))) + margin
    above = int(np.ceil((w - 1) * max(1.0, v_max))) + margin
    iv = sorted(((int(b) - 1) * bw - below, (int(b) + 2) * bw + above) for b in bins[order])
    out: list[tuple[int, int]] = []
    for a, b in iv:
        a, b = max(a, 0), min(b, n_db)
        if a >= b:
            continue
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


def seqslam_topk(db_desc, q_desc, top_k: int = 50, metric: str = "sad", block: int | None = None,
                 candidates=None, n_candidates: int = 50, candidate_stride: int = 4, n_windows: int = 4,
                 ds: int = 10,
                 v_min: float = 0.8, v_max: float = 1.2, v_step: float = 0.1, R: int = 10,
                 rwindow: int = 10, ratio_threshold: float = 0.9, causal: bool = False,
                 enhance: bool = True) -> SeqSLAMTopK:
    """SeqSLAM from descriptors, by blocks of queries, keeping the top-K per query.

    Memory is ``O(searched rows x block)`` instead of the dense ``n_db x n_q``.

    **Exact mode** (``candidates=None``): every database row is searched for
    every query. Per block of queries, the difference matrix on the block's
    columns (plus the ``ds`` neighbouring query frames its trajectories
    reach), its contrast enhancement and the trajectory search are computed as
    :func:`difference_matrix` + :func:`seqslam` do. The result equals the dense
    ``seqslam(difference_matrix(db, q, metric), ...)`` up to float32 rounding:
    OpenSeqSLAM shifts the enhanced matrix by its global minimum before the
    sums; here the shift (``(ds + 1) * min``, the same for every finite score)
    is applied to the sums at the end, since the minimum is known only then.
    Time is ``O(n_db * n_q)`` as for the dense version.

    **Candidate mode** (approximate, for large inputs): only database rows
    near candidate matches are searched. ``candidates`` gives candidate
    (database, query) pairs: a db x query matrix (sparse stored entries or
    nonzeros, e.g. the top-K of a pairwise search or of ``rshosm-seq``), or
    ``"pairwise"`` for the ``n_candidates`` most similar database frames per
    query by single-frame overlap (SDR, through an inverted index, frames
    sharing no bit are never candidates) or by the metric (dense
    descriptors). Per query block the candidates vote for sequence alignments
    (:func:`_windows`); the ``n_windows`` best become database row windows in
    which the difference, the enhancement and the trajectory scores are exact
    (the enhancement and the trajectories read rows beyond the window edges as
    needed). What is approximate: rows outside the windows are not scored (not
    in ``similarity``, never ``best_db``), the uniqueness ratio's second best
    and the global minimum of the enhanced matrix are taken over the searched
    cells only. When the windows of every block cover the whole database the
    result is the exact one (``exact`` is True).

    Measured (``benchmarks/bench_seqslam_scale.py``, aliased SDR traverses,
    one thread, CPU time): candidate mode 0.4 s at 5,000 x 5,000 and 6.7 s at
    50,000 x 50,000 (1 % of the cells searched, growth exponent 1.17), peak RSS
    0.42 GB; its best match equals the exact one for 99.8-99.9 % of the
    queries (5,000 to 20,000 frames). Exact mode 3.4 s at 5,000, 16 s at
    10,000, 66 s and 0.68 GB at 20,000 (exponent 2: about 7 minutes at 50,000).

    Parameters
    ----------
    db_desc, q_desc : SDR batches (scipy.sparse, bool) or arrays (n, ...)
        Both of one kind. SDRs are compared as dense 0/1 rows would be
        (``"sad"``: mean absolute difference, ``"cosine"``), never densified.
    top_k : int
        Database entries kept per query in ``similarity``.
    metric : {"sad", "cosine"}
        As :func:`difference_matrix`.
    block : int, optional
        Queries per block: default 256 in exact mode (memory ``~16 * n_db *
        block`` bytes), 64 in candidate mode (windows grow with the block).
    candidates : None, "pairwise" or matrix (n_db, n_q)
        See above.
    n_candidates : int
        Candidates per query for ``candidates="pairwise"``.
    candidate_stride : int
        ``candidates="pairwise"`` searches every ``candidate_stride``-th query
        only: the single-frame search is the only part whose time grows with
        ``n_db * n_q``, and a block's alignment needs a few of its queries'
        votes, not all of them.
    n_windows : int
        Alignments (windows) searched per query block in candidate mode.
    ds, v_min, v_max, v_step, R, rwindow, ratio_threshold, causal, enhance
        As :func:`seqslam` (``enhance=False`` uses the raw differences, which
        are non-negative for both metrics).

    Returns
    -------
    SeqSLAMTopK

    Raises
    ------
    ValueError
        Bad descriptors or parameters (the message names the argument).
    """
    desc = _Descriptors(db_desc, q_desc, metric)
    n_db, n_q = desc.n_db, desc.n_q
    top_k = check_int(top_k, "top_k", 1)
    ds, velocities, offsets, R, rwindow, ratio_threshold = _check_sequence_params(
        ds, causal, v_min, v_max, v_step, R, rwindow, ratio_threshold)
    n_windows = check_int(n_windows, "n_windows", 1)
    n_candidates = check_int(n_candidates, "n_candidates", 1)
    candidate_stride = check_int(candidate_stride, "candidate_stride", 1)
    if candidates is None:
        ptr = rows = None
    elif isinstance(candidates, str):
        if candidates != "pairwise":
            raise ValueError(f"candidates: expected None, 'pairwise' or a matrix, got {candidates!r}")
        ptr, rows = desc.candidates(n_candidates, candidate_stride)
    else:
        ptr, rows = _candidate_pattern(candidates, n_db, n_q)
    block = check_int(256 if block is None and ptr is None else 64 if block is None else block, "block", 1)

    causal = bool(causal)
    h = R // 2 if enhance else 0
    a = ds if causal else ds // 2
    anchor = offsets[:, ds] if causal else np.full(len(offsets), ds // 2)
    rel = np.ascontiguousarray(offsets - anchor[:, None])
    rmin, rmax = int(rel.min()), int(rel.max())
    n_pts = ds + 1
    hw = rwindow // 2

    zmin = np.inf                         # global minimum of the enhanced matrix (over what was computed)
    s_max, p_min, p_max = -np.inf, np.inf, -np.inf
    any_nothing = False
    best = np.full(n_q, -1, dtype=np.int64)       # -1: no candidate, nothing searched
    best_raw = np.full(n_q, np.inf, dtype=np.float32)
    second_raw = np.full(n_q, np.inf, dtype=np.float32)
    complete = np.zeros(n_q, dtype=bool)
    kept_r, kept_c, kept_cls, kept_v = [], [], [], []
    exact = True
    cells = 0
    for q0 in range(0, n_q, block):
        q1 = min(q0 + block, n_q)
        w = q1 - q0
        if ptr is None:
            ivs = [(0, n_db)]
        else:
            ivs = _windows(ptr, rows, q0, q1, n_db, n_windows, float(velocities[0]), float(velocities[-1]), hw)
        exact &= ivs == [(0, n_db)]
        if not ivs:
            continue
        # query columns the block's trajectories read: j + k for k = 0..ds
        c_lo, c_hi = q0 - a, q1 - a + ds
        c0, c1 = max(c_lo, 0), min(c_hi, n_q)
        colvalid = np.zeros(w + ds, dtype=np.bool_)
        colvalid[c0 - c_lo:c1 - c_lo] = True
        S_parts, P_parts, row_parts = [], [], []
        for o0, o1 in ivs:
            z0, z1 = max(o0 + rmin, 0), min(o1 + rmax, n_db)
            d0, d1 = max(z0 - h, 0), min(z1 + h, n_db)
            Z = np.zeros((z1 - z0, w + ds), dtype=np.float32)
            if c1 > c0:
                D = desc.block(d0, d1, c0, c1)
                if enhance:
                    Zc = np.empty((z1 - z0, c1 - c0), dtype=np.float32)
                    _enhance_rows(D, d0, z0, z1, n_db, h, Zc)
                else:
                    Zc = D[z0 - d0:z1 - d0]
                Z[:, c0 - c_lo:c1 - c_lo] = Zc
                if Zc.size:
                    zmin = min(zmin, float(Zc.min()))
            S = np.empty((o1 - o0, w), dtype=np.float32)
            P = np.empty((o1 - o0, w), dtype=np.float32)
            _trajectories(Z, z0, o0, o1, n_db, rel, colvalid, S, P)
            S_parts.append(S)
            P_parts.append(P)
            row_parts.append(np.arange(o0, o1))
        S = np.concatenate(S_parts) if len(S_parts) > 1 else S_parts[0]
        P = np.concatenate(P_parts) if len(P_parts) > 1 else P_parts[0]
        rws = np.concatenate(row_parts) if len(row_parts) > 1 else row_parts[0]
        L = len(rws)
        cells += L * w
        feas = np.isfinite(S)
        part = ~feas & np.isfinite(P)
        nothing = ~feas & ~part
        if feas.any():
            s_max = max(s_max, float(S[feas].max()))
        if part.any():
            p_min = min(p_min, float(P[part].min()))
            p_max = max(p_max, float(P[part].max()))
        any_nothing |= bool(nothing.any())
        comp = feas.any(axis=0)
        complete[q0:q1] = comp
        T = np.where(comp[None, :], S, P)
        b = np.argmin(T, axis=0)
        cols = np.arange(w)
        best[q0:q1] = rws[b]
        best_raw[q0:q1] = T[b, cols]
        T[np.abs(rws[:, None] - rws[b][None, :]) <= hw] = np.inf
        second_raw[q0:q1] = T.min(axis=0)
        # top-K in the dense order: feasible by score, then partial by partial score, then the rest
        key = np.where(feas, S.astype(np.float64), np.inf)
        if part.any():
            off = (float(S[feas].max()) if feas.any() else 0.0) - float(P[part].min()) + 1.0
            key[part] = P[part].astype(np.float64) + off
        k = min(top_k, L)
        idx = np.argpartition(key, k - 1, axis=0)[:k] if k < L else np.broadcast_to(np.arange(L)[:, None], (L, w))
        cls = np.where(feas, 0, np.where(part, 1, 2)).astype(np.int8)
        kept_r.append(rws[idx].ravel())
        kept_c.append(np.broadcast_to(q0 + cols, idx.shape).ravel())
        kept_cls.append(np.take_along_axis(cls, idx, axis=0).ravel())
        kept_v.append(np.take_along_axis(np.where(feas, S, P), idx, axis=0).ravel())

    # OpenSeqSLAM's shift of the enhanced matrix to minimum 0, applied to the sums
    shift = n_pts * zmin if (enhance and np.isfinite(zmin)) else 0.0
    best_score = (best_raw.astype(np.float64) - shift).astype(np.float32)
    second = (second_raw.astype(np.float64) - shift).astype(np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(np.isinf(second), 0.0, best_score / second)
    ratio = np.where((second == 0) | ~np.isfinite(best_score), 1.0, ratio).astype(np.float32)
    accepted = np.isfinite(best_score) & (ratio <= ratio_threshold)

    r = np.concatenate(kept_r) if kept_r else np.zeros(0, np.int64)
    c = np.concatenate(kept_c) if kept_c else np.zeros(0, np.int64)
    cls = np.concatenate(kept_cls) if kept_cls else np.zeros(0, np.int8)
    v = np.concatenate(kept_v).astype(np.float64) - shift if kept_v else np.zeros(0)
    # the dense _similarity's mapping, with its global constants taken over the searched cells
    hi = float(np.float32(s_max - shift)) if np.isfinite(s_max) else 0.0
    gap = max(1.0, 1e-3 * abs(hi))
    sim = np.empty(len(v), dtype=np.float32)
    sim[cls == 0] = -v[cls == 0].astype(np.float32)
    if np.isfinite(p_min):
        lo_p = float(np.float32(p_min - shift))
        sim[cls == 1] = -(hi + gap + (v[cls == 1].astype(np.float32).astype(np.float64) - lo_p))
        floor = float(np.float32(-(hi + gap + (float(np.float32(p_max - shift)) - lo_p))))
    else:
        floor = -hi if np.isfinite(s_max) else 0.0
    if any_nothing:
        sim[cls == 2] = floor - gap
    similarity = sp.coo_matrix((sim, (r, c)), shape=(n_db, n_q)).tocsr()
    return SeqSLAMTopK(similarity=similarity, best_db=best, best_score=best_score, ratio=ratio,
                       accepted=accepted, complete=complete, velocities=velocities, exact=bool(exact),
                       cells=int(cells))
