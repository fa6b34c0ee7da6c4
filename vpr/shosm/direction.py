"""Whether a query runs the map backwards: the evidence of it moving backward along the map against the evidence its
answers are decided on."""
from __future__ import annotations

import numpy as np

from vpr.paths import MIN_RUN

__all__ = ["reversed_frames", "Direction"]


def _finite(z) -> np.ndarray:
    z = np.asarray(z, np.float64)
    return np.where(np.isfinite(z), z, 0.0)


def reversed_frames(z_forward, z_reverse, window: int = MIN_RUN, causal: bool = True, moved=None) -> np.ndarray:
    """Per query frame, whether the query runs the map backwards there: over the last ``window`` frames, the mean best
    z-score of the evidence of the query moving backward along the map (``z_reverse``: the evidence with the map's
    transitions reversed, ``direction="reversed"``) is above that of the evidence moving along it (``z_forward``,
    ``direction="forward"``). A frame without candidates counts 0. The first ``window - 1`` frames: over the frames so
    far (``causal``, online, where :attr:`Direction.read` holds their answers back), or as the first ``window``
    frames read (a whole traverse at once). ``moved`` (bool per frame): only the frames that moved are read (a query
    that stands has no direction); the others take the reading of the last frame that moved (none yet: False)."""
    f, r = _finite(z_forward), _finite(z_reverse)
    if f.shape != r.shape:
        raise ValueError(f"z_forward and z_reverse need one value per frame each, got {f.shape} and {r.shape}")
    if moved is not None:
        moved = np.asarray(moved, bool)
        idx = np.flatnonzero(moved)
        read = np.r_[False, reversed_frames(f[idx], r[idx], window, causal)]
        last = np.maximum.accumulate(np.where(moved, np.arange(f.size), -1))  # the last frame that moved, -1: none
        return read[np.searchsorted(idx, last) + 1] & (last >= 0)
    d = np.r_[0.0, np.cumsum(r - f)]
    i = np.arange(1, f.size + 1)
    if not causal:
        i = np.maximum(i, min(int(window), f.size))
    return d[i] - d[np.maximum(i - int(window), 0)] > 0.0


class Direction:
    """:func:`reversed_frames` one frame at a time (the last ``window`` frames kept)."""

    def __init__(self, window: int = MIN_RUN):
        self.window = int(window)
        self.diff = np.zeros(0, np.float64)

    def update(self, z_forward: float, z_reverse: float, moved: bool = True) -> bool:
        """Whether the query runs the map backwards at this frame (one that did not move is not read: the reading
        of the frames before)."""
        if moved:
            self.diff = np.r_[self.diff, _finite(z_reverse) - _finite(z_forward)][-self.window:]
        return bool(self.diff.sum() > 0.0)

    @property
    def read(self) -> bool:
        """Whether the direction is read: ``window`` frames that moved seen (before, one direction's evidence is not
        yet told from the other's, and no answer is accepted)."""
        return self.diff.size >= self.window

    def reset(self) -> None:
        self.diff = np.zeros(0, np.float64)

    def state(self) -> tuple[dict, dict]:
        return {"window": self.window}, {"diff": self.diff.copy()}

    def load_state(self, header: dict, arrays: dict) -> Direction:
        self.diff = np.asarray(arrays["diff"], np.float64)[-self.window:]
        return self
