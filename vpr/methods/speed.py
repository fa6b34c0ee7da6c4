"""A query driven at another speed than the database, matched again at the sampling that makes the two agree."""
from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import scipy.sparse as sp

from vpr import sdr as _sdr
from vpr.evaluate import MIN_RUN, path_run_speeds, path_speed, session_speeds
from vpr.groundtruth import speed_step
from vpr.shosm import LOOP_ONLY_KEYS, Localizer, PathConf, confirm_closures
from vpr.shosm.state import joint_state, part_state
from vpr.types import Column, Decision, EncodedTraverse, MatchResult, QueryLocalizer

from .base import Fitted, Method

__all__ = ["match_at_speed", "loops_at_speed", "loops_in_run_at_speed", "pick_maps", "disagree", "between_maps",
           "fill_between", "path_lengths", "SpeedFollower", "PICKS"]


#: How a frame is answered by one of the ``k`` maps of one frame in ``k``: ``"path"``, the map that accepts it on the
#: longest consistent path of best frames; ``"score"``, the map of the largest path score (docs/localize.md).
PICKS = ("path", "score")


def _check_pick(pick: str) -> str:
    if pick not in PICKS:
        raise ValueError(f"pick must be one of {', '.join(PICKS)}, got {pick!r}")
    return pick


def match_at_speed(fitted: Fitted, query: EncodedTraverse, progress: bool = False,
                   first: MatchResult | None = None, speed: float | None = None, pick: str = "path") -> MatchResult:
    """Match ``query`` against the learned database; match again where the query was driven at another speed.

    A method whose sequences follow one database frame a frame (:attr:`Method.follows_sequences`) and whose accepted
    paths move ``k`` >= :data:`~vpr.groundtruth.RATE_RATIO` database frames a query frame
    (:func:`vpr.evaluate.path_speed`, no ground truth; :func:`~vpr.groundtruth.speed_step`) is matched again against
    one database frame in ``k`` (the ``k`` maps of frames ``a, a + k, ...``, learned again; each query frame answered
    by the map ``pick`` chooses or, where several accept it, between their answers (:func:`between_maps`), and not
    accepted where they place it apart: :func:`disagree`)
    and, moving ``1 / k``, as ``k`` queries of one frame in ``k`` (each frame answered by its own, or where its own
    does not accept it, between two accepted frames: :func:`fill_between`); each is said (a warning). The result
    keeps the traverses' frames and their similarity; :attr:`MatchResult.sampling` records the first pass's speed,
    the step and the frames left undecided (``db_apart``) or, slower, filled (``query_filled``); ``seconds`` both
    passes.
    ``first``: the query's result as already matched (by default matched here, :meth:`Fitted.match`); ``speed``:
    the query's speed read by another method of the same run, used where this method's accepted paths read none
    (a method whose answers off the database's speed form no path); ``pick``: one of :data:`PICKS`. Returns the
    first result where nothing is to be done or the sampled traverse is too short for the method.
    """
    _check_pick(pick)
    res = fitted.match(query, progress) if first is None else first
    own = path_speed(res.best, res.accepted)[0]
    speed = speed if own is None else own
    k = speed_step(speed) if fitted.method.follows_sequences else 0
    again = _resampled(fitted, query, k, speed, pick, progress)
    if again is None:
        return res
    return dataclasses.replace(again, method=res.method, seconds=res.seconds + again.seconds, conf=res.conf)


