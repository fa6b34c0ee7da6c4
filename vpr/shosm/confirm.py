"""A loop closure confirmed by the frames after it: held until they are seen, kept where they single out its place."""
from __future__ import annotations

from collections import deque

import numpy as np
import scipy.sparse as sp

from vpr import sdr as _sdr
from vpr.checks import check_exclude
from vpr.similarity import n_candidates
from vpr.types import Column, Decision

from .kernels import confirm as KC

__all__ = ["Confirmation", "Columns", "ahead_scores", "confirm_closures", "decisions_of_state", "decisions_state",
           "look_ahead_z", "standardised_overlaps", "warm_up"]

#: The frames' columns (bit -> frames) are kept in blocks of this many frames, each built once it is whole (the
#: newer frames are read row by row).
COLUMNS_EVERY = 1024

#: Candidates within this many frames of a closure's answer are its place for the look-ahead (a path may start a
#: frame or two off the answer the evidence gave).
NEAR = 3


def standardised_overlaps(ptr, ind, q: int, n: int, n_bits: int, columns=None) -> np.ndarray:
    """The SDR overlap of row ``q`` with rows ``0 .. n - 1`` (a sorted CSR ``ptr``, ``ind`` of ``n_bits`` columns),
    standardised over them (all 0 where they do not vary). ``columns``: (block_ptr, col_rows, m), the columns (bit ->
    rows) of rows ``0 .. m - 1`` in blocks (:class:`Columns`; faster on many rows); default: row by row."""
    block_ptr, col_rows, m = columns if columns is not None else (np.zeros((0, 2), np.int64), np.zeros(0, np.int32), 0)
    out = np.zeros(n, np.float32)
    KC.standardised_overlaps(np.asarray(ptr, np.int64), np.asarray(ind, np.int64), int(q), int(n), block_ptr,
                             col_rows, int(m), np.zeros(int(n_bits), np.bool_), out)
    return out


class Columns:
    """The columns (bit -> rows, ascending) of a stream's SDR rows in blocks of ``every`` rows, each built once whole
    (amortised O(bits) a row): what :func:`standardised_overlaps` counts through."""

    def __init__(self, n_bits: int, every: int = COLUMNS_EVERY):
        self.n_bits, self.every = int(n_bits), int(every)
        self._ptr = np.zeros((0, self.n_bits + 1), np.int64)  # grown by doubling, blocks first
        self._rows = np.zeros(0, np.int32)
        self.blocks, self._used = 0, 0

    @property
    def rows(self) -> int:
        """Rows in whole blocks."""
        return self.blocks * self.every

    def extend(self, ptr, ind, n: int) -> tuple:
        """Build the blocks whole within rows ``0 .. n - 1`` (sorted CSR ``ptr``, ``ind``); returns (block_ptr,
        col_rows, rows)."""
        for a in range(self.rows, n - self.every + 1, self.every):
            b = a + self.every
            block = sp.csr_matrix((np.ones(int(ptr[b] - ptr[a]), bool), ind[ptr[a]:ptr[b]], ptr[a:b + 1] - ptr[a]),
                                  shape=(self.every, self.n_bits)).tocsc()
            block.sort_indices()
            size = block.indices.size
            if self.blocks == self._ptr.shape[0]:
                self._ptr = np.concatenate([self._ptr, np.zeros((max(self.blocks, 4), self.n_bits + 1), np.int64)])
            if self._used + size > self._rows.size:
                self._rows = np.resize(self._rows, max(2 * self._rows.size, self._used + size))
            self._ptr[self.blocks] = block.indptr + self._used
            self._rows[self._used:self._used + size] = block.indices + a
            self._used += size
            self.blocks += 1
        return self._ptr[:self.blocks], self._rows, self.rows


def look_ahead_z(z_rows: list[np.ndarray], b: int, n: int, stay: float, skip: float) -> float:
    """How far the frames of ``z_rows`` (each one's standardised scores over its candidates, the first frame's ``n``
    first) single out candidate ``b`` of the first frame: the best :func:`ahead_scores` within :data:`NEAR` of ``b``,
    in standard deviations over the other places (the candidates farther from ``b`` than a path moves in those
    frames, which could otherwise join ``b``'s path); -inf where fewer than 2 are."""
    scores = ahead_scores(z_rows, stay, skip)[:n]
    near = scores[max(0, b - NEAR):b + NEAR + 1]
    reach = 2 * len(z_rows) + NEAR
    others = np.r_[scores[:max(0, b - reach)], scores[b + reach + 1:]]
    if others.size < 2:
        return -np.inf
    sd = float(others.std())
    return (float(near.max()) - float(others.mean())) / sd if near.size and sd > 0 else -np.inf


