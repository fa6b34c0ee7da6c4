"""Per-dimension standardisation of descriptors over a stream: the frames so far, or a sliding window causal to the
frame (the statistics an encoder fitted on a whole traverse, had as the frames come)."""
from __future__ import annotations

from collections import deque

import numpy as np

__all__ = ["CausalStandardiser", "RunningStandardiser", "CAUSAL_WINDOW", "CAUSAL_MIN", "causal_standardised",
           "window_standardised"]

#: Frames in the sliding window of ``standardise="causal"`` (chosen in research/docs/localize.md).
CAUSAL_WINDOW = 100
#: Frames the window needs before it is used (earlier frames share the statistics of the first ones).
CAUSAL_MIN = 10


def _window_stats(s_hi, s_lo, q_hi, q_lo, count):
    """(mean, std) of windows from prefix sums of the rows (``s``) and their squares (``q``), float64."""
    mean = (s_hi - s_lo) / count
    std = np.sqrt(np.maximum((q_hi - q_lo) / count - mean * mean, 0.0))
    std[std < 1e-6] = np.inf  # constant within the window: no information, as in fit
    return mean, std


def window_standardised(x: np.ndarray, mean, std) -> np.ndarray:
    """float64 rows standardised by their windows' statistics, float32."""
    return ((x - mean) / std).astype(np.float32)


def causal_standardised(d: np.ndarray) -> np.ndarray:
    """Rows standardised by the statistics of their sliding window (see ``standardise="causal"``)."""
    n = d.shape[0]
    x = d.astype(np.float64)
    cs = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])  # cumsum adds in order, as one frame at a time
    cs2 = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(x * x, axis=0)])
    t = np.arange(n)
    hi = np.maximum(t + 1, min(CAUSAL_MIN, n))  # window [lo, hi)
    lo = np.maximum(hi - CAUSAL_WINDOW, 0)
    mean, std = _window_stats(cs[hi], cs[lo], cs2[hi], cs2[lo], (hi - lo)[:, None].astype(np.float64))
    return window_standardised(x, mean, std)


