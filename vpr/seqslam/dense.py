"""SeqSLAM's trajectory search and uniqueness test on a dense difference matrix (OpenSeqSLAM steps 4 and 5)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vpr.checks import check_float, check_int
from vpr.imageproc import seqslam_descriptors

from .difference import check_difference, difference_matrix, enhance_contrast

__all__ = ["SeqSLAMResult", "SeqSlamConf", "trajectory_offsets", "seqslam", "match_images", "pixel_descriptors",
           "check_sequence_params"]

# Floor tolerance for k * v: 0.1-step velocities are not exact in binary, and without it k * v could land just below
# an integer it is meant to equal.
_FLOOR_EPS = 1e-9


def trajectory_offsets(ds: int = 10, v_min: float = 0.8, v_max: float = 1.2,
                       v_step: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Velocities searched and the distinct database offsets of their trajectories.

    Point k (0 .. ds) of a trajectory is at row ``start + floor(k * v)``, as in OpenSeqSLAM, for ``v = v_min, v_min +
    v_step, ...`` up to ``v_max`` (1e-9 tolerance); identical offset rows are searched once. Returns float64
    velocities (n_v,) and int64 offsets (n_distinct, ds + 1).
    """
    ds = check_int(ds, "ds", 0)
    v_min = check_float(v_min, "v_min")
    v_max = check_float(v_max, "v_max")
    v_step = check_float(v_step, "v_step")
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
    """Output of :func:`seqslam` (dense) and :func:`vpr.seqslam.seqslam_topk` (top-K), database x query.

    Attributes
    ----------
    similarity : numpy.ndarray float32 (n_db, n_q) or scipy.sparse.csr_matrix
        ``-score``, higher = better, finite; pairs without a complete trajectory below every other. Top-K: each
        column's ``top_k`` highest among the cells searched.
    best_db : numpy.ndarray, int64, (n_q,)
        Best database row per query (first on ties; -1 where nothing was searched).
    best_score : numpy.ndarray, float32, (n_q,)
        Score of the best row (partial where not ``complete``).
    ratio : numpy.ndarray, float32, (n_q,)
        ``best / second best outside the window``, lower = more distinctive (0: no finite competitor, 1: ``0 / 0``).
    accepted : numpy.ndarray, bool, (n_q,)
        ``ratio <= ratio_threshold`` and a finite ``best_score``.
    complete : numpy.ndarray, bool, (n_q,)
        Whether the best trajectory stays inside the database.
    velocities : numpy.ndarray, float64
    exact : bool
        Whether every database row was searched for every query.
    cells : int
        (database, query) cells whose trajectory score was computed.
    score : numpy.ndarray, float32, (n_db, n_q), or None
        OpenSeqSLAM's sequence score (lower = better, ``inf`` off the database); dense only.
    """

    similarity: np.ndarray
    best_db: np.ndarray
    best_score: np.ndarray
    ratio: np.ndarray
    accepted: np.ndarray
    complete: np.ndarray
    velocities: np.ndarray
    exact: bool = True
    cells: int = 0
    score: np.ndarray | None = None