def warm_up() -> None:
    """Compile (or load from numba's cache) the confirmation's kernels."""
    standardised_overlaps(np.zeros(3, np.int64), np.array([0, 1], np.int64), 1, 1, 2,
                          (np.zeros((0, 3), np.int64), np.zeros(0, np.int32), 0))
    ahead_scores([np.zeros(2, np.float32)] * 2, 0.05, 0.05)


def ahead_scores(z_rows: list[np.ndarray], stay: float, skip: float) -> np.ndarray:
    """The look-ahead score of every candidate of the first frame: the best sum of per-frame scores along a path
    through the frames ``z_rows`` (one row of scores over candidates per frame, later frames possibly longer), moving
    0 (cost ``stay``; negative: not allowed), 1, or 2 (cost ``skip``; negative: not allowed) candidates a frame.

    Returns one score per candidate of ``z_rows[0]``.
    """
    lens = [r.size for r in z_rows]
    width = max(lens)
    acc, nxt = np.empty(width + 2), np.empty(width + 2)
    KC.ahead_scores(np.concatenate(z_rows).astype(np.float32, copy=False), np.r_[0, np.cumsum(lens)].astype(np.int64),
                    float(stay), float(skip), acc, nxt)
    return acc[:lens[0]].copy()


class Confirmation:
    """Closures held until the frames after them are seen; kept where those frames, on their own, single out the
    closure's place (``research/docs/loops.md``, "A revisit that leaves the earlier route").

    A closure of frame ``j`` onto ``b`` waits for ``frames`` frames of its session (``j`` and the ones after it; fewer
    where the session or the stream ends first). Each of them is scored against its own candidates by its SDR overlap
    alone, standardised over them (nothing carried from before ``j``); every candidate ``i`` of ``j`` gets the best sum
    of those scores along a path starting at ``i`` (:func:`ahead_scores`, the evidence's ``stay`` / ``skip``). The
    closure is kept when the best of them within :data:`NEAR` frames of ``b`` stands ``z`` standard deviations above
    those of the other places (:meth:`look_ahead`), and is otherwise refused (``accepted`` False, the rest of the
    decision as it was). A frame that was not accepted, or accepted on its own pair's evidence (``verified``: a second
    opinion's geometry), is final at once; decisions leave in frame order, so the frames after a waiting closure wait
    with it.

    ``frames`` 0 confirms nothing (every decision leaves at once). ``exclude``: the candidates, as the stream's (a
    session starts after :meth:`end_session`); ``n_bits``: the SDRs' width; ``scored``: a dict that keeps every
    frame's standardised overlaps once computed (several confirmations of one stream share it; default: each frame's
    is dropped once no waiting closure needs it).
    """

    def __init__(self, frames: int, z: float, exclude: int, stay: float, skip: float, n_bits: int,
                 scored: dict | None = None):
        self.frames, self.z, self.exclude, self.n_bits = int(frames), float(z), int(exclude), int(n_bits)
        self.stay, self.skip = float(stay), float(skip)
        self.queue: deque[tuple[Decision, bool]] = deque()  # (decision, verified on its pair)
        self.start = 0  # the current session's first frame
        self._keep = scored is not None
        self._columns = Columns(self.n_bits)
        self._z: dict = {} if scored is None else scored  # (session start, frame) -> its standardised overlaps

    # ------------------------------------------------------------- the stream
    def push(self, d: Decision, rows: _sdr.RowLog, verified: bool = False) -> list[Decision]:
        """Frame ``d.frame``'s decision (the frames before it were pushed; ``rows``: the stream's SDR rows, this frame
        included; ``verified``: accepted on its own pair's evidence); returns the decisions now final, in frame
        order."""
        self.queue.append((d, bool(verified)))
        return self._settle(rows, int(d.frame) + 1)

    def settle(self, rows: _sdr.RowLog, end: int) -> list[Decision]:
        """Decide every waiting closure with the frames before ``end`` it has (the stream ends there); returns the
        decisions, in frame order."""
        return self._settle(rows, None, int(end))

    def end_session(self, rows: _sdr.RowLog, end: int) -> list[Decision]:
        """The session ends before frame ``end``, where the next one starts: :meth:`settle`, then the candidates are
        the next session's."""
        out = self.settle(rows, end)
        self.start = int(end)
        if not self._keep:
            self._z.clear()
        return out

    def _settle(self, rows: _sdr.RowLog, seen: int | None, end: int = 0) -> list[Decision]:
        out = []
        while self.queue:
            d, verified = self.queue[0]
            if d.accepted and self.frames > 0 and not verified:
                j = int(d.frame)
                if seen is not None and seen < j + self.frames:
                    break
                d = self._judge(d, rows, j, min(j + self.frames, end if seen is None else seen))
            out.append(d)
            self.queue.popleft()
        if not self._keep:
            oldest = int(self.queue[0][0].frame) if self.queue else (seen if seen is not None else 0)
            for key in [key for key in self._z if key[1] < oldest]:
                del self._z[key]
        return out

    def look_ahead(self, rows: _sdr.RowLog, j: int, b: int, stop: int) -> float:
        """How far frames ``j .. stop - 1`` single out candidate ``b`` of frame ``j`` on their own: the best look-ahead
        score within :data:`NEAR` of ``b`` in standard deviations over the other places (``j``'s candidates farther
        from ``b`` than a path can move in those frames; -inf where fewer than 2 are)."""
        n = n_candidates(j, self.exclude, self.start)
        return look_ahead_z([self._row(rows, q) for q in range(j, stop)], b, n, self.stay, self.skip)

    def _judge(self, d: Decision, rows: _sdr.RowLog, j: int, stop: int) -> Decision:
        if self.look_ahead(rows, j, int(d.best), stop) >= self.z:
            return d
        return Decision(d.best, d.score, False, d.margin, d.frame, d.column)

    def _row(self, rows: _sdr.RowLog, q: int) -> np.ndarray:
        """Frame ``q``'s standardised SDR overlaps with its candidates (computed once)."""
        key = (self.start, q)
        if key not in self._z:
            n = n_candidates(q, self.exclude, self.start)
            columns = self._columns.extend(rows.ptr, rows.ind, n)
            self._z[key] = standardised_overlaps(rows.ptr, rows.ind, q, n, self.n_bits, columns)
        return self._z[key]

    @property
    def needs_rows(self) -> bool:
        """Whether closures are confirmed at all (``frames`` > 0): only then is a frame's row of use."""
        return self.frames > 0

    def prepare(self, rows: _sdr.RowLog, q: int) -> None:
        """Compute frame ``q``'s standardised overlaps now (``rows`` holds it), for a closure that may wait for it;
        nothing else of the confirmation may run meanwhile (a stream computes it on another thread while it learns
        and scores the frame: it reads the rows alone)."""
        self._row(rows, q)

    # ------------------------------------------------------------- state
    def state(self) -> tuple[dict, dict]:
        """(header, arrays): the waiting decisions, with their columns (:meth:`load_state`)."""
        header, arrays = decisions_state([d for d, _ in self.queue])
        arrays["verified"] = np.array([v for _, v in self.queue], bool)
        return {**header, "start": self.start}, arrays

    def load_state(self, header: dict, arrays: dict) -> Confirmation:
        """Continue from a :meth:`state` (raises ValueError on inconsistent arrays)."""
        ds = decisions_of_state(header, arrays, "confirmation")
        self.queue = deque(zip(ds, (bool(v) for v in arrays["verified"]), strict=True))
        self.start = int(header["start"])
        self._z.clear()
        return self


