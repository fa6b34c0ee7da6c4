"""Frame sources: image folders, video files and text files listing images.

Every source streams its frames: iterating over it decodes one image at a
time, so a long traverse never has to fit in memory. A frame that cannot be
read is skipped with a :class:`FrameSkippedWarning` and recorded in
``source.skipped``; a run never stops half-way because of one bad file.

Frame numbering
---------------
``Frame.index`` is the frame's number *in the source*, independent of
``step``, ``fps`` and ``max_frames``: the position in the naturally sorted
folder listing, the line order of a list file, or the video frame number.
Ground-truth files with integer frame columns use the same numbering (see
:mod:`vpr.groundtruth`), so subsampling a traverse does not shift its ground
truth. ``Source.indices()`` gives the numbers of the frames that will be
attempted, parallel to ``Source.names()``; ``Source.iter_range(start, stop)``
reads only the frames at those positions (the unit of parallel encoding).
"""
from __future__ import annotations

import hashlib
import logging
import math
import os
import re
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from vpr.imageproc import to_bgr

__all__ = [
    "Frame",
    "FrameSkippedWarning",
    "Source",
    "FolderSource",
    "ListSource",
    "VideoSource",
    "IMAGE_EXTENSIONS",
    "VIDEO_EXTENSIONS",
    "LIST_EXTENSIONS",
    "natural_key",
    "open_source",
    "load_all",
    "iter_batches",
]

log = logging.getLogger(__name__)

IMAGE_EXTENSIONS = frozenset({".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff"})
VIDEO_EXTENSIONS = frozenset({".mp4", ".avi", ".mov", ".mkv", ".m4v", ".webm", ".mpg", ".mpeg", ".wmv"})
LIST_EXTENSIONS = frozenset({".txt", ".lst"})

# ANYDEPTH|ANYCOLOR keeps 16-bit and grey images as they are (to_bgr converts
# them) while still honouring EXIF orientation, which IMREAD_UNCHANGED ignores.
_IMREAD_FLAGS = cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR


class FrameSkippedWarning(UserWarning):
    """A frame could not be read and was left out of the stream."""


class Frame(NamedTuple):
    """One decoded frame.

    Attributes
    ----------
    index : int
        Frame number within the source (see the module docstring).
    name : str
        File name (folder), entry as written (list file) or ``frame_000123``
        (video).
    image : numpy.ndarray
        uint8 BGR image, shape (H, W, 3).
    """

    index: int
    name: str
    image: np.ndarray


_DIGITS = re.compile(r"(\d+)")


def natural_key(name: str) -> tuple:
    """Sort key putting ``img2`` before ``img10``; text compares case-insensitively."""
    parts = _DIGITS.split(name)
    key = tuple((0, int(p), "") if i % 2 else (1, 0, p.casefold()) for i, p in enumerate(parts))
    # the raw name breaks ties such as "a01" vs "a1" deterministically
    return key + ((2, 0, name),)


def _check_range(start, stop) -> tuple[int, int]:
    for v, what in ((start, "start"), (stop, "stop")):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise ValueError(f"frame range {what} must be a non-negative integer, got {v!r}")
    if stop < start:
        raise ValueError(f"frame range stop ({stop}) is before start ({start})")
    return int(start), int(stop)


def _check_positive_int(value, what: str) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{what} must be a positive integer, got {value!r}")
    if value < 1:
        raise ValueError(f"{what} must be a positive integer, got {value}")
    return int(value)


def _stat_token(path: Path) -> str:
    try:
        st = path.stat()
    except OSError:
        return f"{path}|missing"
    return f"{path}|{st.st_size}|{st.st_mtime_ns}"


