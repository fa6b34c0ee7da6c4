"""Deciders (:class:`vpr.types.Decider`): ``decide(column) -> Decision``, one frame at a time, with the state a
stream carries."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from vpr import sdr as _sdr
from vpr.checks import check_exclude
from vpr.similarity import n_candidates, stationary
from vpr.statefile import joint_state, part_state
from vpr.types import Column, Decider, Decision

from .conf import LoopConf, PathConf
from .evidence import LoopEvidence
from .kernels import decide as KD

__all__ = ["LoopRule", "LoopDecider", "PathDecider", "LOOP_RULES", "loop_rule", "decide_all", "accept_loops",
           "accept_path", "stationary_closures", "STAND_FRAMES", "UNMOVED_SHARE", "map_places", "standing",
           "refuse_stands"]


class PathDecider(Decider):
    """The localisation decision against a map, query frame by query frame (:class:`vpr.shosm.PathConf`).

    ``starts``: the first map frame of each session of the map (a path does not move on across one). The state is the
    path's score, head and start.
    """

    def __init__(self, conf: PathConf | None = None, starts=None):
        self.conf = conf or PathConf()
        self._rule = self.conf.rule
        self.st = KD.path_state()
        self._place = np.zeros(0, np.int64)
        self.starts = np.zeros(1, np.int64) if starts is None else np.asarray(starts, np.int64)
        self.frames = 0

    @property
    def accept_score(self) -> float:
        return float(self.conf.min_score)

    def _decide(self, column: Column) -> Decision:
        best, score, ok, margin = self._step(column, self.st)
        return Decision(int(best), float(score), bool(ok), float(margin), column.frame, column)

    def _step(self, column: Column, st: np.ndarray) -> tuple:
        """(best, score, accepted, margin) of ``column`` on the path state ``st`` (updated)."""
        n = int(column.n)
        if self._place.size < n:
            self._place = np.arange(max(n, 2 * self._place.size), dtype=np.int64)
        return KD.locate_frame(KD.ColumnArgs(column.rows, column.z.astype(np.float64), n, float(column.fill)),
                               self._rule, self._place, st, self.starts)

    def accepted_ahead(self, columns) -> bool:
        """Whether the path of the frame just decided is accepted on one of the next ``columns`` (in order) before it
        breaks (a best more than ``back`` behind or ``ahead`` beyond the path's head, in another session, or the score
        down to 0); the state is left as it was (a copy is stepped)."""
        st = self.st.copy()
        if st[0]["score"] <= 0.0:
            return False
        for column in columns:
            head = int(st[0]["head"])
            best, score, ok, _ = self._step(column, st)
            on = (head - self.conf.back <= best <= head + self.conf.ahead
                  and KD.session_of(self.starts, best) == KD.session_of(self.starts, head))
            if not on or score <= 0.0:
                return False
            if ok:
                return True
        return False

    def new_session(self) -> None:
        """A new query traverse: no path yet."""
        self.st[:] = KD.path_state()

    def state(self) -> tuple[dict, dict]:
        return {"frames": self.frames}, {"path": self.st.copy()}

    def load_state(self, header: dict, arrays: dict) -> PathDecider:
        self.st[:] = np.asarray(arrays["path"], KD.PATH_STATE)
        self.frames = int(header.get("frames", 0))
        return self


class LoopRule(Decider):
    """The contract of a loop-closure rule: decides frame ``column.frame`` of one stream (columns in order) as a
    closure onto an earlier frame or a new place. Registered by name in :data:`LOOP_RULES`, chosen with
    ``rshosm-seq.loop_rule``, built as ``Rule(loop, path, sdr, n_bits=...)``: the :class:`LoopConf`, the
    :class:`PathConf` of a later session's frames against the earlier ones, the stream's SDRs at once (else
    :meth:`add_sdr`) and their width (``n_bits``; that of ``sdr`` where it is given).
    """

    def __init__(self, loop: LoopConf | None = None, path: PathConf | None = None, sdr=None,
                 n_bits: int | None = None):
        self.loop = loop or LoopConf()
        self.path = path or PathConf()
        self.starts = np.zeros(1, np.int64)
        self.frames = 0
        self.n_bits = int(sdr.shape[1]) if sdr is not None else None if n_bits is None else int(n_bits)

    @property
    def accept_score(self) -> float:
        return float(self.loop.min_score)

    def decide(self, column: Column) -> Decision:
        if column.frame != self.frames:
            raise ValueError(f"frames must be decided in order: expected frame {self.frames}, got {column.frame}")
        return super().decide(column)


class LoopDecider(LoopRule):
    """The path rule of one stream, frame by frame (:class:`vpr.shosm.LoopConf`; ``LOOP_RULES["path"]``).

    The stop check reads the stream's SDRs, given frame by frame with
    :meth:`add_sdr` (or all at once with ``sdr``), and their width ``n_bits`` (``sdr``'s where it is given; raises
    ValueError where the check is on and neither is). :meth:`new_session` starts
    a new run of the robot: the path restarts, and never moves on across the boundary. A frame of a later session is
    also decided against the earlier sessions by a :class:`PathDecider` (``path``), as ``vpr localize`` decides
    against a map: a robot's second run over its first is localisation; either decision accepts.
    """

    def __init__(self, loop: LoopConf | None = None, path: PathConf | None = None, sdr=None,
                 n_bits: int | None = None, capacity: int = 1024):
        super().__init__(loop, path, sdr, n_bits)
        self.map_rule = PathDecider(self.path)  # against the earlier sessions
        self.place = np.arange(capacity, dtype=np.int64)
        self.path_b = np.full(capacity, -1, np.int64)
        self.st = KD.path_state()
        self._stops = float(self.loop.stop_ratio) > 0
        if self._stops and (self.n_bits is None or self.n_bits < 1):
            raise ValueError("the stop check (stop_ratio > 0) needs the SDRs' width: give sdr or n_bits")
        self._rule = self.loop.rule
        x = None if sdr is None else _sdr.check_batch(sdr, name="sdr")
        self._rows = _sdr.RowLog() if x is None else _sdr.RowLog(x.indptr, x.indices)

    def new_session(self) -> None:
        """The next frame starts a new session: no path carries over into it."""
        if self.frames > self.starts[-1]:
            self.starts = np.r_[self.starts, self.frames]
        self.st[:] = KD.path_state(self.frames)
        self.map_rule.starts = self.starts[:-1]
        self.map_rule.new_session()

    def add_sdr(self, bits) -> None:
        """Append the next frame's active bits (sorted) for the stop check (amortised O(bits))."""
        if self._stops:
            self._rows.append(bits)

    @property
    def rows(self) -> _sdr.RowLog | None:
        """The stream's SDR rows the stop check reads; None without a stop check."""
        return self._rows if self._stops else None

    def _decide(self, column: Column) -> Decision:
        j = column.frame
        if j + 1 > self.place.size:
            size = max(j + 1, 2 * self.place.size)
            self.place = np.concatenate([self.place, np.arange(self.place.size, size, dtype=np.int64)])
            self.path_b = np.concatenate([self.path_b, np.full(size - self.path_b.size, -1, np.int64)])
        vals = column.z.astype(np.float64)
        best, score, ok, margin, _ = KD.decide_frame(
            j, KD.ColumnArgs(column.rows, vals, int(column.n), float(column.fill)), self._rule,
            (self._rows.ptr, self._rows.ind, self.place, self.path_b, self.st, self.starts, self.n_bits or 1))
        start = int(self.starts[-1])
        if start > 0 and not ok:  # a later session: its frame against the earlier ones, as against a map
            keep = column.rows < start
            d = self.map_rule.decide(Column(column.rows[keep], vals[keep], float(column.fill), start, j))
            if d.accepted:
                best, score, ok, margin = d.best, d.score, True, d.margin
                if self.place[j] == j:
                    self.place[j] = self.place[d.best]
        return Decision(int(best), float(score), bool(ok), float(margin), j, column)

    def state(self) -> tuple[dict, dict]:
        n = self.frames
        header, arrays = joint_state(map=self.map_rule)
        return {**header, "frames": n}, {**arrays, "place": self.place[:n].copy(), "path_b": self.path_b[:n].copy(),
                                         "st": self.st.copy(), "sdr_ptr": self._rows.ptr.copy(),
                                         "sdr_ind": self._rows.ind.copy(), "starts": self.starts.copy()}

    def load_state(self, header: dict, arrays: dict) -> LoopDecider:
        n = int(header["frames"])
        self.place = np.arange(max(n, 1024), dtype=np.int64)
        self.path_b = np.full(self.place.size, -1, np.int64)
        self.place[:n], self.path_b[:n] = arrays["place"], arrays["path_b"]
        self.st[:] = np.asarray(arrays["st"], KD.PATH_STATE)
        self._rows = _sdr.RowLog(arrays["sdr_ptr"], arrays["sdr_ind"])
        self.starts = np.asarray(arrays["starts"], np.int64)
        self.map_rule.load_state(*part_state(header, arrays, "map"))
        self.map_rule.starts = self.starts[:-1]
        self.frames = n
        return self