def decisions_state(ds: list[Decision]) -> tuple[dict, dict]:
    """(header, arrays) of decisions of single frames, with their columns (:func:`decisions_of_state`)."""
    cols = [d.column for d in ds]
    lens = [0 if c is None else c.rows.size for c in cols]
    return ({"has_column": [c is not None for c in cols]},
            {"best": np.array([d.best for d in ds], np.int64), "score": np.array([d.score for d in ds], np.float64),
             "accepted": np.array([d.accepted for d in ds], bool),
             "margin": np.array([d.margin for d in ds], np.float64), "frame": np.array([d.frame for d in ds], np.int64),
             "col_ptr": np.r_[0, np.cumsum(lens)].astype(np.int64),
             "col_rows": np.concatenate([c.rows for c in cols if c is not None] + [np.zeros(0, np.int64)]),
             "col_z": np.concatenate([c.z for c in cols if c is not None] + [np.zeros(0, np.float32)]),
             "col_fill": np.array([np.nan if c is None else c.fill for c in cols], np.float64),
             "col_n": np.array([0 if c is None else c.n for c in cols], np.int64)})


def decisions_of_state(header: dict, arrays: dict, what: str) -> list[Decision]:
    """The decisions of a :func:`decisions_state` pair (raises ValueError naming ``what`` on inconsistent arrays)."""
    frame, ptr = np.asarray(arrays["frame"], np.int64), np.asarray(arrays["col_ptr"], np.int64)
    has = list(header["has_column"])
    if not (len(has) == frame.size == ptr.size - 1 == np.asarray(arrays["best"]).size
            and ptr[-1] == np.asarray(arrays["col_rows"]).size):
        raise ValueError(f"{what} state: the waiting decisions and their columns do not agree")
    out = []
    for k in range(frame.size):
        col = Column(np.asarray(arrays["col_rows"][ptr[k]:ptr[k + 1]], np.int64),
                     np.asarray(arrays["col_z"][ptr[k]:ptr[k + 1]], np.float32), float(arrays["col_fill"][k]),
                     int(arrays["col_n"][k]), int(frame[k])) if has[k] else None
        out.append(Decision(int(arrays["best"][k]), float(arrays["score"][k]), bool(arrays["accepted"][k]),
                            float(arrays["margin"][k]), int(frame[k]), col))
    return out


