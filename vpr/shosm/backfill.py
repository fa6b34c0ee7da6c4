"""A loop closure's path before it: the frames that led up to a confirmed closure, accepted with it."""
from __future__ import annotations

from collections import deque

import numpy as np

from vpr.types import Decision

from .confirm import decisions_of_state, decisions_state

__all__ = ["Backfill", "backfill_closures"]


class Backfill:
    """The frames of a path that led up to a confirmed closure, accepted with it.

    The path rule accepts a revisit once its score reaches the rule's bar, many frames after the revisit began; the
    frames before, on the same path, were the same revisit. A frame not accepted waits while it is on a path that may
    still be accepted: its best earlier frame is a candidate, its score is above 0 and below the bar (a frame whose
    closure was refused at or above it, by the confirmation, a stop or a second opinion, is no such path), and each
    frame after it continues the path (its best at most ``back`` behind and ``ahead`` beyond the frame before's).
    When a closure of that path is accepted (after its confirmation), the frames waiting within ``frames`` before it
    are accepted too, each onto its own best; a frame that leaves the path, or is more than ``frames`` old, leaves as
    it was decided. Decisions leave in frame order.

    The decisions' scores are read as the path rule's: a path score that rises to ``accept_score``, the rule's bar
    (:attr:`vpr.types.Decider.accept_score`); a rule whose score is another (a registered :class:`LoopRule`) takes
    ``frames`` 0, which accepts nothing back.
    """

    def __init__(self, frames: int, back: int, ahead: int, accept_score: float):
        self.frames, self.back, self.ahead, self.bar = int(frames), int(back), int(ahead), float(accept_score)
        self.held: deque[Decision] = deque()

    def push(self, ds: list[Decision]) -> list[Decision]:
        """Decisions leaving the confirmation, in frame order; returns those final now, in frame order."""
        out: list[Decision] = []
        for d in ds:
            self._one(d, out)
        return out

    def flush(self) -> list[Decision]:
        """The session or the stream ends: every waiting frame leaves as it was decided."""
        out = list(self.held)
        self.held.clear()
        return out

    def _one(self, d: Decision, out: list) -> None:
        if self.held and not self._continues(self.held[-1], d):
            out.extend(self.flush())
        if d.accepted:  # every frame still held is within ``frames`` of it (older ones left below)
            out.extend(Decision(h.best, h.score, True, h.margin, h.frame, h.column) for h in self.flush())
            out.append(d)
            return
        while self.held and int(d.frame) - int(self.held[0].frame) >= self.frames:
            out.append(self.held.popleft())
        if self.frames > 0 and d.best >= 0 and 0 < d.score < self.bar:
            self.held.append(d)
        else:
            out.extend(self.flush())
            out.append(d)

    def _continues(self, h: Decision, d: Decision) -> bool:
        step = int(d.best) - int(h.best)
        return int(d.frame) == int(h.frame) + 1 and d.best >= 0 and -self.back <= step <= self.ahead

    # ------------------------------------------------------------- state
    def state(self) -> tuple[dict, dict]:
        """(header, arrays): the waiting frames' decisions (:meth:`load_state`)."""
        return decisions_state(list(self.held))

    def load_state(self, header: dict, arrays: dict) -> Backfill:
        """Continue from a :meth:`state` (raises ValueError on inconsistent arrays)."""
        self.held = deque(decisions_of_state(header, arrays, "back-fill"))
        return self


def backfill_closures(decision: Decision, frames: int, back: int, ahead: int, accept_score: float,
                      sessions=(0,)) -> Decision:
    """Decisions already taken (arrays, every frame of a stream in order, after their confirmation) as
    :class:`Backfill` leaves them (``sessions``: each session's first frame; nothing waits across one)."""
    T = np.asarray(decision.best).size
    b = Backfill(frames, back, ahead, accept_score)
    starts, out = {int(s) for s in sessions} - {0}, []
    for j in range(T):
        if j in starts:
            out.extend(b.flush())
        out.extend(b.push([Decision(int(decision.best[j]), float(decision.score[j]), bool(decision.accepted[j]),
                                    float(decision.margin[j]), j)]))
    out.extend(b.flush())
    return Decision.stack(out)