class CausalStandardiser:
    """``standardise="causal"`` one frame at a time, with exactly the batch's statistics.

    :meth:`push` takes the next frame's descriptor block and returns the
    (mean, std) to standardise the frames that are now ready with
    (:meth:`TopKProjection.standardised` with ``stats``): the first
    :data:`CAUSAL_MIN` frames share the statistics of the first
    ``CAUSAL_MIN`` frames, so they wait for them (``push`` returns None until
    then, and then the statistics of all of them); every later frame is ready
    at once. :meth:`flush` gives the waiting frames of a shorter stream the
    statistics of what there is, as the batch does. The prefix sums are kept
    as the batch computes them, so the SDRs are the same bit for bit.
    """

    def __init__(self):
        self.frames = 0
        self._s: deque = deque(maxlen=CAUSAL_WINDOW + 1)  # prefix sums at frames frames-W .. frames
        self._q: deque = deque(maxlen=CAUSAL_WINDOW + 1)

    @property
    def waiting(self) -> int:
        """Frames pushed whose statistics are not known yet."""
        return self.frames if self.frames < CAUSAL_MIN else 0

    def push(self, x) -> tuple[np.ndarray, np.ndarray] | None:
        """Add one frame's block (dims,); the statistics of the frames now ready, or None."""
        x = np.asarray(x, np.float64).ravel()
        if not self._s:
            self._s.append(np.zeros_like(x))
            self._q.append(np.zeros_like(x))
        elif x.size != self._s[-1].size:
            raise ValueError(f"descriptor block: {x.size} dims, earlier frames had {self._s[-1].size}")
        self._s.append(self._s[-1] + x)
        self._q.append(self._q[-1] + x * x)
        self.frames += 1
        if self.frames < CAUSAL_MIN:
            return None
        return self._stats(self.frames)

    def flush(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The statistics of the waiting frames of a stream shorter than ``CAUSAL_MIN`` (None: none wait)."""
        return self._stats(self.frames) if 0 < self.frames < CAUSAL_MIN else None

    def _stats(self, hi: int):
        lo = max(hi - CAUSAL_WINDOW, 0)
        first = hi - (len(self._s) - 1)  # frame of the oldest prefix sum kept
        return _window_stats(self._s[-1], self._s[lo - first], self._q[-1], self._q[lo - first], float(hi - lo))

    def state(self) -> tuple[dict, dict]:
        """The prefix sums kept, as arrays (:meth:`load_state` continues from them)."""
        return {}, {"frames": np.array(self.frames, np.int64), "s": np.stack(self._s) if self._s else np.zeros((0, 0)),
                    "q": np.stack(self._q) if self._q else np.zeros((0, 0))}

    def load_state(self, header: dict, state: dict) -> CausalStandardiser:
        self.frames = int(state["frames"])
        self._s = deque(np.asarray(state["s"], np.float64), maxlen=CAUSAL_WINDOW + 1)
        self._q = deque(np.asarray(state["q"], np.float64), maxlen=CAUSAL_WINDOW + 1)
        return self


class RunningStandardiser:
    """Per-dimension mean and std of the frames seen so far, for encoding one frame at a time.

    The statistics are those of the last ``window`` frames (all frames so far
    when ``window`` is None) plus fitted statistics counted as
    ``prior_frames`` frames, so the first frames are standardised sensibly and
    the statistics follow a change of condition. Dimensions with no spread in
    the fitted statistics stay ignored (std ``inf``), as in a batch fit.

    Parameters
    ----------
    mean, std : float arrays (dims,)
        The fitted statistics (the prior).
    prior_frames : float > 0
    window : int >= 2 or None
    """

    def __init__(self, mean, std, prior_frames: float = 10.0, window: int | None = 50):
        if not prior_frames > 0:
            raise ValueError(f"prior_frames must be > 0, got {prior_frames}")
        if window is not None and int(window) < 2:
            raise ValueError(f"window must be at least 2 frames, got {window}")
        self.window = None if window is None else int(window)
        self._prior_std = np.asarray(std, np.float64)
        self._prior = (np.asarray(mean, np.float64), float(prior_frames))
        self.reset()

    def reset(self) -> None:
        """Forget the frames seen: the statistics are the prior's again (a new run of the robot)."""
        m, prior_frames = self._prior
        self.n = prior_frames
        self.sum = prior_frames * m
        self.sq = prior_frames * (np.where(np.isfinite(self._prior_std), self._prior_std, 0.0) ** 2 + m ** 2)
        self.recent: list[np.ndarray] = []
        self._last: tuple[np.ndarray, np.ndarray | None] | None = None  # the last frame added, the one it pushed out

    def update(self, x) -> tuple[np.ndarray, np.ndarray]:
        """Add one frame's descriptor block ``x`` (dims,); return the (mean, std) to standardise it with."""
        x = np.asarray(x, np.float64).ravel()
        self.n += 1.0
        old = None
        if self.window is not None:
            self.recent.append(x)
            if len(self.recent) > self.window:  # a sliding window: the oldest frame leaves the sums
                old = self.recent.pop(0)
                self.n -= 1.0
                self.sum -= old
                self.sq -= old * old
        self.sum += x
        self.sq += x * x
        self._last = (x, old)
        return self._stats()

    def withdraw(self) -> None:
        """Take the frame of the last :meth:`update` out of the statistics again (the frame it pushed out of the window
        back in): a frame that repeats the one before is no new sample of the places. Once per update."""
        if self._last is None:
            raise ValueError("withdraw: no frame to take back (one per update)")
        x, old = self._last
        self._last = None
        self.n -= 1.0
        self.sum -= x
        self.sq -= x * x
        if self.window is not None:
            self.recent.pop()
            if old is not None:
                self.recent.insert(0, old)
                self.n += 1.0
                self.sum += old
                self.sq += old * old

    def _stats(self) -> tuple[np.ndarray, np.ndarray]:
        mean = self.sum / self.n
        std = np.sqrt(np.maximum(self.sq / self.n - mean ** 2, 0.0))
        std = np.where(np.isfinite(self._prior_std) & (std >= 1e-6), std, np.inf)
        return mean.astype(np.float32), std.astype(np.float32)

    def state(self) -> tuple[dict, dict]:
        """The running sums as arrays (a restart continues them with :meth:`load_state`)."""
        out = {"n": np.array(self.n), "sum": self.sum, "sq": self.sq}
        if self.recent:
            out["recent"] = np.stack(self.recent)
        return {}, out

    def load_state(self, header: dict, state: dict) -> RunningStandardiser:
        self.n = float(state["n"])
        self.sum, self.sq = np.asarray(state["sum"], np.float64), np.asarray(state["sq"], np.float64)
        self.recent = list(np.asarray(state["recent"], np.float64)) if "recent" in state else []
        self._last = None
        return self