def confirm_closures(decision: Decision, sdr, exclude: int, conf=None, sessions=(0,), verified=None,
                     scored: dict | None = None) -> Decision:
    """Decisions already taken (arrays, every frame of a stream in order) as :class:`Confirmation` leaves them.

    ``sdr``: the stream's SDR batch; ``exclude`` and ``sessions`` (first frames) as the stream's; ``conf``: an
    :class:`~vpr.shosm.RshosmSeqConf` (its ``confirm_frames`` / ``confirm_z`` and the evidence's ``stay`` / ``skip``);
    ``verified``: per frame, whether a closure was accepted on its own pair's evidence (a second opinion's geometry:
    final at once); ``scored``: as :class:`Confirmation`'s (several calls on one stream and ``exclude`` share it).
    Returns the decisions with the closures the frames after them did not confirm refused.
    """
    from .conf import RshosmSeqConf

    seq = conf if isinstance(conf, RshosmSeqConf) else RshosmSeqConf.of(conf)
    loop = seq.loop()
    x = _sdr.check_batch(sdr, name="sdr").copy()
    x.sort_indices()
    T = x.shape[0]
    best, score = np.asarray(decision.best, np.int64), np.asarray(decision.score, np.float64)
    accepted, margin = np.asarray(decision.accepted, bool), np.asarray(decision.margin, np.float64)
    if not best.shape == score.shape == accepted.shape == (T,):
        raise ValueError(f"confirm_closures: decisions of {best.size} frames for an SDR batch of {T}")
    verified = np.zeros(T, bool) if verified is None else np.asarray(verified, bool)
    stay, skip = seq.evidence.costs
    c = Confirmation(loop.confirm_frames, loop.confirm_z, check_exclude(exclude), stay, skip, x.shape[1], scored)
    rows = _sdr.RowLog(x.indptr, x.indices)
    starts = sorted({int(s) for s in sessions} - {0})
    out: list[Decision] = []
    for j in range(T):
        if j in starts:
            out.extend(c.end_session(rows, j))
        out.extend(c.push(Decision(int(best[j]), float(score[j]), bool(accepted[j]), float(margin[j]), j), rows,
                          bool(verified[j])))
    out.extend(c.settle(rows, T))
    return Decision.stack(out)
