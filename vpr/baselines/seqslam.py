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

Where OpenSeqSLAM leaves a value undefined (the first and last ``ds / 2``
queries, databases shorter than a trajectory) this module defines one; every
such choice is listed in the docstring of :func:`seqslam`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vpr.imageproc import seqslam_preprocess
from vpr.similarity import mean_abs_diff

__all__ = [
    "SeqSLAMResult",
    "difference_matrix",
    "enhance_contrast",
    "trajectory_offsets",
    "seqslam",
    "match_images",
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


def _check_int(value, name: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name}: expected an integer, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name}: must be >= {minimum}, got {value}")
    return int(value)


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
    chunk = _check_int(chunk, "chunk", 1)
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
    R = _check_int(R, "R", 2)
    chunk = _check_int(chunk, "chunk", 1)
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
    ds = _check_int(ds, "ds", 0)
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
    ds = _check_int(ds, "ds", 0)
    if not causal and ds % 2:
        raise ValueError(f"ds: must be even for the centred window (OpenSeqSLAM rounds it up), got {ds}")
    velocities, offsets = trajectory_offsets(ds, v_min, v_max, v_step)
    R = _check_int(R, "R", 2)
    rwindow = _check_int(rwindow, "rwindow", 0)
    ratio_threshold = _check_float(ratio_threshold, "ratio_threshold")
    chunk = _check_int(chunk, "chunk", 1)
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
    if isinstance(images, np.ndarray) and images.ndim < 3:
        raise ValueError(f"{name}: expected a sequence of images, got an array of shape {images.shape}")
    out = [seqslam_preprocess(img, size, patch, name=f"{name}[{i}]") for i, img in enumerate(images)]
    if not out:
        raise ValueError(f"{name}: no images")
    return np.stack(out)