def _decode_image(path: Path) -> tuple[np.ndarray | None, str]:
    """Read and decode one image file; return (image, "") or (None, reason)."""
    try:
        # imdecode on bytes rather than imread: works with non-ASCII paths on
        # every platform and separates "cannot read" from "cannot decode"
        buf = np.fromfile(str(path), dtype=np.uint8)
    except FileNotFoundError:
        return None, "file not found"
    except OSError as exc:
        return None, f"cannot read file ({exc.strerror or exc})"
    if buf.size == 0:
        return None, "empty file (0 bytes)"
    try:
        img = cv2.imdecode(buf, _IMREAD_FLAGS)
    except cv2.error as exc:
        return None, f"OpenCV error while decoding ({str(exc).strip().splitlines()[-1]})"
    if img is None:
        return None, "not a decodable image (corrupt, truncated or unsupported format)"
    try:
        return to_bgr(img, str(path)), ""
    except ValueError as exc:
        return None, str(exc)


class Source:
    """Base class: a named, re-iterable stream of :class:`Frame` objects.

    Attributes
    ----------
    path : pathlib.Path
        The folder, video or list file.
    name : str
        Short human-readable name (the folder or file name).
    skipped : list of (str, str)
        (frame name, reason) for every frame left out during the latest
        iteration; reset when a new iteration starts.
    ignored : int
        Non-image files ignored in a folder (0 for other sources).
    """

    kind = "source"

    def __init__(self, path):
        self.path = Path(path)
        self.name = self.path.resolve().name or str(self.path)
        self.skipped: list[tuple[str, str]] = []
        self.ignored = 0

    def names(self) -> list[str]:
        """Names of the frames that will be attempted, in order."""
        raise NotImplementedError

    def indices(self) -> list[int]:
        """Source frame numbers parallel to :meth:`names`."""
        raise NotImplementedError

    def key(self) -> str:
        """A string that changes when the source's content or selection changes."""
        raise NotImplementedError

    def __iter__(self) -> Iterator[Frame]:
        raise NotImplementedError

    def iter_range(self, start: int, stop: int) -> Iterator[Frame]:
        """Frames at positions ``start:stop`` of :meth:`names` (as a slice; unreadable ones skipped).

        The unit of parallel encoding: a worker reads only its range (a video
        seeks to it). Unlike iteration, an empty result does not raise;
        ``skipped`` holds the range's skipped frames.
        """
        raise NotImplementedError

    def _skip(self, name: str, reason: str) -> None:
        self.skipped.append((name, reason))
        warnings.warn(f"{self.path}: skipped frame {name}: {reason}", FrameSkippedWarning, stacklevel=3)

    def _no_frames_error(self) -> ValueError:
        msg = f"no readable frames in {self.path}"
        if self.skipped:
            first = self.skipped[0]
            msg += f" ({len(self.skipped)} skipped; first: {first[0]}: {first[1]})"
        return ValueError(msg)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.path)!r})"


class _FileListSource(Source):
    """Shared logic for sources made of individual image files."""

    def __init__(self, path, step=None, max_frames=None):
        super().__init__(path)
        self.step = _check_positive_int(step, "step") or 1
        self.max_frames = _check_positive_int(max_frames, "max_frames")
        # filled by subclasses: (frame name, file path) for every image, in source order
        self._entries: list[tuple[str, Path]] = []

    def _selected(self) -> list[tuple[int, str, Path]]:
        sel = [(i, n, p) for i, (n, p) in enumerate(self._entries)][::self.step]
        return sel[:self.max_frames] if self.max_frames else sel

    def names(self) -> list[str]:
        return [n for _, n, _ in self._selected()]

    def indices(self) -> list[int]:
        return [i for i, _, _ in self._selected()]

    def key(self) -> str:
        h = hashlib.sha256()
        h.update(f"{self.kind}|{self._key_header()}|step={self.step}|max={self.max_frames}\n".encode())
        for _, name, p in self._selected():
            h.update(f"{name}|{_stat_token(p.resolve())}\n".encode())
        return f"{self.kind}:{h.hexdigest()}"

    def _key_header(self) -> str:
        return str(self.path.resolve())

    def __iter__(self) -> Iterator[Frame]:
        self.skipped = []
        n_yielded = 0
        for index, name, p in self._selected():
            img, reason = _decode_image(p)
            if img is None:
                self._skip(name, reason)
                continue
            n_yielded += 1
            yield Frame(index, name, img)
        if n_yielded == 0:
            raise self._no_frames_error()

    def iter_range(self, start: int, stop: int) -> Iterator[Frame]:
        start, stop = _check_range(start, stop)
        self.skipped = []
        for index, name, p in self._selected()[start:stop]:
            img, reason = _decode_image(p)
            if img is None:
                self._skip(name, reason)
                continue
            yield Frame(index, name, img)


