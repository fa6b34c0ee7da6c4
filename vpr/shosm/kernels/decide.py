"""Compiled kernel of the loop decision (numba): one frame at a time, with the state carried between frames."""
from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit

from vpr.similarity import stationary

#: A path rule as the kernels read it (:attr:`vpr.shosm.PathConf.rule`): the drift taken off each frame's margin,
#: the score that accepts, how far behind (``back``) or beyond (``ahead``) the path's head a best frame continues it,
#: the z-score of a candidate of the best one's island.
PathRule = namedtuple("PathRule", ["drift", "min_score", "back", "ahead", "island"])
#: A loop rule as the kernels read it (:attr:`vpr.shosm.LoopConf.rule`): a path rule and the stop check's ratio.
LoopRule = namedtuple("LoopRule", ["drift", "min_score", "back", "ahead", "island", "stop_ratio"])
#: One frame's evidence over its candidates ``0 .. n - 1`` as the kernels read it: the rows stored (sorted), their
#: z-scores (float64), ``n``, and the z of a candidate not stored.
ColumnArgs = namedtuple("ColumnArgs", ["rows", "vals", "n", "fill"])

#: The state a path decision carries between frames (one record): the path's score, its ``head`` (the
#: furthest best frame of the path; -1: no path) and its ``start`` (the frame the path began at).
PATH_STATE = np.dtype([("score", np.float64), ("head", np.int64), ("start", np.int64)])


def path_state(start: int = 0) -> np.ndarray:
    """The state of no path yet (a 1-record :data:`PATH_STATE` array), the next path starting at frame ``start``."""
    st = np.zeros(1, PATH_STATE)
    st[0]["head"], st[0]["start"] = -1, start
    return st


@njit(cache=True, inline="always")
def _island(rows, vals, k, island):
    lo = k
    while lo > 0 and rows[lo - 1] == rows[lo] - 1 and vals[lo - 1] >= island:
        lo -= 1
    hi = k
    while hi < rows.shape[0] - 1 and rows[hi + 1] == rows[hi] + 1 and vals[hi + 1] >= island:
        hi += 1
    return lo, hi


@njit(cache=True, inline="always")
def _linked(place, root, row, w, n, skip_lo=-1, skip_hi=-2):
    """Whether a frame within ``w`` of ``row`` (outside ``skip_lo..skip_hi``) belongs to place ``root``."""
    for r in range(max(row - w, 0), min(row + w + 1, n)):
        if place[r] == root and not skip_lo <= r <= skip_hi:
            return True
    return False


@njit(cache=True, inline="always")
def session_of(starts, f):
    """The session of frame ``f`` (``starts``: the sessions' first frames, sorted, ``starts[0] == 0``)."""
    return np.searchsorted(starts, f, side="right") - 1


@njit(cache=True)
def column_peaks(rows, vals, n, fill, island, place, link_w, newest):  # pragma: no cover - compiled
    """(best row, z_best, z_other, near) of one column (best -1 without candidates).

    ``near``: the best island reaches ``newest`` (the newest candidate of the current session; -1: none).
    """
    m = rows.shape[0]
    if n <= 0 or m == 0:
        return -1, -np.inf, 0.0, False
    kb = 0
    for k in range(1, m):
        if vals[k] > vals[kb]:
            kb = k
    b = rows[kb]
    lo, hi = _island(rows, vals, kb, island)
    near = newest >= 0 and rows[hi] == newest and vals[hi] >= island
    out = np.ones(m, np.bool_)
    out[lo:hi + 1] = False
    root = place[b]
    other = -np.inf
    for _ in range(8):  # skip up to 8 islands of earlier visits of the best place
        ko = -1
        for k in range(m):
            if out[k] and (ko < 0 or vals[k] > vals[ko]):
                ko = k
        if ko < 0:
            break
        if _linked(place, root, rows[ko], link_w, n, rows[lo], rows[hi]):
            a, c = _island(rows, vals, ko, island)
            out[a:c + 1] = False
            continue
        other = vals[ko]
        break
    if m < n and fill > other:  # candidates without stored evidence
        other = fill
    if other == -np.inf:
        other = 0.0
    return b, vals[kb], other, near


