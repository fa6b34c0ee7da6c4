"""The query's speed read from paths of best frames, without ground truth: runs, their speed, the sampling asked."""
from __future__ import annotations

import numpy as np

from vpr.types import RATE_RATIO

__all__ = ["MIN_RUN", "path_runs", "path_run_speeds", "path_speed", "SpeedReader", "session_speeds", "speed_step"]


#: The frames of a path that read its speed (:func:`path_speed`, :class:`vpr.shosm.SpeedFollower`).
MIN_RUN = 10


def path_runs(best, accepted, min_run: int = MIN_RUN) -> tuple[np.ndarray, np.ndarray]:
    """The runs :func:`path_speed` reads: every run of at least ``min_run`` accepted frames whose best frame moves on
    by 0 to 4 frames a frame. Returns (first frames, last frames) of the runs."""
    best = np.asarray(best, np.int64)
    acc = np.asarray(accepted, bool) & (best >= 0)
    d = np.diff(best)
    linked = acc[:-1] & acc[1:] & (d >= 0) & (d <= 4)  # step i joins frames i and i + 1 on one path
    edges = np.diff(np.r_[0, linked.astype(np.int8), 0])
    first, last = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)  # a run's frames: first .. last
    long = last - first + 1 >= min_run
    return first[long], last[long]


def path_run_speeds(best, accepted, min_run: int = MIN_RUN) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The runs of :func:`path_runs` and each one's speed (best frames moved per frame). Returns (first frames, last
    frames, speeds)."""
    best = np.asarray(best, np.int64)
    first, last = path_runs(best, accepted, min_run)
    return first, last, (best[last] - best[first]) / np.maximum(last - first, 1)


def path_speed(best, accepted, min_run: int = MIN_RUN) -> tuple[float | None, int]:
    """Database (earlier) frames per query frame along the accepted paths, without ground truth.

    Over every run of :func:`path_runs`: the frames moved over the query frames. Returns (speed, or None without
    such a run; query frames counted).
    """
    best = np.asarray(best, np.int64)
    first, last = path_runs(best, accepted, min_run)
    steps = int((last - first).sum())
    moved = int((best[last] - best[first]).sum())
    return (moved / steps if steps else None), steps


class SpeedReader:
    """:func:`path_speed` read as the frames come: :meth:`step` each frame's best frame and whether it counts;
    :attr:`speed` is what :func:`path_speed` returns over the frames so far (O(1) a frame)."""

    def __init__(self, min_run: int = MIN_RUN):
        self.min_run = int(min_run)
        self.moved = self.steps = 0  # over the finished runs of min_run frames or more
        self.first = self.last = -1  # the best frames of the current run (-1: none)
        self.length = 0

    def step(self, best: int, counts: bool = True) -> None:
        best = int(best)
        if not counts or best < 0:
            self._close()
        elif self.length and 0 <= best - self.last <= 4:
            self.last, self.length = best, self.length + 1
        else:
            self._close()
            self.first = self.last = best
            self.length = 1

    def _close(self) -> None:
        if self.length >= self.min_run:
            self.moved += self.last - self.first
            self.steps += self.length - 1
        self.first = self.last = -1
        self.length = 0

    @property
    def speed(self) -> float | None:
        open_run = self.length >= self.min_run
        steps = self.steps + (self.length - 1 if open_run else 0)
        moved = self.moved + (self.last - self.first if open_run else 0)
        return moved / steps if steps else None

    @property
    def run_speed(self) -> float | None:
        """The speed of the run the frames are on now (a run of :func:`path_runs`), once it is ``min_run`` frames
        long; None before."""
        return (self.last - self.first) / (self.length - 1) if self.length >= max(self.min_run, 2) else None


def session_speeds(best, starts, min_run: int = MIN_RUN) -> list[float | None]:
    """Each later session's speed against the earlier ones, without ground truth: :func:`path_speed` over the frames
    of session ``s`` whose best frame lies in an earlier session, accepted or not (a session driven at another speed
    may accept none). ``starts``: each session's first frame; returns one reading per session after the first
    (None: no path of ``min_run`` frames)."""
    best = np.asarray(best, np.int64)
    bounds = [*(int(a) for a in sorted(starts)), best.size]
    out = []
    for a, b in zip(bounds[1:-1], bounds[2:], strict=True):
        part = best[a:b]
        out.append(path_speed(part, (part >= 0) & (part < a), min_run)[0])
    return out


def speed_step(speed: float | None) -> int:
    """The sampling that makes a query moving ``speed`` frames a frame (:func:`vpr.evaluate.path_speed`) move one:
    ``k`` >= 2 for one frame in k of what it is matched to (:data:`RATE_RATIO` or more times faster), ``-k`` for one
    query frame in k (as many times slower), 0 otherwise (also without a speed, or paths that never move on)."""
    if speed is None or speed <= 0 or RATE_RATIO > speed > 1 / RATE_RATIO:
        return 0
    return max(2, round(speed)) if speed > 1 else -max(2, round(1 / speed))