class FolderSource(_FileListSource):
    """The images in one folder (not recursive), in natural order.

    Parameters
    ----------
    path : str or Path
        Folder holding .jpg/.jpeg/.png/.bmp/.tif/.tiff files (extension case
        ignored). Hidden files are ignored; other files are ignored and counted
        in ``ignored``.
    step : int, optional
        Keep every ``step``-th image.
    max_frames : int, optional
        Attempt at most this many images (after ``step``).

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    NotADirectoryError
        ``path`` is not a folder.
    ValueError
        The folder holds no images.
    """

    kind = "folder"

    def __init__(self, path, step=None, max_frames=None):
        super().__init__(path, step, max_frames)
        if not self.path.exists():
            raise FileNotFoundError(f"no such folder: {self.path}")
        if not self.path.is_dir():
            raise NotADirectoryError(f"not a folder: {self.path}")
        images = []
        with os.scandir(self.path) as it:
            for entry in it:
                if entry.name.startswith("."):
                    continue
                try:
                    is_file = entry.is_file()
                except OSError:
                    is_file = False
                if not is_file:
                    continue
                if Path(entry.name).suffix.lower() in IMAGE_EXTENSIONS:
                    images.append(entry.name)
                else:
                    self.ignored += 1
        if not images:
            raise ValueError(f"no images in {self.path} ({self.ignored} other files ignored)")
        images.sort(key=natural_key)
        self._entries = [(n, self.path / n) for n in images]
        if self.ignored:
            log.info("%s: %d non-image files ignored", self.path, self.ignored)


class ListSource(_FileListSource):
    """Images named in a text file, one path per line.

    Relative paths are relative to the list file's folder. Blank lines and
    lines starting with ``#`` are ignored. A listed file that is missing or
    cannot be decoded is skipped at iteration time, like a corrupt image in a
    folder. Frame names are the paths as written in the list.

    Raises
    ------
    FileNotFoundError
        The list file does not exist.
    ValueError
        The list is not UTF-8 text or names no images.
    """

    kind = "list"

    def __init__(self, path, step=None, max_frames=None):
        super().__init__(path, step, max_frames)
        if not self.path.is_file():
            raise FileNotFoundError(f"no such list file: {self.path}")
        try:
            text = self.path.read_text(encoding="utf-8-sig")
        except UnicodeDecodeError as exc:
            raise ValueError(f"{self.path}: not a UTF-8 text file (byte {exc.start})") from None
        base = self.path.parent
        for line in text.splitlines():
            entry = line.strip()
            if not entry or entry.startswith("#"):
                continue
            p = Path(entry).expanduser()
            self._entries.append((entry, p if p.is_absolute() else base / p))
        if not self._entries:
            raise ValueError(f"no image paths in {self.path}")

    def _key_header(self) -> str:
        return _stat_token(self.path.resolve())