@njit(cache=True)
def decide_frame(j, column, rule, stream):  # pragma: no cover - compiled
    """The decision of frame ``j``; updates the stream's ``place``, ``path_b`` and ``st``.

    ``column``: a :data:`ColumnArgs`; ``rule``: a :data:`LoopRule`; ``stream``: (sdr_ptr, sdr_ind (empty: no stop
    check), place (each frame's place), path_b (each frame's best candidate), st (:data:`PATH_STATE`), starts, n_bits
    (the SDRs' width)). Returns (best, score, accepted, margin, near).
    """
    rows, vals, n, fill = column.rows, column.vals, column.n, column.fill
    back, ahead, island = rule.back, rule.ahead, rule.island
    sdr_ptr, sdr_ind, place, path_b, st, starts, n_bits = stream
    p = st[0]
    s_j = session_of(starts, j)
    newest = n - 1 if n - 1 >= starts[s_j] else -1  # the current session's newest candidate, if any
    b, zb, zo, near = column_peaks(rows, vals, n, fill, island, place, back + ahead, newest)
    path_b[j] = b
    if b < 0:
        p.score = 0.0
        p.head = -1
        p.start = j + 1
        return -1, 0.0, False, 0.0, False
    head = p.head
    # moving on along the frames of one session: the next session's first frame is not the next place
    cont = head >= 0 and head - back <= b <= head + ahead and session_of(starts, b) == session_of(starts, head)
    jump = False
    if not cont and head >= 0:  # another visit of the place the path is at (linked earlier) continues it too
        # (across a session boundary the candidate itself is no other visit: the first frame of a run is not the place
        # its previous run ended at)
        own = b if session_of(starts, b) != session_of(starts, head) else -1
        jump = _linked(place, place[b], head + (ahead - back) // 2, (back + ahead) // 2 + 1, place.shape[0], own, own)
    prev = p.score if cont or jump else 0.0
    score = max(0.0, prev + (zb - zo) - rule.drift)
    if not (cont or jump):
        p.start = j
    p.head = max(head, b) if cont else b
    if score == 0.0:
        p.head = b
        p.start = j + 1
    p.score = score
    ok = score >= rule.min_score and not near
    if ok and rule.stop_ratio > 0.0 and sdr_ptr.shape[0] > j and session_of(starts, b) == s_j:  # within one run
        ok = not stationary(sdr_ptr, sdr_ind, b, j, rule.stop_ratio, n_bits)
    if score > 0.0 and not near and place[j] == j:  # a frame on a path is (provisionally) the place it matched
        place[j] = place[b]
    return b, score, ok, zb - zo, near


@njit(cache=True)
def locate_frame(column, rule, place, st, starts):  # pragma: no cover - compiled
    """The localisation decision of one query frame against a map of ``n`` frames; updates ``st``.

    :func:`decide_frame`'s path score without what only one stream has (a place just left, links, stops). ``column``: a
    :data:`ColumnArgs`; ``rule``: a :data:`PathRule`; ``place``: ``arange(n)``; ``starts``: the map's sessions.
    Returns (best, score, accepted, margin).
    """
    back, ahead = rule.back, rule.ahead
    p = st[0]
    b, zb, zo, _ = column_peaks(column.rows, column.vals, column.n, column.fill, rule.island, place, 0, -1)
    if b < 0:
        p.score = 0.0
        p.head = -1
        return -1, 0.0, False, 0.0
    head = p.head
    cont = head >= 0 and head - back <= b <= head + ahead and session_of(starts, b) == session_of(starts, head)
    prev = p.score if cont else 0.0
    score = max(0.0, prev + (zb - zo) - rule.drift)
    p.head = max(head, b) if cont and score > 0.0 else b
    p.score = score
    return b, score, score >= rule.min_score, zb - zo
