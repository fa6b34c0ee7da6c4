"""Following a query driven at another speed than the map: the maps of one frame in k, the queries of one frame in k,
the answers between them, and online localisation that switches to them while the speed is read."""
from __future__ import annotations

import dataclasses

import numpy as np

from vpr import sdr as _sdr
from vpr.paths import MIN_RUN, speed_step
from vpr.statefile import joint_state, part_state
from vpr.types import Column, Decision, FollowingLocalizer

from .conf import PathConf
from .localizer import Localizer

__all__ = ["PICKS", "check_pick", "pick_maps", "disagree", "apart_from_neighbours", "between_maps", "fill_between",
           "path_lengths", "BestPath", "SpeedFollower"]


#: How a frame is answered by one of the ``k`` maps of one frame in ``k``: ``"path"``, the map that accepts it on the
#: longest consistent path of best frames; ``"score"``, the map of the largest path score (research/docs/localize.md).
PICKS = ("path", "score")


def check_pick(pick: str) -> str:
    if pick not in PICKS:
        raise ValueError(f"pick must be one of {', '.join(PICKS)}, got {pick!r}")
    return pick


def pick_maps(best, accepted, score, pick: str = "path", back: int = PathConf.back,
              ahead: int = PathConf.ahead) -> np.ndarray:
    """Per query frame, the map of one frame in k that answers it (:data:`PICKS`): ``"path"``, an accepting map on
    the longest consistent path of best frames (:func:`path_lengths` with ``back`` / ``ahead``; ties: the first
    map), or ``"score"``, the map of the largest score.

    ``best`` (each map's own frame numbers), ``accepted``, ``score``: one row per map, one column per query frame.
    """
    best, accepted = np.asarray(best, np.int64), np.asarray(accepted, bool)
    if check_pick(pick) == "score":
        return np.argmax(np.asarray(score), axis=0)
    lengths = np.stack([path_lengths(b, back, ahead) for b in best])
    return np.argmax(accepted * (best.shape[1] + 1) + lengths, axis=0)


def disagree(best, accepted, step: int) -> np.ndarray:
    """Per query frame, whether the maps of one frame in ``step`` that accept it place it more than ``step + 1``
    frames of the whole map apart (each map's answer is within about ``step / 2`` of the place, and a frame of it
    either way): they contradict each other, and the frame is not decided.

    ``best``, ``accepted``: one row per map, one column per query frame, answers numbered on the whole map.
    """
    best, accepted = np.asarray(best, np.int64), np.asarray(accepted, bool) & (np.asarray(best) >= 0)
    lo = np.where(accepted, best, np.iinfo(np.int64).max).min(axis=0)
    hi = np.where(accepted, best, -1).max(axis=0)
    return (accepted.sum(axis=0) >= 2) & (hi - lo > step + 1)


def apart_from_neighbours(best, accepted, step: int) -> np.ndarray:
    """Per frame of a query driven ``step`` times slower than the map, answered as ``step`` queries of one frame in
    ``step`` (``best``, ``accepted``: in the traverse's order, numbered on the map), whether its answer lies more than
    ``step + 1`` map frames from the mean of the frames just before and after it, both accepted by the other queries:
    those bracket its place (the query moves ``1 / step`` map frames a frame), so the queries contradict each other
    and the frame is not decided (:func:`disagree`, the same of the maps of one frame in ``step``)."""
    best, accepted = np.asarray(best, np.int64), np.asarray(accepted, bool) & (np.asarray(best) >= 0)
    out = np.zeros(best.size, bool)
    if best.size < 3:
        return out
    both = accepted[:-2] & accepted[2:]
    mid = (best[:-2] + best[2:]) / 2.0
    out[1:-1] = accepted[1:-1] & both & (np.abs(best[1:-1] - mid) > step + 1)
    return out


def between_maps(best, accepted, chosen, step: int) -> np.ndarray:
    """Per query frame, the answer of the maps of one frame in ``step`` that accept it and agree: the mean of their
    answers, rounded toward ``chosen`` (the answer of the map picked, :func:`pick_maps`); ``chosen`` where fewer than
    two accept or they place the frame apart (:func:`disagree`: it is not decided).

    Each map holds the place within about ``step / 2`` frames of the whole map, so two that accept a frame bracket
    it. ``best``, ``accepted``: one row per map, one column per query frame, answers numbered on the whole map;
    ``chosen``: one per query frame.
    """
    best, chosen = np.asarray(best, np.int64), np.asarray(chosen, np.int64)
    accepted = np.asarray(accepted, bool) & (best >= 0)
    n = accepted.sum(axis=0)
    mean = np.where(accepted, best, 0).sum(axis=0) / np.maximum(n, 1)
    toward = np.where(chosen >= mean, np.ceil(mean), np.floor(mean)).astype(np.int64)
    return np.where((n >= 2) & ~disagree(best, accepted, step), toward, chosen)