def _resampled(fitted: Fitted, query: EncodedTraverse, k: int, speed: float, pick: str, progress: bool,
               who: str | None = None, along: str = "accepted paths") -> MatchResult | None:
    """``query`` matched at the step ``k`` of :func:`~vpr.groundtruth.speed_step` (:func:`match_at_speed`), said
    (of ``who``, by default the method, whose ``along`` read ``speed``); ``seconds``: those matches'. None where
    ``k`` is 0 or a sampled traverse is too short for the method."""
    n_db, n_q, method = len(fitted.db), len(query), fitted.method
    who = who or method.name
    if not k or (n_db if k > 0 else n_q) < 2 * abs(k):
        return None
    n, step = (n_db, k) if k > 0 else (n_q, -k)
    phases = [np.arange(a, n, step) for a in range(step)]
    try:
        if k > 0:
            parts = [method.fit(fitted.db.take(f), progress, once=fitted.once).match(query, progress) for f in phases]
        else:
            parts = [fitted.match(query.take(f), progress) for f in phases]
    except ValueError as e:  # the sampled traverse is too short for the method (SeqSLAM's ``ds``)
        warnings.warn(f"{who}: the query moves {speed:.2g} database frames a frame, and one "
                      f"{'database' if k > 0 else 'query'} frame in {step} cannot be matched: {e}", UserWarning,
                      stacklevel=3)
        return None
    order = np.argsort(np.concatenate(phases), kind="stable")  # the phases' frames back in the traverse's order
    sparse = sp.issparse(parts[0].similarity)
    if k > 0:  # each database frame is in one phase's map; a query frame takes the phase accepted on the longest path
        S = (sp.vstack if sparse else np.vstack)([r.similarity for r in parts])[order]
        best = np.stack([np.where(r.best >= 0, f[np.maximum(r.best, 0)], -1) for r, f in zip(parts, phases,
                                                                                          strict=True)])
        score, accepted = np.stack([r.score for r in parts]), np.stack([r.accepted for r in parts])
        bounds = PathConf(**{k: method.conf[k] for k in ("back", "ahead") if method.conf.get(k) is not None})
        chosen = pick_maps(np.stack([r.best for r in parts]), accepted, score, pick, bounds.back, bounds.ahead), \
            np.arange(n_q)
        apart = disagree(best, accepted, step)
        score, taken = score[chosen], accepted[chosen] & ~apart
        best, accepted = between_maps(best, accepted, best[chosen], step), taken
        said = f"the database was learned again as {step} maps of one frame in {step}"
    else:  # each query frame is in one phase's query
        S = (sp.hstack if sparse else np.hstack)([r.similarity for r in parts])[:, order]
        best, score, accepted = (np.concatenate([getattr(r, f) for r in parts])[order]
                                 for f in ("best", "score", "accepted"))
        best, score, filled = fill_between(best, score, accepted, step)
        accepted = accepted | filled
        said = f"its frames were matched as {step} queries of one frame in {step}"
    S = S.tocsr() if sparse else S
    warnings.warn(f"{who}: along its {along} the query moved {speed:.2g} database frames a frame, "
                  f"driven {'faster' if k > 0 else 'slower'} than the database at the same frame rate: {said}, so "
                  "that its sequences follow the query's (docs/localize.md)", UserWarning, stacklevel=3)
    sampling = {"speed": round(float(speed), 3), "db_step" if k > 0 else "query_step": abs(k),
                "db_apart" if k > 0 else "query_filled": int((apart if k > 0 else filled).sum())}
    return MatchResult(method.name, S, best, score, accepted, sum(r.seconds for r in parts), dict(method.conf),
                       sampling)


def pick_maps(best, accepted, score, pick: str = "path", back: int = PathConf.back,
              ahead: int = PathConf.ahead) -> np.ndarray:
    """Per query frame, the map of one frame in k that answers it (:data:`PICKS`): ``"path"``, an accepting map on
    the longest consistent path of best frames (:func:`path_lengths` with ``back`` / ``ahead``; ties: the first
    map), or ``"score"``, the map of the largest score.

    ``best`` (each map's own frame numbers), ``accepted``, ``score``: one row per map, one column per query frame.
    """
    best, accepted = np.asarray(best, np.int64), np.asarray(accepted, bool)
    if _check_pick(pick) == "score":
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


