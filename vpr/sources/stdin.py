"""Image paths read from a stream (a robot's pipe into ``vpr localize -``), one per line, as they come."""
from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from .base import Frame, Source, decode_image

__all__ = ["StdinSource", "SESSION", "FramesByPath"]

#: What :class:`StdinSource` yields for a line ``#session``.
SESSION = Frame(-2, "#session", None)

#: A line longer than this is not a path (Linux's PATH_MAX).
_MAX_PATH = 4096


def _garbage(raw: bytes) -> str | None:
    """Why a line is not a path (None: it may be one)."""
    if b"\0" in raw:
        return "not a path (a NUL byte)"
    if len(raw) > _MAX_PATH:
        return f"not a path (over {_MAX_PATH} bytes)"
    if any(c < 32 and c != 9 for c in raw):
        return "not a path (control characters)"
    try:
        raw.decode("utf-8")
    except UnicodeDecodeError:
        if not os.path.exists(os.fsdecode(raw)):  # a real file may have a name that is not UTF-8
            return "not a path (not UTF-8 text, and no such file)"
    return None


class FramesByPath:
    """``image(j)``: frame ``j`` of a stream of image paths, read again from its path (``names``, the paths in the
    order their frames were numbered); None where the file is gone or no image (a run resumed elsewhere, a log
    rotated away)."""

    def __init__(self, names=()):
        self.names: list[str] = list(names)

    def __call__(self, j: int) -> np.ndarray | None:
        return decode_image(Path(self.names[j]))[0]


class StdinSource(Source):
    """The frames named on ``stream``, one path per line, read as they arrive (once: a pipe is not re-read).

    Frames are numbered in the order their paths come (lines that are not paths take no number).
    """

    kind = "stdin"
    carries = frozenset({"paths"})

    def __init__(self, stream, name: str = "stdin"):
        super().__init__(name)
        self.name = name
        self._stream = stream
        self.line = 0  # the input line last read

    def _lines(self):
        buf = getattr(self._stream, "buffer", None)
        if buf is not None:
            yield from buf
            return
        for line in self._stream:  # a text stream without a byte buffer, encoded back
            yield line.encode("utf-8", "surrogateescape")

    def __iter__(self) -> Iterator[Frame]:
        index, seen_path = 0, False
        for lineno, raw in enumerate(self._lines(), start=1):
            self.line = lineno
            text = raw.rstrip(b"\r\n").strip()
            if text == b"#session":
                yield SESSION
                continue
            if not text or text.startswith(b"#"):
                continue
            why = _garbage(text)
            if why is not None:
                if not seen_path:
                    raise ValueError(f"{self.name}: binary data, not image paths one per line (line {lineno}: {why})")
                self.skipped.append((f"{self.name} line {lineno}", why))
                continue
            seen_path = True
            name = os.fsdecode(text)
            img, reason = self._read(Path(name), name)
            index += 1
            if img is None:
                self.skipped.append((name, reason))
                continue
            yield Frame(index - 1, name, img)

    def names(self) -> list[str]:
        raise ValueError(f"{self.name}: frames on a stream are not known before they come")

    def key(self) -> str:
        return f"stdin:{id(self._stream)}"