def fill_between(best, score, accepted, step: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Answers of a query driven ``step`` times slower than the map for its frames that were not accepted between two
    that were: a frame whose nearest accepted frames before and after, ``q0`` and ``q1``, lie at most ``step`` frames
    apart and were answered with map frames ``b0 <= b1 <= b0 + 2`` (moving on as such a query does) lies between
    their places, and takes the map frame interpolated between them, with the smaller of their scores.

    ``best``, ``score``, ``accepted``: per query frame, in the traverse's order. Returns (best, score, filled): the
    answers with those frames', and which frames were filled so (accepted there).
    """
    best, score = np.array(best, np.int64), np.array(score, np.float64)
    accepted = np.asarray(accepted, bool) & (best >= 0)
    filled = np.zeros(best.size, bool)
    acc = np.flatnonzero(accepted)
    gap, moved = np.diff(acc), np.diff(best[acc])
    for i in np.flatnonzero((gap > 1) & (gap <= step) & (moved >= 0) & (moved <= 2)):
        q0, q1 = acc[i], acc[i + 1]
        b0, b1 = best[q0], best[q1]
        q = np.arange(q0 + 1, q1)
        best[q] = b0 + np.rint((b1 - b0) * (q - q0) / (q1 - q0)).astype(np.int64)
        score[q] = min(score[q0], score[q1])
        filled[q] = True
    return best, score, filled


class BestPath:
    """A consistent path of best frames (each within ``back`` behind and ``ahead`` beyond the last): its first frame
    and best, its last best, its length, and its bests (one per frame), which read its speed."""

    def __init__(self, back: int, ahead: int):
        self.back, self.ahead = back, ahead
        self.start, self.first, self.last, self.length = -1, -1, -1, 0
        self.recent: list[int] = []

    def step(self, frame: int, best: int) -> None:
        if best >= 0 and self.length and -self.back <= best - self.last <= self.ahead:
            self.last, self.length = best, self.length + 1
            self.recent.append(best)
        else:
            self.start, self.first, self.last, self.length = frame, best, best, int(best >= 0)
            self.recent = [best] if best >= 0 else []

    def speed(self) -> float | None:
        """Best frames per frame along the path (the least-squares slope of its bests: one answer
        off moves it little), once it is :data:`~vpr.evaluate.MIN_RUN` frames long; None where the two halves of
        those frames read different speeds (faster, slower or neither: :func:`~vpr.paths.speed_step`): a path
        that moves on, then stands, is no slower speed, nor one that jumps, then moves on, a faster."""
        if len(self.recent) < MIN_RUN:
            return None
        p = np.asarray(self.recent, np.float64)
        h = p.size // 2
        v = _slope(p)
        reads = {int(np.sign(speed_step(x))) for x in (_slope(p[:h]), v, _slope(p[h:]))}
        return v if len(reads) == 1 else None

    def state(self) -> list:
        return [self.start, self.first, self.last, self.length, *self.recent]

    def restore(self, values) -> None:
        self.start, self.first, self.last, self.length = (int(v) for v in values[:4])
        self.recent = [int(v) for v in values[4:]]


def _slope(p: np.ndarray) -> float:
    """The least-squares slope of ``p`` over its index."""
    t = np.arange(p.size) - (p.size - 1) / 2
    return float(t @ (p - p.mean()) / (t @ t))


class SpeedFollower(FollowingLocalizer):
    """Online localisation that follows a query driven at another speed than the map at the same frame rate.

    Steps the map's ``localizer`` on every frame and reads the speed of the consistent path of best frames (the
    path rule's ``back`` / ``ahead``, over at least :data:`~vpr.evaluate.MIN_RUN` frames; counted in the map's places
    and the query's frames that moved, so that neither's stand reads as a speed: :meth:`_tick`) of the answers: the
    localizer's, and while a faster query is followed, those given (the localizer's evidence lags a faster
    query). While it is :data:`~vpr.groundtruth.RATE_RATIO` or more map frames a frame, the frames are answered by
    the ``step`` maps of one frame in ``step`` (learned again from ``sdr``, the map's SDRs, when first needed; each
    frame by the map whose path is accepted and longest or, where several accept it, between their answers
    (:func:`between_maps`), not accepted where they place it apart: :func:`disagree`); while it is
    ``1 / RATE_RATIO`` or less (:func:`~vpr.groundtruth.speed_step`: a path that stays on one map frame is no
    speed), by the map with the frames taken as ``step`` queries of one frame in
    ``step`` (each frame by its own; a frame its own does not accept, just after one its own accepted, by that
    one's answer: it moved less than a map frame since), and such a speed is left only at a frame they do not answer
    (the localizer's evidence runs ahead of a slower query); otherwise by ``localizer``. The engines of a speed start
    when it is read, from the last ``replay`` frames (kept for that), so that they answer with their evidence built;
    at the map's speed only ``localizer`` runs. Without ``sdr`` a faster query is answered by ``localizer``;
    ``pick``: how the map of one frame in ``step`` is chosen (:data:`PICKS`). :meth:`update` returns the map's
    :class:`~vpr.types.Decision` with the frame's number.
    """

    def __init__(self, localizer: Localizer, sdr=None, step: int = 2, replay: int = 2 * MIN_RUN, pick: str = "path"):
        self.base, self.sdr, self.step, self.replay = localizer, sdr, int(step), int(replay)
        self.pick = check_pick(pick)
        path = localizer.seq.path()
        self._bounds = path.back, path.ahead
        self.path = BestPath(*self._bounds)
        self.kept = BestPath(*self._bounds)  # the path of the accepted answers alone: a slower speed is read on it
        self.phases: list[Localizer] = []
        self.keeps: list[np.ndarray] = []
        self.phase_paths: list[BestPath] = []
        self.queries: list[Localizer] = []
        self.mode, self.frame, self.clock = 0, 0, 0  # clock: the query frames that moved (:meth:`_tick`)
        self.recent: list[tuple[int, np.ndarray]] = []  # (frame, active bits) of the last ``replay`` frames
        #: frames this object answered by the maps of one frame in ``step`` / as queries of one frame in ``step``, of
        #: them those the maps placed apart / answered by the frame before (not part of the state: a follower loaded
        #: from one counts its own)
        self.frames = {"db_step": 0, "query_step": 0, "db_apart": 0, "query_filled": 0}
        self.last: tuple[int, int, float] | None = None  # (frame, best, score) of a slower query's frame accepted on
        # its own query, the frame before this one

    @property
    def follows_faster(self) -> bool:
        """Whether a faster query can be followed (the map's SDRs are there to learn its maps of one frame in k)."""
        return self.sdr is not None and self.base.n_db >= 2 * self.step

    def _learn_phases(self) -> None:
        self.keeps = [self.base.every(self.step, a) for a in range(self.step)]
        self.phases = [self.base.relearned(self.sdr, keep) for keep in self.keeps]

    def _engines(self, mode: int) -> list[Localizer]:
        """The engines that answer at ``mode`` (+1 faster, -1 slower), built the first time."""
        if mode > 0:
            if not self.phases and self.follows_faster:
                self._learn_phases()
            return self.phases
        if mode < 0 and not self.queries:
            loc = self.base
            self.queries = [Localizer(loc.memory, loc.db_codes, loc.names, loc.seq, sessions=loc.sessions)
                            for _ in range(self.step)]
        return self.queries if mode < 0 else []

    def _start(self, mode: int) -> None:
        """Start the engines of ``mode`` afresh and give them the frames kept (those before this one)."""
        for loc in self._engines(mode):
            loc.reset()
        self.phase_paths = [BestPath(*self._bounds) for _ in self.phases]
        for j, bits in self.recent[:-1]:
            self._feed(mode, j, bits)

    def _feed(self, mode: int, j: int, bits) -> list[Decision]:
        if mode > 0:
            out = [p.update(bits) for p in self.phases]
            for path, d in zip(self.phase_paths, out, strict=True):
                path.step(j, d.best)
            return out
        return [self.queries[j % self.step].update(bits)] if mode < 0 else []

    def reset(self) -> None:
        """A new query traverse: the evidence and the paths start again."""
        self.base.reset()
        for loc in [*self.phases, *self.queries]:
            loc.reset()
        self.path.step(-1, -1)
        self.kept.step(-1, -1)
        self.mode, self.frame, self.clock, self.recent, self.last = 0, 0, 0, [], None

    def warm_up(self) -> None:
        self.base.warm_up()

    def update(self, sdr_row) -> Decision:
        """Localise one query frame (as :meth:`vpr.shosm.Localizer.update`)."""
        j = self.frame
        bits = _sdr.row_bits(sdr_row, self.base.memory.n_inputs, name="query SDR")
        self.recent = [*self.recent[-(self.replay - 1):], (j, bits)] if self.replay > 0 else []
        d = self.base.update(bits)
        self.frame += 1
        if self.mode < 0:  # a slower query's queries answer first; the speed read leaves it where they do not
            out = self._slower(j, bits, d)
            if out.accepted:
                self._tick(d.best)
            else:
                self._read(j, d.best)
            if self.mode < 0:
                self.frames["query_step"] += 1
                return out
            return self._answer(j, bits, d)
        faster = self.mode > 0 and self.follows_faster
        if not faster:  # the map's own answers read the speed
            self._read(j, d.best, d.accepted)
        out = self._answer(j, bits, d)
        if faster:  # while a faster query is followed, the answers given read it
            self._read(j, out.best)
            if self.mode < 0:  # from the faster speed to the slower: this frame too
                self._feed(self.mode, j, bits)
        return out

    def _tick(self, best: int, accepted: bool = True) -> bool:
        """Step the paths with this frame's answer (:attr:`kept` only where it is ``accepted``), on the map's places
        (a stand of the map is one) and the query's frames that moved (a stand of the query is no time); False where
        the query did not move (not stepped)."""
        if self.base.last is not None and self.base.last.unmoved:
            return False
        place = int(self.base.places[best]) if best >= 0 else -1
        self.path.step(self.clock, place)
        self.kept.step(self.clock, place if accepted else -1)
        self.clock += 1
        return True

    def _read(self, j: int, best: int, accepted: bool = True) -> None:
        """Step the path with frame ``j``'s answer and switch to the speed it reads (its engines started from the
        frames kept before ``j``); a frame where the query did not move reads nothing, and a slower speed is read only
        on the path of the map's ``accepted`` answers alone, as the batch reads a speed (:func:`vpr.paths.path_runs`;
        its evidence follows a slower query; a path it does not accept, as after a stand or on a reversed query, moves
        slowly too)."""
        if not self._tick(best, accepted):
            return
        v = self.path.speed()
        mode = self.mode if v is None else int(np.sign(speed_step(v)))
        if mode < 0 <= self.mode and speed_step(self.kept.speed()) >= 0:
            mode = self.mode
        if mode != self.mode:
            self.mode = mode
            self._start(mode)

    def _answer(self, j: int, bits, d: Decision) -> Decision:
        """Frame ``j``'s answer at the current speed (``d``: the map's own)."""
        answers = self._feed(self.mode, j, bits)
        if self.mode >= 0:
            self.last = None
        if self.mode > 0 and answers:
            i = max(range(self.step), key=lambda i: (bool(answers[i].accepted), self.phase_paths[i].length)
                    if self.pick == "path" else answers[i].score)
            self.frames["db_step"] += 1
            out = _on_map(answers[i], self.keeps[i], self.base.n_db, d.frame)
            on_map = np.array([keep[a.best] if a.best >= 0 else -1 for a, keep in zip(answers, self.keeps,
                                                                                    strict=True)])[:, None]
            took = np.array([a.accepted for a in answers])[:, None]
            if out.accepted and disagree(on_map, took, self.step)[0]:
                self.frames["db_apart"] += 1  # the maps contradict each other: not decided
                return dataclasses.replace(out, accepted=False)
            if out.accepted:  # between the answers of the maps that accept it
                out = dataclasses.replace(out, best=int(between_maps(on_map, took, [out.best], self.step)[0]))
            return out
        if self.mode < 0:
            self.frames["query_step"] += 1
            return self._slower(j, bits, d, answers)
        return d

    def _slower(self, j: int, bits, d: Decision, answers: list[Decision] | None = None) -> Decision:
        """Frame ``j``'s answer by the queries of one frame in ``step`` (``answers``: their decisions, default: fed
        here): its own query's, or where that does not accept it just after a frame its own accepted, that one's."""
        answers = self._feed(-1, j, bits) if answers is None else answers
        own, prev = dataclasses.replace(answers[0], frame=d.frame), self.last
        self.last = (j, own.best, own.score) if own.accepted and own.best >= 0 else None
        if own.accepted or prev is None or prev[0] != j - 1:
            return own
        self.frames["query_filled"] += 1  # it moved less than a map frame since the frame before
        return dataclasses.replace(own, best=prev[1], score=prev[2], accepted=True)

    def sampling(self) -> dict | None:
        """metrics.json's ``sampling`` of the frames so far: the step and the frames answered at it (None: every
        frame as it came)."""
        used = {k: self.frames[k] for k in ("db_step", "query_step") if self.frames[k]}
        out = {**{k: self.step for k in used}, **{f"{k}_frames": v for k, v in used.items()}}
        for k, extra in (("db_step", "db_apart"), ("query_step", "query_filled")):
            if used.get(k):
                out[extra] = self.frames[extra]
        return out or None

    def state(self) -> tuple[dict, dict]:
        """(header, arrays) of what the follower carries besides the map's localizer (:meth:`load_state`)."""
        frames = np.array([j for j, _ in self.recent], np.int64)
        sizes = np.array([b.size for _, b in self.recent], np.int64)
        header = {"step": self.step, "replay": self.replay, "mode": self.mode, "frame": self.frame, "clock": self.clock,
                  "path": self.path.state(), "kept": self.kept.state(),
                  "phase_paths": [p.state() for p in self.phase_paths],
                  "last": None if self.last is None else [int(self.last[0]), int(self.last[1]), float(self.last[2])]}
        arrays = {"recent_frames": frames, "recent_sizes": sizes,
                  "recent_bits": np.concatenate([b for _, b in self.recent] or [np.zeros(0, np.int64)])}
        engines, engine_arrays = joint_state(**self._named(self.mode))
        return {**header, "engines": engines}, {**arrays, **engine_arrays}

    def _named(self, mode: int) -> dict[str, Localizer]:
        return {f"{'phase' if mode > 0 else 'query'}{i}": loc for i, loc in enumerate(self._engines(mode))}

    def load_state(self, header: dict, arrays: dict) -> SpeedFollower:
        """Continue from :meth:`state` (of a follower of the same map, step and replay)."""
        if int(header["step"]) != self.step or int(header["replay"]) != self.replay:
            raise ValueError(f"a speed follower's state of step {header['step']}, replay {header['replay']} cannot "
                             f"continue one of step {self.step}, replay {self.replay}")
        self.mode, self.frame = int(header["mode"]), int(header["frame"])
        self.clock = int(header.get("clock", self.frame))
        self.path.restore(header["path"])
        self.kept.restore(header["kept"])
        last = header.get("last")
        self.last = None if last is None else (int(last[0]), int(last[1]), float(last[2]))
        bits = np.split(np.asarray(arrays["recent_bits"], np.int64), np.cumsum(arrays["recent_sizes"])[:-1])
        self.recent = [(int(j), b) for j, b in zip(arrays["recent_frames"], bits, strict=True)] \
            if len(arrays["recent_frames"]) else []
        for name, loc in self._named(self.mode).items():
            loc.load_state(*part_state(header["engines"], arrays, name))
        self.phase_paths = [BestPath(*self._bounds) for _ in self.phases]
        for p, v in zip(self.phase_paths, header["phase_paths"], strict=False):
            p.restore(v)
        return self


def path_lengths(best, back: int, ahead: int) -> np.ndarray:
    """Each frame's length of the consistent path of best frames it ends, over a whole traverse: a frame whose best
    (``best``, -1: none) lies within ``back`` behind and ``ahead`` beyond the frame before's continues its path."""
    best = np.asarray(best, np.int64)
    found, step = best >= 0, np.diff(best, prepend=-1)
    linked = found & np.r_[False, found[:-1]] & (step >= -back) & (step <= ahead)
    frame = np.arange(best.size)
    start = np.maximum.accumulate(np.where(linked, 0, frame))  # the frame each path started at
    return np.where(found, frame - start + 1, 0)


def _on_map(d: Decision, keep: np.ndarray, n: int, frame: int) -> Decision:
    """A decision of the map of the frames ``keep`` on the whole map of ``n`` frames."""
    c = d.column
    column = None if c is None else Column(keep[c.rows], c.z, c.fill, n, c.frame)
    return dataclasses.replace(d, best=int(keep[d.best]) if d.best >= 0 else -1, frame=frame, column=column)