def _resample_frames(native_fps: float, target_fps: float) -> Iterator[int]:
    """Video frame numbers to keep when resampling ``native_fps`` to ``target_fps``.

    Sample k is at time k / target_fps; the kept frame is the first whose
    timestamp i / native_fps is not earlier than that. Endless generator.
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


class VideoSource(Source):
    """Frames of a video file decoded with OpenCV.

    Parameters
    ----------
    path : str or Path
        Video file.
    fps : float, optional
        Resample to this frame rate using the video's nominal frame rate
        (frame ``i`` is at ``i / video_fps`` seconds). Rates at or above the
        video's own keep every frame.
    step : int, optional
        Keep every ``step``-th frame. Not together with ``fps``.
    max_frames : int, optional
        Yield at most this many frames; decoding stops there.

    Notes
    -----
    :meth:`names` relies on the container's frame count (one counting pass
    when the container has none). If decoding ends before that count, the
    stream ends with a warning and the first missing frame is recorded in
    ``skipped``: OpenCV cannot tell a decode failure from a short file.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    ValueError
        Both ``fps`` and ``step``; bad values; the file cannot be opened or
        its first frame cannot be decoded; ``fps`` for a video without a
        frame rate.
    """

    kind = "video"

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
        self.step = _check_positive_int(step, "step")
        self.max_frames = _check_positive_int(max_frames, "max_frames")
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
        self._reported_count = int(reported) if math.isfinite(reported) and reported > 0 else None
        self._count: int | None = self._reported_count

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
        """Endless increasing sequence of frame numbers to keep."""
        if self.fps is not None and self.fps < self.video_fps:
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
        return out

    def names(self) -> list[str]:
        return [self.frame_name(i) for i in self.indices()]

    @staticmethod
    def frame_name(i: int) -> str:
        """Name of video frame ``i``: ``frame_000123``."""
        return f"frame_{i:06d}"

    def key(self) -> str:
        token = _stat_token(self.path.resolve())
        raw = f"video|{token}|fps={self.fps}|step={self.step}|max={self.max_frames}"
        return f"video:{hashlib.sha256(raw.encode()).hexdigest()}"

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
            for frame in self._decode(cap, self._selection(), 0, "stream ended"):
                n_yielded += 1
                yield frame
                if self.max_frames and n_yielded >= self.max_frames:
                    break
        finally:
            cap.release()
        if n_yielded == 0:
            raise self._no_frames_error()

    def iter_range(self, start: int, stop: int) -> Iterator[Frame]:
        start, stop = _check_range(start, stop)
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


def open_source(path, fps=None, step=None, max_frames=None) -> Source:
    """Open a folder, video file or image-list file as a :class:`Source`.

    Parameters
    ----------
    path : str or Path
        A folder of images, a video (.mp4 .avi .mov .mkv .m4v .webm .mpg .mpeg
        .wmv) or a list file (.txt .lst).
    fps : float, optional
        Video only: resample to this frame rate.
    step : int, optional
        Keep every ``step``-th frame.
    max_frames : int, optional
        Cap on the number of frames attempted.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    ValueError
        Unknown kind of path, ``fps`` for a non-video, or an error from the
        source's constructor (empty folder, unreadable video, ...).
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"no such file or folder: {p}")
    if p.is_dir():
        if fps is not None:
            raise ValueError(f"{p}: fps only applies to videos; use step for image folders")
        return FolderSource(p, step=step, max_frames=max_frames)
    ext = p.suffix.lower()
    if ext in VIDEO_EXTENSIONS:
        return VideoSource(p, fps=fps, step=step, max_frames=max_frames)
    if ext in LIST_EXTENSIONS:
        if fps is not None:
            raise ValueError(f"{p}: fps only applies to videos; use step for image lists")
        return ListSource(p, step=step, max_frames=max_frames)
    raise ValueError(
        f"{p}: unknown source kind {ext or '(no extension)'!r}; expected a folder of images, a video "
        f"({' '.join(sorted(VIDEO_EXTENSIONS))}) or an image list ({' '.join(sorted(LIST_EXTENSIONS))})")


def load_all(source: Source, progress: bool = True) -> tuple[list[np.ndarray], list[str]]:
    """Read every frame of ``source`` into memory.

    Returns
    -------
    images : list of numpy.ndarray
        uint8 BGR images of the frames that could be read.
    names : list of str
        Their names; skipped frames are in ``source.skipped``.
    """
    from tqdm import tqdm

    images, names = [], []
    total = len(source.names()) if progress else None
    with tqdm(total=total, desc=source.name, unit="frame", disable=not progress) as bar:
        for frame in source:
            images.append(frame.image)
            names.append(frame.name)
            bar.update(1)
    return images, names


def iter_batches(source: Source, batch_size: int) -> Iterator[list[Frame]]:
    """Yield lists of up to ``batch_size`` frames; only one batch is held at a time."""
    batch_size = _check_positive_int(batch_size, "batch_size")
    if batch_size is None:
        raise ValueError("batch_size must be a positive integer, got None")
    batch: list[Frame] = []
    for frame in source:
        batch.append(frame)
        if len(batch) == batch_size:
            yield batch
            batch = []
    if batch:
        yield batch
