"""A loop closure placed by the frames before it where the robot drives faster than the evidence follows."""
from __future__ import annotations

from bisect import bisect_right

import numpy as np

from vpr import sdr as _sdr
from vpr.checks import check_exclude
from vpr.similarity import n_candidates
from vpr.types import RATE_RATIO, Decision

from .kernels import confirm as KC

__all__ = ["Placement", "place_closures", "MOVES"]

#: The placement's paths move up to this many candidates a frame (the evidence's transitions move up to 2).
MOVES = 3


class Placement:
    """Accepted closures answered again where the frames up to them, on their own, read a faster revisit.

    The evidence follows a revisit that moves 0 to 2 earlier frames a frame (``stay`` / ``skip``); where the robot
    drives faster, its best earlier frame lags behind the place. For an accepted closure of frame ``j`` onto ``b``,
    the ``frames`` frames up to ``j`` (of ``j``'s session) are matched on their own SDR overlaps along every path of
    candidates moving 0 to :data:`MOVES` a frame; of the paths ending within ``back`` before and ``ahead`` beyond
    ``b`` (the decision's path bounds), the best one ending elsewhere than ``b`` and scoring more replaces ``b``
    where it moves :data:`~vpr.types.RATE_RATIO` or more candidates a frame. Everything else of the decision stays.

    ``frames`` below 3 places nothing. ``exclude``: the candidates, as the stream's; ``n_bits``: the SDRs' width;
    ``speed``: the path speed from which a closure is placed (0: every closure answered by the best path).
    """

    def __init__(self, frames: int, exclude: int, back: int, ahead: int, n_bits: int, speed: float = RATE_RATIO):
        self.frames, self.exclude, self.back, self.ahead = int(frames), check_exclude(exclude), int(back), int(ahead)
        self.speed = float(speed)
        self._mask = np.zeros(int(n_bits), bool)

    def __call__(self, ds: list[Decision], rows: _sdr.RowLog, starts) -> list[Decision]:
        """``ds`` with every accepted closure placed (``rows``: the stream's SDR rows up to the last of them at least;
        ``starts``: the sessions' first frames, ascending)."""
        return [self.place(d, rows, starts[bisect_right(starts, int(d.frame)) - 1]) if d.accepted else d for d in ds]

    def place(self, d: Decision, rows: _sdr.RowLog, first: int) -> Decision:
        """Decision ``d`` (accepted) placed with the frames of its session (``first``: the session's first frame)."""
        j, b = int(d.frame), int(d.best)
        t0 = max(int(first), j - self.frames + 1)
        if self.frames < 3 or j - t0 < 2 or b < 0:
            return d
        n = n_candidates(j, self.exclude, first)
        end_lo, hi = max(0, b - self.back), min(n, b + self.ahead + 1)
        lo = max(0, end_lo - MOVES * (j - t0))
        if hi <= end_lo or b >= hi:
            return d
        n_cand = np.array([n_candidates(t, self.exclude, first) for t in range(t0, j + 1)], np.int64)
        score, start = np.empty(hi - lo), np.empty(hi - lo, np.int64)
        KC.faster_paths(rows.ptr, rows.ind, t0, lo, hi, n_cand, MOVES, self._mask, score, start)
        ends = score[end_lo - lo:]
        c = end_lo + int(np.argmax(ends))
        if not score[c - lo] > score[b - lo] or (c - start[c - lo]) < self.speed * (j - t0):
            return d
        return Decision(c, d.score, True, d.margin, d.frame, d.column)


def place_closures(decision: Decision, sdr, exclude: int, conf=None, sessions=(0,)) -> Decision:
    """Decisions already taken (arrays, every frame of a stream in order) as :class:`Placement` leaves them.

    ``sdr``: the stream's SDR batch; ``exclude`` and ``sessions`` (first frames) as the stream's; ``conf``: an
    :class:`~vpr.shosm.RshosmSeqConf` (its ``place_frames`` and path bounds). Returns the decisions with the accepted
    closures placed.
    """
    from .conf import RshosmSeqConf

    loop = (conf if isinstance(conf, RshosmSeqConf) else RshosmSeqConf.of(conf)).loop()
    x = _sdr.check_batch(sdr, name="sdr")
    best, accepted = np.asarray(decision.best, np.int64), np.asarray(decision.accepted, bool)
    if not best.shape == accepted.shape == (x.shape[0],):
        raise ValueError(f"place_closures: decisions of {best.size} frames for an SDR batch of {x.shape[0]}")
    p = Placement(loop.place_frames, exclude, loop.back, loop.ahead, x.shape[1])
    rows, starts = _sdr.RowLog(x.indptr, x.indices), sorted({0, *(int(s) for s in sessions)})
    placed = best.copy()
    for j in np.flatnonzero(accepted):
        first = starts[bisect_right(starts, int(j)) - 1]
        placed[j] = p.place(Decision(int(best[j]), 0.0, True, 0.0, int(j)), rows, first).best
    return Decision(placed, np.asarray(decision.score), accepted, np.asarray(decision.margin),
                    np.asarray(decision.frame))
