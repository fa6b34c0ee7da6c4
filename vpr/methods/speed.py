"""A query driven at another speed than the database, matched again at the sampling that makes the two agree."""
from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import scipy.sparse as sp

from vpr.paths import path_run_speeds, path_speed, session_speeds, speed_step
from vpr.shosm import (
    LOOP_ONLY_KEYS,
    PathConf,
    apart_from_neighbours,
    between_maps,
    check_pick,
    confirm_closures,
    disagree,
    fill_between,
    pick_maps,
)
from vpr.types import Decision, EncodedTraverse, MatchResult

from .base import Fitted, Method

__all__ = ["match_at_speed", "loops_at_speed", "loops_in_run_at_speed"]


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
    check_pick(pick)
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
        apart = apart_from_neighbours(best, accepted, step)
        accepted = accepted & ~apart
        best, score, filled = fill_between(best, score, accepted, step)
        accepted = accepted | filled
        said = f"its frames were matched as {step} queries of one frame in {step}"
    S = S.tocsr() if sparse else S
    warnings.warn(f"{who}: along its {along} the query moved {speed:.2g} database frames a frame, "
                  f"driven {'faster' if k > 0 else 'slower'} than the database at the same frame rate: {said}, so "
                  "that its sequences follow the query's (research/docs/localize.md)", UserWarning, stacklevel=3)
    sampling = {"speed": round(float(speed), 3), "db_step" if k > 0 else "query_step": abs(k),
                "db_apart" if k > 0 else "query_apart": int(apart.sum())}
    if k < 0:
        sampling["query_filled"] = int(filled.sum())
    return MatchResult(method.name, S, best, score, accepted, sum(r.seconds for r in parts), dict(method.conf),
                       sampling, reversed=(max if k > 0 else sum)(r.reversed for r in parts))


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
    check_pick(pick)
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
    check_pick(pick)
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