def loops_at_speed(method: Method, seq: EncodedTraverse, res: MatchResult, sessions, progress: bool = False,
                   pick: str = "path") -> MatchResult:
    """Loop closures of a stream of sessions, each later session read for its speed and decided again where it was
    driven at another speed than the earlier sessions.

    ``res``: ``method``'s :meth:`~Method.loops` of ``seq`` with ``sessions`` (each session's first frame). Each
    later session is matched against the earlier sessions (:meth:`Method.fit`, :meth:`Fitted.match`) and its speed
    read along that match's accepted paths (:func:`vpr.evaluate.path_speed`, no ground truth), or where they read
    none along its paths of best frames in ``res`` (:func:`vpr.evaluate.session_speeds`). Moving ``k`` >=
    :data:`~vpr.groundtruth.RATE_RATIO` of their frames a frame, or ``1 / k`` (:func:`~vpr.groundtruth.speed_step`),
    it is matched again as :func:`match_at_speed` matches a query at ``k`` (said), and each of its frames takes that
    answer onto the earlier sessions unless the loop's best frame lies in its own session and that match does not
    accept; its similarity onto the earlier sessions is that match's (in ``res``'s form: dense, or as many
    candidates a frame as its column holds), the rest of the stream's is ``res``'s. :attr:`MatchResult.sampling`:
    ``{"sessions": [{"session": s (1 = the first), "speed", and "db_step" or "query_step" where followed}]}``, every
    later session; ``seconds`` counts the matches. Returns ``res`` for a stream of one session or a method whose
    sequences do not follow one frame a frame.
    """
    _check_pick(pick)
    bounds = [*sorted({0, *(int(a) for a in sessions)}), len(seq)]
    if not method.follows_sequences or len(bounds) < 3:
        return res
    S, best, score, accepted = res.similarity, res.best.copy(), res.score.copy(), res.accepted.copy()
    read, seconds = [], res.seconds
    for s, own in enumerate(session_speeds(res.best, bounds[:-1]), start=1):
        a, b = bounds[s], bounds[s + 1]
        fitted, query = _matcher(method).fit(seq.slice(0, a), progress), seq.slice(a, b)
        first = fitted.match(query, progress)
        v = path_speed(first.best, first.accepted)[0]
        v = own if v is None else v
        read.append({"session": s + 1, "speed": None if v is None else round(float(v), 3)})
        seconds += first.seconds
        again = _resampled(fitted, query, speed_step(v), v, pick, progress, f"{method.name}: session {s + 1}",
                           "accepted paths onto the earlier sessions")
        if again is None:
            continue
        take = again.accepted | ~(best[a:b] >= a)  # its own session's loop stands unless the match accepts
        for mine, theirs in ((best, again.best), (score, again.score), (accepted, again.accepted)):
            mine[a:b] = np.where(take, theirs, mine[a:b])
        S = _with_block(S, again.similarity, a, b)
        read[-1] = {**read[-1], **{k: v for k, v in again.sampling.items() if k != "speed"}}
        seconds += again.seconds
    return dataclasses.replace(res, similarity=S, best=best, score=score, accepted=accepted, seconds=seconds,
                               sampling={"sessions": read})


