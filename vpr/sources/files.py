"""Sources made of image files: a folder of images, or a text file listing image paths."""
from __future__ import annotations

import hashlib
import os
import re
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from vpr.imageproc import depth_bits

from .base import (
    IMAGE_EXTENSIONS,
    LIST_EXTENSIONS,
    OTHER_IMAGE_EXTENSIONS,
    Frame,
    IgnoredFilesWarning,
    Source,
    check_positive_int,
    natural_key,
    read_image,
    stat_token,
)

__all__ = ["FolderSource", "ListSource", "name_time"]

_WHOLE = re.compile(r"\d{10}|\d{13}|\d{16}|\d{19}")
_FRACTION = re.compile(r"\d+\.\d+")


def name_time(stem: str) -> float | None:
    """Seconds a file name's stem stands for (see :meth:`FolderSource.stamps`), or None."""
    if _FRACTION.fullmatch(stem):
        return float(stem)
    if _WHOLE.fullmatch(stem):
        return int(stem) / 10 ** (len(stem) - 10)
    return None


class _FileListSource(Source):
    """Shared logic for sources made of individual image files."""

    def __init__(self, path, step=None, max_frames=None):
        super().__init__(path)
        self.step = check_positive_int(step, "step") or 1
        self.max_frames = check_positive_int(max_frames, "max_frames")
        # filled by subclasses: (frame name, file path) for every image, in source order
        self._entries: list[tuple[str, Path]] = []

    def _selected(self) -> list[tuple[int, str, Path]]:
        """(number, name, path) of the frames selected, built once per selection (a report reads frames one by
        one)."""
        key = (len(self._entries), self.step, self.max_frames, getattr(self, "_only", None))
        if self.__dict__.get("_selection_key") != key:
            sel = [(i, n, p) for i, (n, p) in enumerate(self._entries)][::self.step]
            sel = sel[:self.max_frames] if self.max_frames else sel
            self._selection, self._selection_key = [e for e in sel if self._allowed(e[0])], key
        return self._selection

    def __getstate__(self) -> dict:
        """Pickled without the selection built from the entries (a source shipped to a worker)."""
        return {k: v for k, v in self.__dict__.items() if k not in ("_selection", "_selection_key", "_key", "_key_of")}

    carries = frozenset({"paths"})

    def frame_paths(self) -> list[Path]:
        """The files of the frames :meth:`indices` names."""
        return [p for _, _, p in self._selected()]

    def stamps(self):
        """Times from file names that are times, else None: seconds with a fraction (``1305031102.175304.png``,
        the TUM RGB-D datasets), or whole Unix seconds, milliseconds, microseconds or nanoseconds (10, 13, 16
        or 19 digits, as ROS exporters write them). A frame number (``000042.png``) is not a time."""
        out = []
        for _, name, _ in self._selected():
            t = name_time(Path(name).stem)
            if t is None:
                return None
            out.append(t)
        return np.asarray(out, np.float64)

    def names(self) -> list[str]:
        return [n for _, n, _ in self._selected()]

    def indices(self) -> list[int]:
        return [i for i, _, _ in self._selected()]

    def key(self) -> str:
        """A hash of the selected files' names, resolved paths, sizes and times (once per selection)."""
        selected = self._selected()
        if self.__dict__.get("_key_of") is selected:
            return self._key
        h = hashlib.sha256()
        head = f"{self.kind}|{self._key_header()}|step={self.step}|max={self.max_frames}\n"
        h.update(head.encode("utf-8", "surrogateescape"))
        for _, name, p in selected:
            h.update(f"{name}|{stat_token(p.resolve())}\n".encode("utf-8", "surrogateescape"))
        self._key, self._key_of = f"{self.kind}:{h.hexdigest()}", selected
        return self._key

    def _key_header(self) -> str:
        return str(self.path.resolve())

    def exact_total(self) -> int:
        return len(self._entries)

    def _first_bits(self, img: np.ndarray) -> int:
        for _, _, p in self._selected():  # the first readable frame, whichever range is read
            first, _ = read_image(p)
            if first is not None:
                return depth_bits(first) if first.dtype == np.uint16 else depth_bits(img)
        return depth_bits(img)

    def _frames(self, entries) -> Iterator[Frame]:
        for index, name, p in entries:
            img, reason = self._read(p, name)
            if img is None:
                self._skip(name, reason)
                continue
            yield Frame(index, name, img)


