"""The frame source: a named, re-iterable stream of decoded frames, and what every kind shares."""
from __future__ import annotations

import logging
import re
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from vpr.checks import check_int
from vpr.imageproc import depth_bits, to_bgr

__all__ = ["Frame", "FrameSkippedWarning", "IgnoredFilesWarning", "Source", "IMAGE_EXTENSIONS",
           "OTHER_IMAGE_EXTENSIONS", "VIDEO_EXTENSIONS", "LIST_EXTENSIONS", "natural_key", "decode_image",
           "read_image", "check_fps", "check_range", "check_positive_int", "stat_token", "frames_in"]

log = logging.getLogger(__name__)

IMAGE_EXTENSIONS = frozenset({".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp", ".pgm", ".ppm", ".pbm",
                              ".pnm", ".jp2"})
#: Files of a folder that are frames OpenCV may not decode: they keep their place in the frame numbering and are
#: skipped with a warning if unreadable, so that the frames after them keep their numbers (``--tolerance``).
OTHER_IMAGE_EXTENSIONS = frozenset({".gif", ".heic", ".heif", ".avif", ".jxl", ".exr", ".hdr", ".ico", ".svg",
                                    ".dng", ".raw", ".cr2", ".nef", ".arw", ".psd"})
VIDEO_EXTENSIONS = frozenset({".mp4", ".avi", ".mov", ".mkv", ".m4v", ".webm", ".mpg", ".mpeg", ".wmv"})
LIST_EXTENSIONS = frozenset({".txt", ".lst"})

# ANYDEPTH|ANYCOLOR keeps 16-bit and grey images as they are (to_bgr converts them) while still honouring EXIF
# orientation, which IMREAD_UNCHANGED ignores.
_IMREAD_FLAGS = cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR


class FrameSkippedWarning(UserWarning):
    """A frame could not be read and was left out of the stream."""


class IgnoredFilesWarning(UserWarning):
    """Files of a folder that are not images were not read as frames."""