def loops_in_run_at_speed(method: Method, seq: EncodedTraverse, res: MatchResult, exclude: int,
                          progress: bool = False, pick: str = "path") -> MatchResult:
    """Loop closures of one run decided again where its best earlier frames read another speed.

    ``res``: ``method``'s :meth:`~Method.loops` of ``seq``, one session, ``exclude`` frames excluded. Each run of
    best earlier frames (:func:`vpr.evaluate.path_runs`, accepted or not) that moves ``k`` >=
    :data:`~vpr.groundtruth.RATE_RATIO` earlier frames a frame (:func:`~vpr.groundtruth.speed_step`; a slower one
    starts none) starts a stretch (the runs after it at the same step continue it): from ``exclude`` frames before
    the run's first frame to where the next stretch starts or the stream's end. The stretch is matched against the
    ``k`` maps of one frame in ``k`` of the frames at least ``exclude`` before it (as :func:`match_at_speed`; said),
    decided by the loop rule's path (the method's loop ``drift`` and ``min_score``) and each closure confirmed by
    the frames after it (:func:`vpr.shosm.confirm_closures`, the method's :meth:`~Method.loop_conf`). A frame the
    loops did not accept takes its stretch's confirmed closure where it lies on a run of closures
    (:func:`~vpr.evaluate.path_runs`, with the loops' own) that reads a faster speed too, and its similarity onto the
    frames the stretch was matched against is that match's.
    :attr:`MatchResult.sampling`: ``{"runs": [{"frames": [first, last], "speed", "db_step", "db_apart",
    "closures"}]}``, each stretch matched again (``closures``: its frames taken); ``seconds`` counts the matches.
    Returns ``res`` where no run reads a faster speed, or for a method whose sequences do not follow one frame a
    frame or that has no loop conf.
    """
    _check_pick(pick)
    rule = method.loop_conf()
    if not method.follows_sequences or rule is None:
        return res
    loop, n, exclude = rule.loop(), len(seq), int(exclude)
    first, _, speeds = path_run_speeds(res.best, res.best >= 0)
    runs = [(int(a), float(v)) for a, v in zip(first, speeds, strict=True) if speed_step(v) > 0]
    runs = [r for i, r in enumerate(runs) if not i or speed_step(r[1]) != speed_step(runs[i - 1][1])]  # one a speed
    if not runs:
        return res
    strict = _matcher(method, drift=loop.drift, min_score=loop.min_score)
    best, score = np.full(n, -1, np.int64), np.zeros(n)
    accepted = np.zeros(n, bool)
    S, read, seconds, blocks = res.similarity, [], res.seconds, []
    for i, (a, v) in enumerate(runs):
        lo, hi = max(a - exclude, 0), max(runs[i + 1][0] - exclude, 0) if i + 1 < len(runs) else n
        m = lo - exclude  # the frames it is matched against
        if m < 1 or hi <= lo:
            continue
        again = _resampled(strict.fit(seq.slice(0, m), progress), seq.slice(lo, hi), speed_step(v), v, pick,
                           progress, f"{method.name}: frames {lo}-{hi - 1} of one run",
                           "run of best earlier frames")
        if again is None:
            continue
        best[lo:hi], score[lo:hi], accepted[lo:hi] = again.best, again.score, again.accepted
        blocks.append((again.similarity, lo, hi))
        seconds += again.seconds
        read.append({"frames": [lo, hi - 1], "speed": round(v, 3),
                     **{k: x for k, x in again.sampling.items() if k != "speed"}})
    if not read:
        return res
    kept = confirm_closures(Decision(best, score, accepted, np.zeros(n)), method.need(seq, "sdr", "loop"), exclude,
                            rule).accepted
    take = np.asarray(kept, bool) & ~res.accepted
    joined = np.where(take, best, res.best)
    on_path = np.zeros(n, bool)  # a closure taken lies on a path of closures that reads a faster speed too
    for a, b, v in zip(*path_run_speeds(joined, res.accepted | take), strict=True):
        on_path[a:b + 1] = speed_step(v) > 0
    take &= on_path
    for block, lo, hi in blocks:
        S = _with_block(S, block, lo, hi)
    for r in read:
        r["closures"] = int(take[r["frames"][0]:r["frames"][1] + 1].sum())
    return dataclasses.replace(res, similarity=S, best=np.where(take, best, res.best),
                               score=np.where(take, score, res.score), accepted=res.accepted | take,
                               seconds=seconds, sampling={"runs": read})


def _matcher(method: Method, **decision) -> Method:
    """``method`` as it matches frames of a stream against its earlier frames (a later session, a stretch of one run):
    its conf without the keys of loop closure within one stream (:data:`~vpr.shosm.LOOP_ONLY_KEYS`), ``decision``
    over it."""
    drop = dict.fromkeys(k for k in LOOP_ONLY_KEYS if method.conf.get(k) is not None)
    return type(method)(**{**method.conf, **drop, **decision}) if drop or decision else method


def _with_block(S, block, a: int, b: int):
    """The loop similarity ``S`` (T x T, dense or top-K sparse) with rows ``:m`` of columns ``a:b`` from ``block``
    (``m`` x ``b - a``, ``m <= a``; in a sparse ``S``, each of those columns keeps its largest values, as many as
    ``S``'s fullest column holds)."""
    m = block.shape[0]
    if not sp.issparse(S):
        S = S.copy()
        S[:m, a:b] = block.toarray() if sp.issparse(block) else block
        return S
    coo, csc = S.tocoo(), S.tocsc()
    blk = sp.csc_matrix(block) if sp.issparse(block) else None
    per_column = max(int(np.diff(csc.indptr).max(initial=0)), 1)
    kept = (coo.col < a) | (coo.col >= b)  # the other columns stay as they are
    rows, cols, vals = [coo.row[kept]], [coo.col[kept]], [coo.data[kept]]
    for j in range(a, b):
        r, x = csc.indices[csc.indptr[j]:csc.indptr[j + 1]], csc.data[csc.indptr[j]:csc.indptr[j + 1]]
        c = j - a
        if blk is not None:
            r_b, x_b = blk.indices[blk.indptr[c]:blk.indptr[c + 1]], blk.data[blk.indptr[c]:blk.indptr[c + 1]]
        else:
            r_b = np.flatnonzero(np.isfinite(block[:, c]))
            x_b = block[r_b, c]
        own = r >= m
        r, x = np.r_[r_b, r[own]], np.r_[x_b.astype(S.dtype), x[own]]
        top = np.argsort(-x, kind="stable")[:per_column]
        rows.append(r[top])
        cols.append(np.full(top.size, j))
        vals.append(x[top])
    out = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=S.shape)
    out.sort_indices()
    return out


