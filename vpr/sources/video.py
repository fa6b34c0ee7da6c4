"""A video file as a frame source (OpenCV), resampled to a frame rate or a step."""
from __future__ import annotations

import hashlib
import math
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from vpr.imageproc import to_bgr

from .base import VIDEO_EXTENSIONS, Frame, Source, check_fps, check_positive_int, check_range, stat_token

__all__ = ["VideoSource", "sample_by_time", "frame_times"]


def _resample_frames(native_fps: float, target_fps: float) -> Iterator[int]:
    """Video frame numbers to keep when resampling ``native_fps`` to ``target_fps``.

    Sample k is at time k / target_fps; the kept frame is the first whose timestamp i / native_fps is not earlier than
    that. Endless generator.
    """
    ratio = native_fps / target_fps
    last = -1
    k = 0
    while True:
        # the epsilon absorbs float error when the ratio is a whole number
        i = math.ceil(k * ratio - 1e-9)
        k += 1
        if i > last:
            last = i
            yield i


def sample_by_time(times: np.ndarray, target_fps: float) -> list[int]:
    """Frame numbers to keep from frames at ``times`` (seconds, increasing): the same rule by real timestamps.

    Sample k is at ``times[0] + k / target_fps``; the kept frame is the first whose timestamp is not earlier than
    that. A variable frame rate is therefore sampled evenly in time, not in frame numbers.
    """
    if times.size == 0:
        return []
    span = float(times[-1] - times[0])
    samples = times[0] + np.arange(int(math.floor(span * target_fps + 1e-9)) + 1) / target_fps
    idx = np.searchsorted(times, samples - 1e-6, side="left")
    return np.unique(idx[idx < times.size]).tolist()


def frame_times(path) -> np.ndarray | None:
    """Presentation time (s) of every frame of a video's first video stream, in presentation order.

    Read from the container's packets with PyAV, without decoding (fast even for long videos); None when the container
    gives no timestamps. Frame ``i`` as OpenCV decodes it is at ``frame_times(path)[i]``.
    """
    import av  # PyAV: the container's real timestamps (OpenCV's frame rate is nominal)

    try:
        with av.open(str(path)) as c:
            if not c.streams.video:
                return None
            st = c.streams.video[0]
            stamps = []
            for pkt in c.demux(st):
                if pkt.size == 0:  # the demuxer's flush packet
                    continue
                t = pkt.pts if pkt.pts is not None else pkt.dts
                if t is None:
                    return None
                stamps.append(t)
            base = st.time_base
    except (av.FFmpegError, OSError, ValueError):
        return None
    if not stamps or base is None:
        return None
    return np.sort(np.asarray(stamps, np.float64)) * float(base)