#: The loop rules by name (``rshosm-seq.loop_rule``): a new rule is a :class:`LoopRule` and one line here.
LOOP_RULES: dict[str, type[LoopRule]] = {"path": LoopDecider}


def loop_rule(name: str) -> type[LoopRule]:
    """The loop rule registered as ``name`` in :data:`LOOP_RULES` (ValueError naming the known ones)."""
    try:
        return LOOP_RULES[name]
    except KeyError:
        raise ValueError(f"rshosm-seq: loop_rule {name!r} is not a loop rule (known: "
                         f"{', '.join(sorted(LOOP_RULES))})") from None


def decide_all(decider: Decider, columns) -> Decision:
    """Every column of a traverse decided in order by ``decider``: a :class:`~vpr.types.Decision` of arrays."""
    return Decision.stack(decider.decide(c) for c in columns)


def accept_loops(evidence, conf: LoopConf | None = None, sdr=None, exclude: int | None = None,
                 path: PathConf | None = None, rule: str = "path") -> Decision:
    """The loop decision of every frame of a stored loop matrix (:class:`LoopDecider`), causal.

    Frame ``j``'s best earlier frame stands out by ``z_best - z_other`` (earlier visits of the same place, linked by
    accepted closures, are not other places); along a consistent path the margins minus ``drift`` add up, restarting
    at 0 when the path breaks; a closure is accepted at ``min_score`` unless it is the place just left or (with the
    SDRs) the camera never left it (``research/docs/loops.md``). On a stored top-K matrix an island may be cut where
    entries
    were dropped: :func:`vpr.shosm.loop_evidence` decides on full columns.

    ``evidence``: a LoopEvidence or a dense T x T loop matrix; ``sdr`` (T rows): optional, for the stop check;
    ``exclude``: read from an Evidence; ``path``: the decision of a later session's frames (default: its defaults);
    ``rule``: a name in :data:`LOOP_RULES`.
    """
    conf = conf or LoopConf()
    fill, starts = None, (0,)
    if isinstance(evidence, LoopEvidence):
        S, fill, exclude, starts = evidence.similarity, evidence.fill, evidence.exclude, tuple(evidence.starts)
    else:
        S = evidence
        if exclude is None:
            raise ValueError("accept_loops needs exclude with a plain loop matrix (or pass the Evidence)")
        if sp.issparse(S):
            raise ValueError("a top-K loop matrix needs the z of its missing candidates: pass the Evidence")
    exclude = check_exclude(int(exclude))
    T = S.shape[1]
    x = None if sdr is None else _sdr.check_batch(sdr, name="sdr")
    if x is not None and x.shape[0] != T:
        raise ValueError(f"sdr has {x.shape[0]} rows for a stream of {T} frames")
    decider = loop_rule(rule)(conf if x is not None else LoopConf(**{**conf.as_dict(), "stop_ratio": 0.0}), path, x)
    C = sp.csc_matrix(S) if sp.issparse(S) else None
    if C is not None:
        C.sort_indices()
    arange = np.arange(T, dtype=np.int64)
    begin = set(starts) - {0}

    def columns():
        start = 0
        for j in range(T):
            if j in begin:
                decider.new_session()
                start = j
            n = n_candidates(j, exclude, start)
            if C is not None:
                a, b = C.indptr[j], C.indptr[j + 1]
                keep = C.indices[a:b] < n
                yield Column(C.indices[a:b][keep].astype(np.int64), C.data[a:b][keep], float(fill[j]), n, j)
                continue
            rows, vals, f = arange[:n], S[:n, j], 0.0
            if fill is not None:  # an Evidence: the entries equal to the fill are candidates without evidence
                keep = vals != fill[j]
                rows, vals, f = rows[keep], vals[keep], float(fill[j])
            yield Column(rows, vals, f, n, j)

    return decide_all(decider, columns())