class _Path:
    """A consistent path of best frames (each within ``back`` behind and ``ahead`` beyond the last): its first frame
    and best, its last best and its length."""

    def __init__(self, back: int, ahead: int):
        self.back, self.ahead = back, ahead
        self.start, self.first, self.last, self.length = -1, -1, -1, 0

    def step(self, frame: int, best: int) -> None:
        if best >= 0 and self.length and -self.back <= best - self.last <= self.ahead:
            self.last, self.length = best, self.length + 1
        else:
            self.start, self.first, self.last, self.length = frame, best, best, int(best >= 0)

    def speed(self, frame: int) -> float | None:
        """Best frames per frame since the path started, once it is :data:`~vpr.evaluate.MIN_RUN` frames long."""
        return (self.last - self.first) / (frame - self.start) if self.length >= MIN_RUN else None

    def state(self) -> list[int]:
        return [self.start, self.first, self.last, self.length]

    def restore(self, values) -> None:
        self.start, self.first, self.last, self.length = (int(v) for v in values)


class SpeedFollower(QueryLocalizer):
    """Online localisation that follows a query driven at another speed than the map at the same frame rate.

    Steps the map's ``localizer`` on every frame and reads the speed of the consistent path of best frames (the
    path rule's ``back`` / ``ahead``, over at least :data:`~vpr.evaluate.MIN_RUN` frames) of the answers: the
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
        self.pick = _check_pick(pick)
        path = localizer.seq.path()
        self._bounds = path.back, path.ahead
        self.path = _Path(*self._bounds)
        self.phases: list[Localizer] = []
        self.keeps: list[np.ndarray] = []
        self.phase_paths: list[_Path] = []
        self.queries: list[Localizer] = []
        self.mode, self.frame = 0, 0
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
        self.phase_paths = [_Path(*self._bounds) for _ in self.phases]
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
        self.mode, self.frame, self.recent, self.last = 0, 0, [], None

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
                self.path.step(j, d.best)
            else:
                self._read(j, d.best)
            if self.mode < 0:
                self.frames["query_step"] += 1
                return out
            return self._answer(j, bits, d)
        faster = self.mode > 0 and self.follows_faster
        if not faster:  # the map's own answers read the speed
            self._read(j, d.best)
        out = self._answer(j, bits, d)
        if faster:  # while a faster query is followed, the answers given read it
            self._read(j, out.best)
            if self.mode < 0:  # from the faster speed to the slower: this frame too
                self._feed(self.mode, j, bits)
        return out

    def _read(self, j: int, best: int) -> None:
        """Step the path with frame ``j``'s answer and switch to the speed it reads (its engines started from the
        frames kept before ``j``)."""
        self.path.step(j, best)
        v = self.path.speed(j)
        mode = self.mode if v is None else int(np.sign(speed_step(v)))
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
        header = {"step": self.step, "replay": self.replay, "mode": self.mode, "frame": self.frame,
                  "path": self.path.state(), "phase_paths": [p.state() for p in self.phase_paths],
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
        self.path.restore(header["path"])
        last = header.get("last")
        self.last = None if last is None else (int(last[0]), int(last[1]), float(last[2]))
        bits = np.split(np.asarray(arrays["recent_bits"], np.int64), np.cumsum(arrays["recent_sizes"])[:-1])
        self.recent = [(int(j), b) for j, b in zip(arrays["recent_frames"], bits, strict=True)] \
            if len(arrays["recent_frames"]) else []
        for name, loc in self._named(self.mode).items():
            loc.load_state(*part_state(header["engines"], arrays, name))
        self.phase_paths = [_Path(*self._bounds) for _ in self.phases]
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


