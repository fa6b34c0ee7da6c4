"""A geometric second opinion on loop closures: a decider over another, with two-view inliers where geometry can see."""
from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from vpr import sdr as _sdr
from vpr.similarity import stationary
from vpr.types import Column, Decider, Decision

from .verifier import Verifier

__all__ = ["opinion_around", "OpinionConf", "GeometricOpinion", "second_opinion"]


@dataclass(frozen=True)
class OpinionConf:
    """When geometry confirms a closure (``docs/internals.md``)."""

    min_inliers: int = 40
    #: the bar instead of ``min_inliers`` where the wrapped rule's path score is above 0 (its sequence evidence already
    #: stands out on this path); 0: ``min_inliers`` there too
    rising_inliers: int = 0
    frames: int = 3
    #: frames that must verify before geometry accepts (the first of a run is not enough) ...
    verified_frames: int = 2
    #: ... among the last this many frames checked (blind ones skipped; equal to ``verified_frames``: in a row)
    verified_within: int = 3
    #: once geometry accepted a frame, the frames continuing its path need only this many inliers, and a blind one none
    #: (tracking, as against finding it: ORB-SLAM's lower bar for tracking than for relocalisation); 0: every frame
    #: needs ``min_inliers`` and its run
    keep_inliers: int = 10
    #: a path the wrapped rule accepts is refused while none of its frames (its run since its score last stood at 0,
    #: the accepted ones too) reached ``min_inliers`` and the last this many geometry saw all have fewer than
    #: ``keep_inliers``; blind frames are not seen (0, the default: never refused; ``research/docs/loops.md``)
    refuse_after: int = 0
    #: frames between the earlier frame and this one checked for a break of view (spread, the middle first)
    break_samples: int = 8
    #: out of sight: a frame between has fewer inliers with the earlier frame than this share of this frame's
    break_ratio: float = 0.25
    #: the pair must also have this share of the inliers the earlier frame has with its own neighbour ``self_gap``
    #: frames on (one place seen twice from almost the same pose): a bar in the stream's own units (0: none)
    self_ratio: float = 0.0
    self_gap: int = 2
    #: matches also pass the ratio test against each keypoint's own image (a pattern repeated within a frame, such as
    #: a crossing's stripes, confirms nothing: :func:`vpr.verify.own_distances`)
    distinct: bool = True
    min_side: int = 120
    min_keypoints: int = 100
    n_features: int = 2000
    max_error: float = 2.0
    #: frames whose features are kept (the least recently used dropped): memory bounded on a long stream
    max_cached: int = 512