class Frame(NamedTuple):
    """One decoded frame: ``index`` within the source (``docs/internals.md``), ``name`` (file name, list entry or
    ``frame_000123``), ``image`` uint8 BGR (H, W, 3).
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


def check_range(start, stop) -> tuple[int, int]:
    for v, what in ((start, "start"), (stop, "stop")):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise ValueError(f"frame range {what} must be a non-negative integer, got {v!r}")
    if stop < start:
        raise ValueError(f"frame range stop ({stop}) is before start ({start})")
    return int(start), int(stop)


def check_positive_int(value, what: str) -> int | None:
    """``None``, or a positive integer (:func:`vpr.checks.check_int`)."""
    return None if value is None else check_int(value, what, 1)


def stat_token(path: Path) -> str:
    try:
        st = path.stat()
    except OSError:
        return f"{path}|missing"
    return f"{path}|{st.st_size}|{st.st_mtime_ns}"


def read_image(path: Path) -> tuple[np.ndarray | None, str]:
    """Read and decode one image file as it is stored (grey, colour, 16-bit); return (image, "") or (None, reason)."""
    try:
        # imdecode on bytes rather than imread: works with non-ASCII paths on every platform and separates "cannot
        # read" from "cannot decode"
        buf = np.fromfile(str(path), dtype=np.uint8)
    except FileNotFoundError:
        return None, "dangling symbolic link" if path.is_symlink() else "file not found"
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
    return img, ""


def decode_image(path: Path, bits: int | None = None) -> tuple[np.ndarray | None, str]:
    """:func:`read_image` as uint8 BGR (``bits``: :func:`vpr.imageproc.to_uint8`); (image, "") or (None, reason)."""
    img, reason = read_image(path)
    if img is None:
        return None, reason
    try:
        return to_bgr(img, str(path), bits), ""
    except ValueError as exc:
        return None, str(exc)


def check_fps(path, fps: float | None, rate: float | None) -> None:
    """Warn when ``fps`` asks for more frames per second than the source has (``rate``): every frame is read,
    and a frame is never repeated to make up the rate."""
    if fps is not None and rate and fps > rate * 1.01:
        warnings.warn(f"{path}: --fps {fps:g} is above its frame rate ({rate:.3g} frames/s): every frame is read",
                      UserWarning, stacklevel=3)


def frames_in(exclude, rate: float | None = None, none: str = "the frames have none") -> int:
    """A number of frames (``30``, ``"30"``) or of seconds (``"5s"``, at ``rate`` frames per second) in frames;
    ``none``: says where the times are missing."""
    text = str(exclude).strip().lower()
    try:
        if text.endswith("s"):
            if not rate:
                raise ValueError(f"--exclude {exclude}: seconds need the frames' times, and {none}; give frames "
                                 "instead (e.g. --exclude 30)")
            n = round(float(text[:-1]) * rate)
        else:
            n = int(text)
    except (TypeError, ValueError) as e:
        if "--exclude" in str(e):
            raise
        raise ValueError(f"--exclude must be a number of frames or seconds like 5s, got {exclude!r}") from None
    if n < 1:
        raise ValueError(f"--exclude must be at least 1 frame, got {exclude!r} ({n} frames)")
    return n


class Source:
    """Base class: a named, re-iterable stream of :class:`Frame` objects.

    Attributes
    ----------
    path : pathlib.Path
    name : str
        Short name (the folder or file name).
    skipped : list of (str, str)
        (frame name, reason) of every frame left out in the latest iteration.
    ignored : int
        Non-image files ignored in a folder.
    salvaged : dict or None
        A damaged recording read up to the damage: ``{"damage", "messages_read"}``.
    """

    kind = "source"
    #: whether its frames are images (a descriptor file's are descriptor rows, of length ``dim``)
    has_images: bool = True
    #: the input line last read, for sources read line by line (image paths on stdin); None for the others
    line: int | None = None
    #: what the frames of this kind of source come with: ``"stamps"`` (times), ``"positions"``
    #: (:meth:`trajectory`), ``"paths"`` (image files, :meth:`frame_paths`)
    carries: frozenset = frozenset()
    #: the options (:func:`vpr.sources.open_source`) this kind takes
    options: frozenset = frozenset({"step", "max_frames"})
    #: whether reading one frame alone costs more than reading on from the frame before it (a video decodes from its
    #: key frame, a bag opens its index): :func:`vpr.sources.frame_reader` and :func:`vpr.sources.images_at` then
    #: read on where they can
    sequential: bool = False

    @classmethod
    def accepts(cls, path: Path) -> bool:
        """Whether ``path`` is a source of this kind (:func:`vpr.sources.open_source` asks each kind in turn)."""
        return False

    def __init__(self, path):
        self.path = Path(path)
        self.name = self.path.resolve().name or str(self.path)
        self.skipped: list[tuple[str, str]] = []
        self.ignored = 0
        self.salvaged: dict | None = None
        self._bits: int | None = None  # of 16-bit frames: one scale for every frame of the source

    def names(self) -> list[str]:
        """Names of the frames that will be attempted, in order."""
        raise NotImplementedError

    def indices(self) -> list[int]:
        """Source frame numbers parallel to :meth:`names`."""
        raise NotImplementedError

    def key(self) -> str:
        """A string that changes when the source's content or selection changes."""
        raise NotImplementedError

    def stamps(self):
        """The times (seconds) of the frames :meth:`indices` names, where the source has them (else None).

        Bags: the bag's record times; videos: the container's presentation times (from the first frame); folders and
        lists: file names that are times (``1305031102.175304.png``, as the TUM RGB-D datasets name them).
        """
        return None

    def native_rate(self) -> float | None:
        """Frames per second of the source's own frame numbers (:meth:`indices`), where they are evenly timed (a
        video's rate; else None)."""
        return None

    def rate(self) -> float | None:
        """Frames per second of the frames kept, from their times (None without times)."""
        t = self.stamps()
        if t is None or len(t) < 2 or not np.all(np.isfinite(t)):
            return None
        span = float(t[-1] - t[0])
        return (len(t) - 1) / span if span > 0 else None

    def frames_in(self, exclude) -> int:
        """:func:`frames_in` with this source's :meth:`rate`."""
        return frames_in(exclude, self.rate(), f"{self.path} ({self.kind}) has none")

    def frame_paths(self) -> list[Path] | None:
        """The image files of the frames :meth:`indices` names (None: the frames are not files)."""
        return None

    def trajectory(self, topic: str):
        """(times s, positions (n, 2), ``"latlon"`` or ``"metres"``) of a position topic (``"positions"``)."""
        raise ValueError(f"--gt-topic {topic}: {self.path} is not a ROS bag; give its positions with --gt FILE")

    def restrict(self, indices) -> None:
        """Attempt only the frames numbered ``indices`` among those selected (e.g. one per 2 m of travel)."""
        self._only = frozenset(int(i) for i in indices)

    def _allowed(self, index: int) -> bool:
        only = getattr(self, "_only", None)
        return only is None or index in only

    def exact_total(self) -> int | None:
        """The number of frames in the source before any selection, where it is known exactly (else None).

        A ground-truth matrix over the source's frames must have this size. A video's container count is not exact (it
        may count frames that do not decode, or a nominal rate times the duration): None.
        """
        return None

    def _selected(self):
        """The frames to attempt, as the kind keeps them (sliced by :meth:`iter_range`)."""
        raise NotImplementedError

    def _frames(self, selection) -> Iterator[Frame]:
        """The readable frames of a slice of :meth:`_selected`; the others skipped (:meth:`_skip`)."""
        raise NotImplementedError

    def __iter__(self) -> Iterator[Frame]:
        self.skipped = []
        n = 0
        for f in self._frames(self._selected()):
            n += 1
            yield f
        if n == 0:
            raise self._no_frames_error()

    def iter_range(self, start: int, stop: int) -> Iterator[Frame]:
        """Frames at positions ``start:stop`` of :meth:`names` (as a slice; unreadable ones skipped).

        The unit of parallel encoding: a worker reads only its range (a video seeks to it). Unlike iteration, an empty
        result does not raise; ``skipped`` holds the range's skipped frames.
        """
        start, stop = check_range(start, stop)
        self.skipped = []
        yield from self._frames(self._selected()[start:stop])

    def _read(self, path: Path, name: str) -> tuple[np.ndarray | None, str]:
        """An image file as a frame (:meth:`_bgr`), or the reason it is not one."""
        img, reason = read_image(path)
        if img is None:
            return None, reason
        try:
            return self._bgr(img, name), ""
        except ValueError as exc:
            return None, str(exc)

    def _bgr(self, img: np.ndarray, name: str) -> np.ndarray:
        """uint8 BGR of a decoded frame; 16-bit frames scaled alike, by the bits the source's first frame uses
        (a 12-bit camera keeps its contrast; :meth:`_first_bits`)."""
        if img.dtype == np.uint16 and self._bits is None:
            self._bits = self._first_bits(img)
        return to_bgr(img, f"{self.path} {name}", self._bits)

    def _first_bits(self, img: np.ndarray) -> int:
        """The bits of the source's first 16-bit frame (here: ``img``, the first one read)."""
        return depth_bits(img)

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