class FolderSource(_FileListSource):
    """The images in one folder, in natural order (those of its subfolders where it has none of its own).

    Images are :data:`IMAGE_EXTENSIONS` (any case); other image formats and dangling links keep their frame number and
    are skipped with a warning when they do not decode; hidden files are ignored, other files with one warning
    (counted in ``ignored``). ``step``: every ``step``-th image; ``max_frames``: images attempted. Raises
    FileNotFoundError, NotADirectoryError, or ValueError when the folder holds no images.
    """

    kind = "folder"

    @classmethod
    def accepts(cls, path: Path) -> bool:
        return path.is_dir()

    def __init__(self, path, step=None, max_frames=None):
        super().__init__(path, step, max_frames)
        if not self.path.exists():
            raise FileNotFoundError(f"no such folder: {self.path}")
        if not self.path.is_dir():
            raise NotADirectoryError(f"not a folder: {self.path}")
        images, others = [], []
        frame_like = IMAGE_EXTENSIONS | OTHER_IMAGE_EXTENSIONS
        with os.scandir(self.path) as it:
            for entry in it:
                if entry.name.startswith("."):
                    continue
                try:
                    # a symbolic link is a frame whether or not its target exists: a dangling one is skipped with a
                    # warning at reading time and keeps its frame number, like a corrupt image
                    is_file = entry.is_file() or entry.is_symlink() and not entry.is_dir()
                except OSError:
                    is_file = False
                if not is_file:
                    continue
                if Path(entry.name).suffix.lower() in frame_like:
                    images.append(entry.name)
                else:
                    others.append(entry.name)
        self.ignored = len(others)
        if not images:
            images = self._nested(frame_like)
        if not images:
            raise ValueError(f"no images in {self.path} ({self.ignored} other files ignored)")
        images.sort(key=natural_key)
        self._entries = [(n, self.path / n) for n in images]
        if others:
            others.sort(key=natural_key)
            warnings.warn(f"{self.path}: {len(others)} files that are not images ignored (e.g. "
                          f"{', '.join(others[:3])})", IgnoredFilesWarning, stacklevel=2)


    def _nested(self, frame_like) -> list[str]:
        """The images in the folder's subfolders, as paths relative to it (a folder with none of its own: a dataset
        laid out in subfolders, as VPR-datasets-downloader's or Pittsburgh's); said in one line. A folder holding both
        ``database`` and ``queries`` is refused: they are two traverses."""
        subs = {p.name for p in self.path.iterdir() if p.is_dir() and not p.name.startswith(".")}
        if {"database", "queries"} <= subs:
            raise ValueError(f"{self.path}: holds database/ and queries/, two traverses: give each "
                             f"({self.path / 'database'} {self.path / 'queries'})")
        found = sorted(str(p.relative_to(self.path)) for p in self.path.rglob("*")
                       if p.suffix.lower() in frame_like and not any(part.startswith(".") for part in
                                                                       p.relative_to(self.path).parts)
                       and (p.is_file() or p.is_symlink()))
        if found:
            warnings.warn(f"{self.path}: no images of its own; the {len(found)} in its subfolders are read, in the "
                          "natural order of their paths", UserWarning, stacklevel=3)
        return found


class ListSource(_FileListSource):
    """Images named in a text file, one path per line, relative to the list's folder; named as written.

    Blank and ``#`` lines are ignored; a missing or undecodable file is skipped as in a folder. A missing list raises
    FileNotFoundError; one not UTF-8 or naming no images ValueError.
    """

    kind = "list"

    @classmethod
    def accepts(cls, path: Path) -> bool:
        return path.suffix.lower() in LIST_EXTENSIONS

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
        return stat_token(self.path.resolve())