def accept_path(S, conf: PathConf | None = None, sessions=None) -> Decision:
    """The decision against a map of every query of a traverse, in order (:class:`PathDecider`).

    So that ``vpr match`` / ``compare`` accept what ``vpr localize`` would, with the same score, on the batch
    evidence. ``S``: n_db x n_q z-scores, dense or top-K sparse (a missing entry counts as the column's lowest stored
    z); ``sessions``: the first database frame of each session of the map.
    """
    decider = PathDecider(conf or PathConf(), sessions)
    n_db, n_q = S.shape
    if sp.issparse(S):
        C = sp.csc_matrix(S)
        C.sort_indices()
        cols = ((C.indices[C.indptr[j]:C.indptr[j + 1]].astype(np.int64), C.data[C.indptr[j]:C.indptr[j + 1]])
                for j in range(n_q))
    else:
        A = np.asarray(S)
        rows_all = np.arange(n_db, dtype=np.int64)
        cols = ((rows_all[np.isfinite(A[:, j])], A[np.isfinite(A[:, j]), j]) for j in range(n_q))
    return decide_all(decider, (Column(r, v, float(v.min()) if v.size else 0.0, n_db, j)
                                for j, (r, v) in enumerate(cols)))


def map_places(codes, cells_per_column: int, sessions=(0,)) -> np.ndarray:
    """Each map frame's place number: the next frame has the next number unless the memory learned it as the same
    minicolumns as the frame before in its session (the camera stood: one place under several frame numbers).

    ``codes``: the map's winner cells (:meth:`SequenceMemory.run`, cell ``c`` in minicolumn ``c // cells_per_column``);
    ``sessions``: each session's first frame.
    """
    c = sp.csr_matrix(codes)
    n = c.shape[0]
    if n < 2:
        return np.zeros(n, np.int64)
    width = -(-c.shape[1] // int(cells_per_column))
    cols = sp.csr_matrix((np.ones(c.nnz, np.int32), c.indices // int(cells_per_column), c.indptr.copy()),
                         shape=(n, width))  # its own arrays: summing duplicates rewrites them
    cols.sum_duplicates()
    cols.data[:] = 1
    size = np.diff(cols.indptr)
    shared = np.asarray(cols[1:].multiply(cols[:-1]).sum(axis=1)).ravel()
    same = (size[1:] > 0) & (shared == size[1:]) & (shared == size[:-1])
    starts = np.asarray([s for s in sessions if 0 < int(s) < n], np.int64)
    same[starts - 1] = False  # a session's first frame follows no frame of the map
    return np.r_[0, np.cumsum(~same)].astype(np.int64)


#: :data:`vpr.sdr.UNMOVED_SHARE`: a query frame that kept this share of the frame before's bits is not accepted
UNMOVED_SHARE = _sdr.UNMOVED_SHARE

#: Map frames of one place (:func:`map_places`) from which on no frame number singles out an answer: with 2, the
#: answer is within a frame of the query's own either way; with 3 or more, it may not be.
STAND_FRAMES = 3


def standing(places, frames: int = STAND_FRAMES) -> np.ndarray:
    """Per map frame, whether it is one of ``frames`` or more map frames of one place (``places``:
    :func:`map_places`, one number per frame, non-decreasing): a frame of a stand."""
    p = np.asarray(places, np.int64)
    if p.size == 0:
        return np.zeros(0, bool)
    _, count = np.unique(p, return_counts=True)
    return np.repeat(count >= int(frames), count)


def refuse_stands(best, accepted, map_standing, query_unmoved):
    """``accepted`` without the answers that no frame number singles out: onto a map frame of a stand
    (:func:`standing`), or of a query frame that did not move since the frame before (:func:`vpr.sdr.unmoved`; the
    evidence, which expects the query to move on, runs ahead of it). Arrays of a traverse, or one frame's scalars."""
    best = np.asarray(best, np.int64)
    on_stand = np.asarray(map_standing, bool)[np.clip(best, 0, None)] & (best >= 0)
    out = np.asarray(accepted, bool) & ~np.asarray(query_unmoved, bool) & ~on_stand
    return bool(out) if out.ndim == 0 else out


def stationary_closures(sdr, best, accepted, ratio: float = 0.35) -> np.ndarray:
    """Which accepted closures ``best[j] -> j`` are onto a place the camera never left
    (:func:`vpr.similarity.stationary`).

    Returns
    -------
    bool per frame: accepted and stationary.
    """
    ratio = float(ratio)
    if not 0.0 < ratio < 1.0:
        raise ValueError(f"stop_ratio must be in (0, 1), got {ratio}")
    x = _sdr.check_batch(sdr, name="sdr")
    best, accepted = np.asarray(best), np.asarray(accepted, bool)
    if len(best) != x.shape[0] or len(accepted) != x.shape[0]:
        raise ValueError(f"best and accepted need one entry per frame of the stream ({x.shape[0]}), "
                         f"got {len(best)} and {len(accepted)}")
    x = x.copy()
    x.sort_indices()
    ptr, ind = x.indptr.astype(np.int64), x.indices.astype(np.int64)
    out = np.zeros(x.shape[0], bool)
    for j in np.flatnonzero(accepted & (best >= 0)):
        out[j] = stationary(ptr, ind, int(best[j]), int(j), ratio, x.shape[1])
    return out