class GeometricOpinion(Decider):
    """The wrapped decider's decision, geometry's where the path has not accepted, and geometry's refusal of a path
    it saw and never confirmed (``OpinionConf.refuse_after``) (a :class:`Decider`).

    ``decider``: the loop rule (:class:`vpr.shosm.LoopDecider`); ``image(j)``: frame ``j`` at its source's resolution,
    None where it cannot be read again (blind);
    ``back``, ``ahead``, ``stop_ratio``: :class:`vpr.shosm.LoopConf`'s; ``conf``: an :class:`OpinionConf`.
    """

    def __init__(self, decider: Decider, image, back: int, ahead: int, stop_ratio: float,
                 conf: OpinionConf | None = None):
        self.decider, self.conf = decider, conf or OpinionConf()
        self.back, self.ahead, self.stop_ratio = int(back), int(ahead), float(stop_ratio)
        self._verifier = Verifier(image, image, n_features=self.conf.n_features, max_error=self.conf.max_error,
                                  min_side=1, distinct=self.conf.distinct, max_cached=self.conf.max_cached,
                                  missing="blind")
        self._recent: list[tuple[int, int]] = []  # (best, session) of the last frames
        self._checked: list[bool] = []  # whether each frame geometry checked along the path verified, the last first
        self._tracking = False  # the path geometry accepted last goes on (keep_inliers)
        self._verified = False  # the last frame accepted by geometry
        # the wrapped rule's current path: frames geometry saw in a row under keep_inliers, whether one confirmed it
        self._seen, self._confirmed = 0, False
        self._session = 0
        self.verified = self.blind = self.accepted = self.refused = 0
        self.seconds = 0.0
        self.frames = decider.frames

    @property
    def starts(self) -> np.ndarray:
        return self.decider.starts

    @property
    def accept_score(self) -> float:
        return self.decider.accept_score

    def add_sdr(self, bits) -> None:
        self.decider.add_sdr(bits)

    @property
    def rows(self) -> _sdr.RowLog | None:
        """The wrapped decider's SDR rows (its stop check's, and this opinion's)."""
        return self.decider.rows

    @property
    def n_bits(self) -> int | None:
        """The width of the wrapped decider's SDRs."""
        return self.decider.n_bits

    def new_session(self) -> None:
        self.decider.new_session()
        self._session += 1

    def state(self) -> tuple[dict, dict]:
        """The wrapped decider's state (the stream's SDR rows with it) and the opinion's own (its recent best frames,
        its run, its counts); the features and inliers it computed are not kept (computed again as needed)."""
        header, arrays = self.decider.state()
        own = {"recent": [list(r) for r in self._recent], "checked": self._checked, "tracking": self._tracking,
               "session": self._session, "seen": self._seen, "confirmed": self._confirmed,
               "verified": self.verified, "blind": self.blind, "accepted": self.accepted, "refused": self.refused,
               "frames": self.frames}
        return {"rule": header, "opinion": own}, {f"rule_{k}": v for k, v in arrays.items()}

    def load_state(self, header: dict, arrays: dict) -> GeometricOpinion:
        self.decider.load_state(header["rule"], {k[5:]: v for k, v in arrays.items() if k.startswith("rule_")})
        own = header["opinion"]
        self._recent = [tuple(r) for r in own["recent"]]
        self._checked, self._tracking = [bool(v) for v in own["checked"]], bool(own["tracking"])
        self._session, self.frames = int(own["session"]), int(own["frames"])
        self.verified, self.blind, self.accepted = int(own["verified"]), int(own["blind"]), int(own["accepted"])
        self._seen, self._confirmed = int(own.get("seen", 0)), bool(own.get("confirmed", False))
        self.refused = int(own.get("refused", 0))
        return self

    def _consistent(self, best: int) -> bool:
        need = self.conf.frames - 1
        past = self._recent[-need:] if need else []
        if best < 0 or len(past) < need or any(s != self._session for _, s in past):
            return False
        chain = [b for b, _ in past] + [best]
        return all(a >= 0 and a - self.back <= b <= a + self.ahead for a, b in zip(chain[:-1], chain[1:], strict=True))

    @property
    def pair_verified(self) -> bool:
        return self._verified

    def _decide(self, column: Column) -> Decision:
        d = self.decider.decide(column)
        self._verified = False
        j, b = int(d.frame), int(d.best)
        consistent = self._consistent(b)
        self._recent = (self._recent + [(b, self._session)])[-max(self.conf.frames, 1):]
        if not d.score > 0:  # the wrapped rule's path starts again
            self._seen, self._confirmed = 0, False
        if d.accepted:
            self._checked, self._tracking = [], False
            return self._judge(d, b, j)
        if not consistent:
            self._checked, self._tracking = [], False
            return d
        t = time.perf_counter()
        c = self.conf
        try:
            n = self._inliers(b, j)
            if n is None:  # frames too small or bare for geometry
                return self._accept(d, b, j) if self._tracking else d
            bar = c.rising_inliers if c.rising_inliers > 0 and d.score > 0 else c.min_inliers
            ok = n >= bar and not (c.self_ratio > 0 and n < c.self_ratio * self._own(b, j))
            self._checked = ([ok] + self._checked)[:max(c.verified_within, c.verified_frames)]
            if self._tracking and n >= c.keep_inliers:
                return self._accept(d, b, j)
            self._tracking = False
            if not ok or sum(self._checked) < c.verified_frames or not self._out_of_sight(b, j, n):
                return d
            return self._accept(d, b, j)
        finally:
            self.seconds += time.perf_counter() - t

    def _inliers(self, b: int, j: int) -> int | None:
        """The distinct inliers of frames ``b`` and ``j`` (counted verified), None where either is blind (counted);
        noted for the wrapped rule's current path (:meth:`_judge`)."""
        c = self.conf
        fj = self._verifier.query_features(j)
        fb = self._verifier.db_features(b) if min(fj.size) >= c.min_side else None
        if fb is None or min(len(fj), len(fb)) < c.min_keypoints:
            self.blind += 1
            return None
        self.verified += 1
        n = self._verifier.pair_inliers(b, j)
        self._seen = self._seen + 1 if n < c.keep_inliers else 0
        self._confirmed = self._confirmed or n >= c.min_inliers
        return n

    def _judge(self, d: Decision, b: int, j: int) -> Decision:
        """A frame the wrapped rule accepted: refused while no frame of its path reached ``min_inliers`` and the last
        ``refuse_after`` geometry saw have fewer than ``keep_inliers`` (this frame is looked at until one confirms)."""
        c = self.conf
        if c.refuse_after <= 0 or self._confirmed:
            return d
        t = time.perf_counter()
        try:
            self._inliers(b, j)
        finally:
            self.seconds += time.perf_counter() - t
        if self._confirmed or self._seen < c.refuse_after:
            return d
        self.refused += 1
        return replace(d, accepted=False)

    def _accept(self, d: Decision, b: int, j: int) -> Decision:
        """``d`` accepted by geometry (:attr:`pair_verified`), unless it is onto a place the camera never left (the stop
        check); from there on the path is tracked (``keep_inliers``)."""
        rows = self.rows
        if self.stop_ratio > 0 and rows is not None and self._same_session(b, j):
            if stationary(rows.ptr, rows.ind, b, j, self.stop_ratio, self.n_bits):
                self._tracking = False
                return d
        self.accepted += 1
        self._verified = True
        self._tracking = self.conf.keep_inliers > 0
        # its score ranks it with the closures the decider accepts (the decision's curve, R@100P)
        return replace(d, accepted=True, score=max(float(d.score), self.decider.accept_score))

    def _own(self, b: int, j: int) -> int:
        """The inliers of frame ``b`` with its neighbour ``self_gap`` frames on (before ``j``, in ``b``'s session),
        or back where there is none: what one place seen twice from almost the same pose gives here."""
        gap = self.conf.self_gap
        starts = self.decider.starts
        first = int(starts[np.searchsorted(starts, b, side="right") - 1])
        k = b + gap if b + gap < j and self._same_session(b + gap, b) else b - gap
        return self._verifier.pair_inliers(b, k) if first <= k < j else 0

    def _out_of_sight(self, b: int, j: int, inliers: int) -> bool:
        """Whether some frame between ``b`` and ``j`` lost sight of ``b``: fewer inliers with it than ``break_ratio``
        of ``inliers`` (the pair's own)."""
        if not self._same_session(b, j):
            return True
        between = np.arange(b + 1, j)
        bar = self.conf.break_ratio * inliers
        if not between.size:
            return False
        # the middle first, then spread: a loop is out of sight there at once, a road ahead nowhere
        picks = np.unique(np.round(np.linspace(0, between.size - 1, self.conf.break_samples + 2)[1:-1]).astype(int))
        for k in between[picks[np.argsort(np.abs(picks - between.size // 2), kind="stable")]]:
            if self._verifier.pair_inliers(b, int(k)) < bar:
                return True
        return False

    def _same_session(self, b: int, j: int) -> bool:
        """Whether ``b`` is in the current session (across runs the camera surely left)."""
        starts = self.decider.starts
        return bool(np.searchsorted(starts, b, side="right") == np.searchsorted(starts, j, side="right"))

    def report(self) -> dict:
        """Frames verified, blind, accepted by geometry, refused by it, milliseconds per verified frame."""
        return {"frames_verified": self.verified, "frames_blind": self.blind, "accepted_by_geometry": self.accepted,
                "refused_by_geometry": self.refused,
                "ms_per_verified_frame": round(1e3 * self.seconds / max(self.verified, 1), 2),
                "min_inliers": self.conf.min_inliers, "keep_inliers": self.conf.keep_inliers}


class _Replay(Decider):
    """Decisions already taken (arrays of a whole stream), given again frame by frame, with the stream's SDRs ``x``
    (a batch, sorted rows)."""

    def __init__(self, d: Decision, starts, accept_score: float, x):
        self.d, self.starts, self._accept = d, np.asarray(starts, np.int64), float(accept_score)
        self._rows = _sdr.RowLog(x.indptr, x.indices)
        self.n_bits = int(x.shape[1])
        self.frames = 0

    @property
    def accept_score(self) -> float:
        return self._accept

    @property
    def rows(self) -> _sdr.RowLog:
        return self._rows

    def new_session(self) -> None:
        pass

    def _decide(self, column: Column) -> Decision:
        j, d = column.frame, self.d
        return Decision(int(d.best[j]), float(d.score[j]), bool(d.accepted[j]), 0.0, j)

    def state(self) -> tuple[dict, dict]:
        return {"frames": self.frames}, {}

    def load_state(self, header: dict, arrays: dict) -> _Replay:
        self.frames = int(header["frames"])
        return self


def second_opinion(decision: Decision, image, sdr, back: int, ahead: int, stop_ratio: float,
                   conf: OpinionConf | None = None, sessions=(0,), accept_score: float = float("-inf")
                   ) -> tuple[Decision, dict]:
    """The opinion over decisions already taken (arrays ``best``, ``score``, ``accepted``), and its report.

    ``accept_score``: the score at which the rule that took them accepts (geometry's accepts score at least it).
    """
    x = _sdr.check_batch(sdr, name="sdr").copy()
    x.sort_indices()
    starts = sorted({0, *(int(s) for s in sessions)})
    op = GeometricOpinion(_Replay(decision, starts, accept_score, x), image, back, ahead, stop_ratio, conf)
    out = []
    empty, none = np.zeros(0, np.int64), np.zeros(0, np.float32)
    for j in range(x.shape[0]):
        if j in starts[1:]:
            op.new_session()
        out.append(op.decide(Column(empty, none, 0.0, 0, j)))
    return Decision.stack(out), op.report()


def opinion_around(image, opinions: dict | None = None, key: str = ""):
    """``opinion(rule)``: the geometric second opinion around a loop rule (:class:`GeometricOpinion`) over
    ``image(j)``, frame ``j`` at its source's resolution, with the rule's own bounds of a consistent path; the opinion
    made is kept in ``opinions[key]`` (given)."""
    def opinion(rule):
        loop = rule.loop
        made = GeometricOpinion(rule, image, loop.back, loop.ahead, loop.stop_ratio)
        if opinions is not None:
            opinions[key] = made
        return made
    return opinion