class VideoSource(Source):
    """Frames of a video file decoded with OpenCV.

    ``fps``: resample by the frames' timestamps (:func:`frame_times`; sample k at ``k / fps`` s, the first frame not
    earlier kept; nominal rate without timestamps; at or above the video's own rate every frame). ``step``: every
    ``step``-th frame (not with ``fps``). ``max_frames``: decoding stops there. A missing file raises
    FileNotFoundError; bad values, a file that cannot be opened or decoded, or ``fps`` without a frame rate
    ValueError.
    """

    kind = "video"
    carries = frozenset({"stamps"})
    sequential = True
    options = frozenset({"fps", "step", "max_frames"})

    @classmethod
    def accepts(cls, path: Path) -> bool:
        return path.suffix.lower() in VIDEO_EXTENSIONS

    def native_rate(self) -> float | None:
        return self.video_fps or None

    def rate(self) -> float | None:
        """Frames per second of the frames kept: ``fps`` where it lowers the video's rate, else its rate / ``step``."""
        if not self.video_fps:
            return super().rate()
        if self.fps is not None and self.fps < self.video_fps:
            return self.fps
        return self.video_fps / (self.step or 1)

    def __init__(self, path, fps=None, step=None, max_frames=None):
        super().__init__(path)
        if fps is not None and step is not None:
            raise ValueError("give either fps or step, not both")
        if fps is not None:
            if isinstance(fps, bool) or not isinstance(fps, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(fps) or fps <= 0:
                raise ValueError(f"fps must be a positive number, got {fps!r}")
            fps = float(fps)
        self.fps = fps
        self.step = check_positive_int(step, "step")
        self.max_frames = check_positive_int(max_frames, "max_frames")
        if not self.path.is_file():
            raise FileNotFoundError(f"no such video file: {self.path}")
        cap = self._open()
        try:
            self.video_fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
            reported = cap.get(cv2.CAP_PROP_FRAME_COUNT)
            ok, first = cap.read()
        finally:
            cap.release()
        if not ok or first is None:
            raise ValueError(f"{self.path}: no frame could be decoded (unreadable or empty video)")
        if not math.isfinite(self.video_fps) or self.video_fps <= 0:
            self.video_fps = 0.0
            if fps is not None:
                raise ValueError(f"{self.path}: the video reports no frame rate; use step instead of fps")
        check_fps(self.path, fps, self.video_fps)
        self._reported_count = int(reported) if math.isfinite(reported) and reported > 0 else None
        self._count: int | None = self._reported_count
        self._times: np.ndarray | None = None  # frame timestamps, read for fps on first use

    def _open(self) -> cv2.VideoCapture:
        cap = cv2.VideoCapture(str(self.path))
        if not cap.isOpened():
            cap.release()
            raise ValueError(f"{self.path}: cannot open as a video (unsupported or corrupt file)")
        return cap

    def frame_count(self) -> int:
        """Number of frames in the video (container value, else counted once)."""
        if self._count is None:
            cap = self._open()
            n = 0
            try:
                while cap.grab():
                    n += 1
            finally:
                cap.release()
            self._count = n
        return self._count

    def _selection(self) -> Iterator[int]:
        """Increasing sequence of frame numbers to keep (endless, but for a selection by timestamps)."""
        if self.fps is not None:
            if self._times is None:
                self._times = frame_times(self.path)
                if self._times is None:
                    self._times = np.empty(0)
            if self._times.size:
                return iter(sample_by_time(self._times, self.fps))
            if self.fps < self.video_fps:
                return _resample_frames(self.video_fps, self.fps)
        step = self.step or 1
        return iter(range(0, 1 << 62, step))

    def indices(self) -> list[int]:
        n = self.frame_count()
        out = []
        for i in self._selection():
            if i >= n or (self.max_frames and len(out) >= self.max_frames):
                break
            out.append(i)
        return [i for i in out if self._allowed(i)]

    def stamps(self):
        """The frames' presentation times (s from the first frame), from the container; None without them."""
        times = frame_times(self.path) if self._times is None or not self._times.size else self._times
        if times is None or not times.size:
            return None
        idx = np.asarray(self.indices(), np.int64)
        if idx.size and idx.max() >= times.size:
            return None
        return times[idx] - times[0]

    def names(self) -> list[str]:
        return [self.frame_name(i) for i in self.indices()]

    @staticmethod
    def frame_name(i: int) -> str:
        """Name of video frame ``i``: ``frame_000123``."""
        return f"frame_{i:06d}"

    def key(self) -> str:
        token = stat_token(self.path.resolve())
        only = "" if getattr(self, "_only", None) is None else ",".join(map(str, sorted(self._only)))
        raw = f"video|{token}|fps={self.fps}|step={self.step}|max={self.max_frames}|{only}"
        return f"video:{hashlib.sha256(raw.encode('utf-8', 'surrogateescape')).hexdigest()}"

    def _decode(self, cap, targets, pos: int, ended: str) -> Iterator[Frame]:
        """Frames ``targets`` (increasing numbers) from ``cap``, whose next grab() returns frame ``pos``.

        The first frame that cannot be read ends the run (recorded with ``ended``).
        """
        for target in targets:
            # grab() without retrieve() skips decoding into BGR for dropped frames
            while pos < target:
                if not cap.grab():
                    break
                pos += 1
            if pos < target or not cap.grab():
                self._end_of_stream(target)
                return
            pos += 1
            ok, img = cap.retrieve()
            if not ok or img is None:
                self._skip(self.frame_name(target), f"frame could not be decoded; {ended}")
                return
            try:
                img = to_bgr(img, f"{self.path} frame {target}")
            except ValueError as exc:
                self._skip(self.frame_name(target), f"{exc}; {ended}")
                return
            yield Frame(target, self.frame_name(target), img)

    def __iter__(self) -> Iterator[Frame]:
        self.skipped = []
        cap = self._open()
        n_yielded = 0
        try:
            targets = (i for i in self._selection() if self._allowed(i))
            for frame in self._decode(cap, targets, 0, "stream ended"):
                n_yielded += 1
                yield frame
                if self.max_frames and n_yielded >= self.max_frames:
                    break
        finally:
            cap.release()
        if n_yielded == 0:
            raise self._no_frames_error()

    def iter_range(self, start: int, stop: int) -> Iterator[Frame]:
        start, stop = check_range(start, stop)
        self.skipped = []
        wanted = self.indices()[start:stop]
        if not wanted:
            return
        cap = self._open()
        try:
            pos = 0  # number of the frame the next grab() returns
            if wanted[0] > 0:
                cap.set(cv2.CAP_PROP_POS_FRAMES, wanted[0])
                if cap.get(cv2.CAP_PROP_POS_FRAMES) == wanted[0]:
                    pos = wanted[0]
                else:
                    # the backend could not seek exactly: decode from the start rather than misnumber frames
                    cap.release()
                    cap = self._open()
            yield from self._decode(cap, wanted, pos, "range ended")
        finally:
            cap.release()

    def _end_of_stream(self, target: int) -> None:
        expected = self._reported_count
        if expected is not None and target < expected:
            self._skip(self.frame_name(target),
                       f"decoding stopped at frame {target} of {expected} reported by the container; stream ended")