def _trajectory_scores(DD: np.ndarray, offsets: np.ndarray, ds: int, causal: bool,
                       chunk: int) -> tuple[np.ndarray, np.ndarray]:
    """Complete-trajectory scores ``S`` and partial-trajectory scores ``P``.

    Both are rescaled to ``ds + 1`` frames: ``(ds + 1) * mean`` over the points used. ``S`` is ``inf`` unless every
    point whose query frame exists lies in the database; ``P`` uses the points inside the matrix (``inf`` if none).
    """
    n_db, n_q = DD.shape
    n_pts = ds + 1
    k = np.arange(n_pts)
    a = ds if causal else ds // 2               # window position of the anchor query
    anchor = offsets[:, ds] if causal else np.full(len(offsets), ds // 2)
    rel = offsets - anchor[:, None]             # row of point k = anchor row + rel[v, k]
    pad = int(np.abs(rel).max()) if rel.size else 0
    # Zero padding makes out-of-matrix points contribute nothing; the point counts below say which trajectories were
    # cut.
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


@dataclass(frozen=True)
class SeqSlamConf:
    """SeqSLAM's trajectory and enhancement parameters (OpenSeqSLAM's defaults), checked once where built.

    ``ds`` sequence length minus one (even unless ``causal``; 0: one frame, which the ``seqslam`` method refuses),
    ``v_min``, ``v_max``, ``v_step`` the velocities searched (database rows per query frame), ``R`` the contrast
    enhancement's window, ``rwindow`` the uniqueness test's, ``ratio_threshold`` its bar, ``causal`` the trajectory
    ends at the query instead of being centred on it, ``enhance`` the contrast enhancement applied (False: the raw
    differences).
    """

    ds: int = 10
    v_min: float = 0.8
    v_max: float = 1.2
    v_step: float = 0.1
    R: int = 10
    rwindow: int = 10
    ratio_threshold: float = 0.9
    causal: bool = False
    enhance: bool = True

    def __post_init__(self):
        check_sequence_params(**{k: v for k, v in self.as_dict().items() if k != "enhance"})

    @classmethod
    def of(cls, conf: SeqSlamConf | None = None, **params) -> SeqSlamConf:
        """``conf`` (None: the defaults) with ``params`` over it (an unknown name: ValueError naming the known)."""
        unknown = sorted(set(params) - set(cls.__dataclass_fields__))
        if unknown:
            raise ValueError(f"unknown SeqSLAM parameter {', '.join(unknown)}; known: "
                             f"{', '.join(cls.__dataclass_fields__)}")
        return cls(**{**(conf.as_dict() if conf is not None else {}), **params})

    @classmethod
    def from_conf(cls, conf) -> SeqSlamConf:
        """The fields found in ``conf`` (a method's whole conf) over the defaults."""
        return cls(**{f: conf[f] for f in cls.__dataclass_fields__ if f in conf})

    def as_dict(self) -> dict:
        """The parameters as :func:`seqslam` and :func:`vpr.seqslam.seqslam_topk` take them."""
        return {f: getattr(self, f) for f in self.__dataclass_fields__}


def check_sequence_params(ds, causal, v_min, v_max, v_step, R, rwindow, ratio_threshold):
    """The trajectory and enhancement parameters shared by :func:`seqslam` and :func:`seqslam_topk`.

    ``ds`` 0 is sequences of one frame (the enhanced single-frame differences; the ``seqslam`` method refuses it).
    """
    ds = check_int(ds, "ds", 0)
    if not causal and ds % 2:
        raise ValueError(f"ds: must be even for the centred window (OpenSeqSLAM rounds it up), got {ds}")
    velocities, offsets = trajectory_offsets(ds, v_min, v_max, v_step)
    R = check_int(R, "R", 2)
    rwindow = check_int(rwindow, "rwindow", 0)
    return ds, velocities, offsets, R, rwindow, check_float(ratio_threshold, "ratio_threshold")


def seqslam(D, conf: SeqSlamConf | None = None, chunk: int = 256, **params) -> SeqSLAMResult:
    """SeqSLAM trajectory search and uniqueness test on a difference matrix, as OpenSeqSLAM (``docs/internals.md``).

    Parameters
    ----------
    D : array_like, shape (n_db, n_q)
        Finite differences, database x query, lower = more similar (non-negative unless ``enhance``).
    conf : SeqSlamConf, optional
        The parameters (default: OpenSeqSLAM's), ``params`` over them by name: ``ds`` (each trajectory visits
        ``ds + 1`` query frames; even unless ``causal``, an odd one is refused), ``v_min``, ``v_max``, ``v_step``
        (velocities searched, database rows per query frame: :func:`trajectory_offsets`), ``R`` (contrast-enhancement
        window: :func:`enhance_contrast`, applied when ``enhance``), ``rwindow`` (the second best is searched outside
        rows ``best - rwindow//2 .. best + rwindow//2``), ``ratio_threshold`` (a match is accepted when ``ratio <=
        ratio_threshold``), ``causal`` (query frames ``q - ds .. q``, online, instead of OpenSeqSLAM's ``q - ds/2 .. q
        + ds/2``), ``enhance``.
    chunk : int
        Query columns processed at once (memory only).

    Returns
    -------
    SeqSLAMResult

    Bad ``D`` or parameters raise ValueError naming the argument.
    """
    D = check_difference(D, "D")
    c = SeqSlamConf.of(conf, **params)
    causal, enhance = c.causal, c.enhance
    ds, velocities, offsets, R, rwindow, ratio_threshold = check_sequence_params(
        c.ds, causal, c.v_min, c.v_max, c.v_step, c.R, c.rwindow, c.ratio_threshold)
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
    return SeqSLAMResult(similarity=similarity, best_db=best, best_score=best_val, ratio=ratio, accepted=accepted,
                         complete=complete, velocities=velocities, exact=True, cells=int(S.size), score=S)


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
    """SeqSLAM end to end on two image sequences (any images :func:`vpr.imageproc.to_grey` takes).

    Each image is preprocessed (:func:`vpr.imageproc.seqslam_preprocess`: grey, ``size`` = (w, h), ``patch``
    normalisation), then :func:`difference_matrix` with ``metric`` and :func:`seqslam` with ``**kw``; returns a
    :class:`SeqSLAMResult`.
    """
    db = seqslam_descriptors(db_images, size, patch, "db_images")
    q = seqslam_descriptors(q_images, size, patch, "q_images")
    return seqslam(difference_matrix(db, q, metric=metric), **kw)


def pixel_descriptors(images, name: str = "images") -> np.ndarray:
    """OpenSeqSLAM's descriptor of every image with its defaults: 64 x 32 grey, 8 x 8 patch-normalised, flattened.

    What the ``seqslam`` method reads as its ``"pixels"`` input (:func:`vpr.imageproc.seqslam_descriptors`); float32,
    (n_images, 2048).
    """
    return seqslam_descriptors(images, name=name)

