"""The loop decision, frame by frame: a closure onto the best earlier frame, or a new place.

:class:`LoopDecider` carries the state of one stream's decisions from frame
to frame (the compiled kernel is :mod:`vpr.shosm.kernels.decide`);
:func:`accept_loops` runs it over a stored loop matrix;
:func:`stationary_closures` tells a stop from a loop. The rule and its
parameters: :class:`vpr.shosm.LoopConf`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from vpr import sdr as _sdr
from vpr.checks import check_exclude
from vpr.similarity import n_candidates

from .conf import LoopConf, PathConf
from .kernels import decide as KD

__all__ = ["LoopDecisions", "LoopDecider", "PathDecider", "accept_loops", "accept_path", "stationary_closures"]


@dataclass
class LoopDecisions:
    """One decision per frame: its best earlier frame, the score of that closure and whether it is accepted.

    ``best`` is -1 for a frame without candidates; ``score`` is the path score
    of :class:`vpr.shosm.LoopConf` (0: a new place), comparable across frames
    and streams; ``margin`` how far the best place stands out this frame
    (``z_best - z_other``); ``near``: the best place is the one just left.
    """

    best: np.ndarray
    score: np.ndarray
    accepted: np.ndarray
    margin: np.ndarray
    near: np.ndarray


class LoopDecider:
    """The per-frame decision of :func:`accept_loops`, one frame at a time (the state a stream carries).

    ``decide(j, rows, vals, n_candidates, fill)`` takes frame ``j``'s column
    (the z-scores ``vals`` of the candidates ``rows``, sorted; a candidate not
    stored has the z ``fill``); frames must come in order ``0, 1, 2, ...``.
    ``sdr`` (the stream's SDR rows so far, grown with :meth:`add_sdr`) enables
    the stop check. :meth:`new_session` starts a new run of the robot: the
    path restarts, and never moves on across the boundary.
    """

    def __init__(self, conf: LoopConf | None = None, capacity: int = 1024):
        self.conf = conf or LoopConf()
        self.frames = 0
        self.place = np.arange(capacity, dtype=np.int64)
        self.path_b = np.full(capacity, -1, np.int64)
        self.st = np.array([0.0, float(KD._NONE), 0.0])
        self._set_sdr(np.zeros(1, np.int64), np.zeros(0, np.int64))
        self._check_stops = float(self.conf.stop_ratio) > 0
        self.starts = np.zeros(1, np.int64)  # the first frame of every session

    def new_session(self) -> None:
        """The next frame starts a new session: no path carries over into it."""
        if self.frames > self.starts[-1]:
            self.starts = np.r_[self.starts, self.frames]
        self.st[:] = (0.0, float(KD._NONE), float(self.frames))

    def _grow(self, n: int) -> None:
        if n > self.place.size:
            size = max(n, 2 * self.place.size)
            self.place = np.concatenate([self.place, np.arange(self.place.size, size, dtype=np.int64)])
            self.path_b = np.concatenate([self.path_b, np.full(size - self.path_b.size, -1, np.int64)])

    def add_sdr(self, bits) -> None:
        """Append the next frame's active bits (sorted) for the stop check (amortised O(bits))."""
        if not self._check_stops:
            return
        bits = np.asarray(bits, np.int64)
        n, end = self._n_sdr, int(self._sdr_buf_ptr[self._n_sdr])
        if n + 2 > self._sdr_buf_ptr.size:
            self._sdr_buf_ptr = np.resize(self._sdr_buf_ptr, 2 * (n + 2))
        if end + bits.size > self._sdr_buf_ind.size:
            self._sdr_buf_ind = np.resize(self._sdr_buf_ind, max(2 * self._sdr_buf_ind.size, end + bits.size))
        self._sdr_buf_ind[end:end + bits.size] = bits
        self._sdr_buf_ptr[n + 1] = end + bits.size
        self._n_sdr = n + 1
        self._sdr_ptr = self._sdr_buf_ptr[: n + 2]
        self._sdr_ind = self._sdr_buf_ind[: end + bits.size]

    def _set_sdr(self, ptr, ind) -> None:
        self._sdr_buf_ptr, self._sdr_buf_ind = np.array(ptr, np.int64), np.array(ind, np.int64)
        self._n_sdr = self._sdr_buf_ptr.size - 1
        self._sdr_ptr, self._sdr_ind = self._sdr_buf_ptr, self._sdr_buf_ind

    def decide(self, j: int, rows, vals, n: int, fill: float):
        """(best, score, accepted, margin, near) of frame ``j``."""
        if j != self.frames:
            raise ValueError(f"frames must be decided in order: expected frame {self.frames}, got {j}")
        self._grow(j + 1)
        c = self.conf
        out = KD.decide_frame(j, np.asarray(rows, np.int64), np.asarray(vals, np.float64), int(n), float(fill),
                              float(c.drift), float(c.min_score), int(c.back), int(c.ahead), float(c.island),
                              float(c.stop_ratio) if self._check_stops else 0.0, self._sdr_ptr, self._sdr_ind,
                              self.place, self.path_b, self.st, self.starts)
        self.frames += 1
        return out

    def state_dict(self) -> dict:
        """The state after the frames decided so far, as arrays (:meth:`load_state` continues from it)."""
        n = self.frames
        return {"place": self.place[:n].copy(), "path_b": self.path_b[:n].copy(), "st": self.st.copy(),
                "sdr_ptr": self._sdr_ptr.copy(), "sdr_ind": self._sdr_ind.copy(), "starts": self.starts.copy()}

    def load_state(self, state: dict) -> LoopDecider:
        n = int(np.asarray(state["place"]).size)
        self.frames = 0
        self._grow(n)
        self.place[:n], self.path_b[:n] = state["place"], state["path_b"]
        self.st[:] = state["st"]
        self._set_sdr(state["sdr_ptr"], state["sdr_ind"])
        self.starts = np.asarray(state.get("starts", [0]), np.int64)  # states saved before sessions: one
        self.frames = n
        return self


class PathDecider:
    """The localisation decision, one query frame at a time: the map frame's path score (:class:`PathConf`).

    ``decide(rows, vals, n_map, fill)`` takes the query frame's column over
    the map (the z-scores ``vals`` of map frames ``rows``, sorted; a map frame
    not stored has the z ``fill``) and returns (best, score, accepted, margin).
    The state is the path score and its head (:meth:`state_dict`).
    """

    def __init__(self, conf: PathConf | None = None, starts=None):
        self.conf = conf or PathConf()
        self.st = np.array([0.0, float(KD._NONE), 0.0])
        self._place = np.zeros(0, np.int64)
        #: the first map frame of every session of the map (a path does not move on across one)
        self.starts = np.zeros(1, np.int64) if starts is None else np.asarray(starts, np.int64)

    def decide(self, rows, vals, n: int, fill: float):
        if self._place.size < n:
            self._place = np.arange(n, dtype=np.int64)
        c = self.conf
        return KD.locate_frame(np.asarray(rows, np.int64), np.asarray(vals, np.float64), int(n), float(fill),
                               float(c.drift), float(c.min_score), int(c.back), int(c.ahead), float(c.island),
                               self._place, self.st, self.starts)

    def reset(self) -> None:
        """A new query traverse: no path yet."""
        self.st[:] = (0.0, float(KD._NONE), 0.0)

    def state_dict(self) -> dict:
        return {"path": self.st.copy()}

    def load_state(self, state: dict) -> PathDecider:
        if "path" in state:
            self.st[:] = np.asarray(state["path"], np.float64)
        return self


def accept_loops(evidence, conf: LoopConf | None = None, sdr=None, exclude: int | None = None) -> LoopDecisions:
    """Frame by frame: a loop closure onto the best earlier frame, or a new place.

    For frame ``j`` the best earlier frame stands out from every other place by
    ``margin = z_best - z_other``, where earlier visits of the same place
    (linked by closures accepted before) are not other places
    (:class:`vpr.shosm.LoopConf`). Along a path of consistent best matches (a
    revisit moves on with the camera) the margins minus ``drift`` add up to
    the closure's score, which restarts at 0 when the path breaks or the "new
    place" hypothesis wins; a closure is accepted when its score reaches
    ``min_score``, its best place is not the one just left, and (with the
    stream's SDRs) the camera left the place in between
    (:func:`stationary_closures`). Causal: only frames up to ``j`` are used.

    Why a path score and not a threshold per frame: a revisit keeps standing
    out frame after frame, a look-alike does so briefly; and a margin against
    the strongest other place, not a z-score against all candidates, stays
    comparable when a stream grows long or repeats itself (``docs/loops.md``).

    :func:`vpr.shosm.loop_evidence` takes the same decisions as it goes, on
    each frame's full evidence column (``LoopEvidence.decisions``); this
    function decides again on a stored matrix, e.g. under another conf. On a
    top-K matrix that is an approximation (an island may be cut where entries
    were dropped); on a dense one it is exact.

    Parameters
    ----------
    evidence : LoopEvidence, or a dense T x T loop matrix
        (a top-K sparse matrix needs its LoopEvidence, which knows its missing entries' z).
    conf : LoopConf
    sdr : SDR batch (T rows), optional
        The stream; without it stops are not checked.
    exclude : int, optional
        Frames closer than this are not candidates; read from ``evidence`` when
        it is a :class:`LoopEvidence` (required otherwise).

    Returns
    -------
    LoopDecisions
    """
    conf = conf or LoopConf()
    fill, starts = None, (0,)
    if hasattr(evidence, "similarity") and hasattr(evidence, "fill"):  # a LoopEvidence
        S, fill, exclude = evidence.similarity, evidence.fill, evidence.exclude
        starts = tuple(getattr(evidence, "starts", (0,)))
    else:
        S = evidence
        if exclude is None:
            raise ValueError("accept_loops needs exclude with a plain loop matrix (or pass the LoopEvidence)")
        if sp.issparse(S):
            raise ValueError("a top-K loop matrix needs the z of its missing candidates: pass the LoopEvidence")
    exclude = int(exclude)
    exclude = check_exclude(exclude)
    T = S.shape[1]
    decider = LoopDecider(conf if sdr is not None else LoopConf(**{**conf.as_dict(), "stop_ratio": 0.0}), T)
    x = None if sdr is None else _sdr.check_batch(sdr, name="sdr")
    if x is not None and x.shape[0] != T:
        raise ValueError(f"sdr has {x.shape[0]} rows for a stream of {T} frames")
    if x is not None and decider._check_stops:
        decider._set_sdr(x.indptr, x.indices)
    C = sp.csc_matrix(S) if sp.issparse(S) else None
    if C is not None:
        C.sort_indices()
    out = np.zeros((5, T))
    arange = np.arange(T, dtype=np.int64)
    begin = set(starts) - {0}
    start = 0
    for j in range(T):
        if j in begin:
            decider.new_session()
            start = j
        n = n_candidates(j, exclude, start)
        if C is not None:
            a, b = C.indptr[j], C.indptr[j + 1]
            keep = C.indices[a:b] < n
            rows, vals, f = C.indices[a:b][keep], C.data[a:b][keep], fill[j]
        else:
            rows, vals = arange[:n], S[:n, j]
            f = 0.0
            if fill is not None:  # a LoopEvidence: the entries equal to the fill are candidates without evidence
                keep = vals != fill[j]
                rows, vals, f = rows[keep], vals[keep], fill[j]
        out[:, j] = decider.decide(j, rows, vals, n, f)
    best = out[0].astype(np.int64)
    return LoopDecisions(best, out[1], out[2].astype(bool), out[3], out[4].astype(bool))


def accept_path(S, conf: PathConf | None = None, sessions=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The decision against a map, query by query in order, over a whole query traverse's evidence.

    The rule of :class:`vpr.Localizer` (:class:`PathDecider`, :class:`PathConf`):
    the best database frame's margin over the strongest other place, minus
    ``drift``, summed while the best frame moves on consistently; accepted
    when the sum reaches ``min_score``. So that ``vpr match`` / ``compare``
    accept what ``vpr localize`` would, with the same score, on the batch
    evidence. ``S``: n_db x n_q z-scores, dense or top-K sparse (a missing
    entry counts as the column's lowest stored z); ``sessions``: the first
    database frame of each session of the map.

    Returns
    -------
    (best, score, accepted): per query, the best database frame (-1: none), the path score, the decision.
    """
    decider = PathDecider(conf or PathConf(), sessions)
    n_db, n_q = S.shape
    best, score, ok = np.full(n_q, -1, np.int64), np.zeros(n_q), np.zeros(n_q, bool)
    if sp.issparse(S):
        C = sp.csc_matrix(S)
        C.sort_indices()
        cols = ((C.indices[C.indptr[j]:C.indptr[j + 1]], C.data[C.indptr[j]:C.indptr[j + 1]]) for j in range(n_q))
    else:
        A = np.asarray(S, np.float64)
        rows_all = np.arange(n_db, dtype=np.int64)
        cols = ((rows_all[np.isfinite(A[:, j])], A[np.isfinite(A[:, j]), j]) for j in range(n_q))
    for j, (rows, vals) in enumerate(cols):
        if not rows.size:
            decider.decide(rows, vals, n_db, 0.0)
            continue
        b, sc, accepted, _ = decider.decide(rows, vals, n_db, float(vals.min()))
        best[j], score[j], ok[j] = b, sc, accepted
    return best, score, ok


def stationary_closures(sdr, best, accepted, ratio: float = 0.35, chunk: int = 256) -> np.ndarray:
    """Which accepted closures ``best[j] -> j`` are onto a place the camera never left.

    A loop closure means the camera went elsewhere and came back: some frame
    between ``i = best[j]`` and ``j`` looks less like ``j`` than ``ratio`` times
    the overlap of ``i`` and ``j`` (SDR overlap, as a fraction of ``j``'s
    bits). When every frame in between keeps at least that much, the vehicle
    stood still or crept (a station, a traffic light) and the "closure" is a
    stop (``docs/localize.md`` has the overlaps measured at stops, revisits
    and false closures).

    Parameters
    ----------
    sdr : SDR batch (T rows), the stream.
    best : int per frame, the closure's earlier frame (-1: none).
    accepted : bool per frame, the closures to check.
    ratio : float in (0, 1)
    chunk : int
        Frames compared at once (the scan stops at the first frame that left).

    Returns
    -------
    bool per frame: accepted and stationary.
    """
    ratio = float(ratio)
    if not 0.0 < ratio < 1.0:
        raise ValueError(f"stop_ratio must be in (0, 1), got {ratio}")
    x = _sdr.check_batch(sdr, name="sdr").astype(np.float32).tocsr()
    best, accepted = np.asarray(best), np.asarray(accepted, bool)
    if len(best) != x.shape[0] or len(accepted) != x.shape[0]:
        raise ValueError(f"best and accepted need one entry per frame of the stream ({x.shape[0]}), "
                         f"got {len(best)} and {len(accepted)}")
    out = np.zeros(x.shape[0], bool)
    for j in np.flatnonzero(accepted & (best >= 0)):
        i = int(best[j])
        xj = x[j].T
        o_i = (x[i] @ xj).toarray()[0, 0]
        left = o_i == 0  # the two frames share nothing: not one place the camera stood at
        for a in range(i + 1, j, chunk):
            o = (x[a:min(a + chunk, j)] @ xj).toarray().ravel()
            if np.any(o < ratio * o_i):
                left = True
                break
        out[j] = not left
    return out
