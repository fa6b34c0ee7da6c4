"""A geometric second opinion on loop closures: two-view inliers of the best candidate, where geometry can see.

The path score of rSHOSM-seq (:class:`vpr.shosm.LoopConf`) needs a revisit to
stand out for many frames: a short stream (an 84-frame indoor loop) never
reaches it although its best matches are right. Geometry sees what the path
cannot yet: a frame whose best earlier frame moves on consistently with the
frames before it (``back`` / ``ahead`` of :class:`LoopConf`, for ``frames``
frames) and whose pair with it has at least ``min_inliers`` RANSAC inliers
(ORB, :class:`vpr.verify.Verifier`, at the source's resolution) is accepted
as well, unless the camera never left the place in between
(:func:`vpr.shosm.stationary_closures`: on a forward drive the frame 30 back
shows the same road ahead, a scene seen again but no loop).

Geometry is a second route to acceptance, not a replacement: it is blind
where the images are small (a shorter side under ``min_side`` pixels, as
Nordland's 64 x 32) or bare (fewer than ``min_keypoints`` ORB keypoints), and
there the path decides alone; and it does not survive day to night (true
pairs median 11 inliers), which the sequence evidence does. It is run only on
the frames that reach it: a consistent best frame, not accepted by the path.
Measured in ``docs/loops.md`` ("A geometric second opinion").
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from vpr.shosm import stationary_closures
from vpr.types import MatchResult

__all__ = ["SecondOpinion", "second_opinion"]


@dataclass(frozen=True)
class SecondOpinion:
    """The conf of :func:`second_opinion` (see the module docstring)."""

    min_inliers: int = 20
    frames: int = 3
    min_side: int = 120
    min_keypoints: int = 100
    n_features: int = 2000
    max_error: float = 2.0


def second_opinion(res: MatchResult, image, sdr, back: int, ahead: int, stop_ratio: float,
                   conf: SecondOpinion | None = None, sessions=(0,)) -> tuple[MatchResult, dict]:
    """``res`` (a method's loop closures) with closures that geometry confirms accepted too; and a report.

    ``image(j)``: frame ``j`` of the stream at its source's resolution;
    ``sdr``: the stream's SDRs (the stop check); ``back`` / ``ahead`` /
    ``stop_ratio``: the loop decision's (:class:`vpr.shosm.LoopConf`).
    The report: frames verified, how many were blind, how many geometry
    accepted, and the milliseconds per verified frame.
    """
    from vpr.verify import Verifier  # pycolmap: loaded only when verifying

    c = conf or SecondOpinion()
    best, accepted = np.asarray(res.best_db, np.int64), np.asarray(res.accepted, bool)
    T = best.size
    starts = np.asarray(sorted(sessions), np.int64)
    session = np.searchsorted(starts, np.arange(T), side="right") - 1
    consistent = np.zeros(T, bool)
    for j in range(c.frames - 1, T):
        ok = best[j] >= 0
        for t in range(1, c.frames):
            a, b = best[j - t], best[j - t + 1]
            ok = ok and a >= 0 and a - back <= b <= a + ahead and session[j - t] == session[j]
        consistent[j] = ok
    todo = np.flatnonzero(consistent & ~accepted)
    verifier = Verifier(image, image, n_features=c.n_features, max_error=c.max_error, min_side=1)
    inliers = np.full(T, -1, np.int64)
    blind = 0
    t0 = time.perf_counter()
    if todo.size and min(image(int(todo[0])).shape[:2]) < c.min_side:  # frames too small for geometry
        blind, todo = todo.size, todo[:0]
    for j in todo:
        fj, fb = verifier.query_features(int(j)), verifier.db_features(int(best[j]))
        if min(fj.xy.shape[0], fb.xy.shape[0]) < c.min_keypoints:
            blind += 1
            continue
        inliers[j] = verifier.pair_inliers(int(best[j]), int(j))
    seconds = time.perf_counter() - t0
    geometry = inliers >= c.min_inliers
    if geometry.any() and stop_ratio > 0:
        cross = session[np.maximum(best, 0)] != session  # across runs the camera surely left
        geometry &= cross | ~stationary_closures(sdr, best, geometry, ratio=stop_ratio)
    out = MatchResult(res.method, res.similarity, best, res.score, accepted | geometry, res.seconds + seconds,
                      res.conf)
    report = {"frames_verified": int(np.count_nonzero(inliers >= 0)), "frames_blind": blind,
              "accepted_by_geometry": int(geometry.sum()),
              "ms_per_verified_frame": round(1e3 * seconds / max(int(np.count_nonzero(inliers >= 0)), 1), 2),
              "min_inliers": c.min_inliers}
    return out, report
