"""Frame sources: image folders, video files, text files listing images, ROS bags, and image paths on stdin."""
from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from vpr.checks import per_input

from .bag import BagSource, is_bag
from .base import (
    IMAGE_EXTENSIONS,
    LIST_EXTENSIONS,
    VIDEO_EXTENSIONS,
    Frame,
    FrameSkippedWarning,
    IgnoredFilesWarning,
    Source,
    check_positive_int,
    decode_image,
    natural_key,
)
from .descriptors import (
    DESCRIPTOR_EXTENSIONS,
    DescriptorSource,
    is_descriptor_file,
    names_carry_order,
    read_descriptors,
)
from .files import FolderSource, ListSource
from .stdin import StdinSource
from .video import VideoSource

__all__ = ["Frame", "FrameSkippedWarning", "IgnoredFilesWarning", "Source", "FolderSource", "ListSource", "VideoSource",
           "BagSource", "StdinSource", "KINDS", "is_bag", "DescriptorSource", "read_descriptors",
           "is_descriptor_file", "names_carry_order", "DESCRIPTOR_EXTENSIONS",
           "IMAGE_EXTENSIONS", "VIDEO_EXTENSIONS", "LIST_EXTENSIONS", "natural_key", "decode_image", "open_source",
           "open_sources", "check_ordered", "load_all", "iter_batches", "frame_reader", "images_at"]


#: The kinds of source, asked in this order whether a path is theirs (:meth:`Source.accepts`).
KINDS = (BagSource, FolderSource, VideoSource, ListSource, DescriptorSource)

_WHERE = {"fps": "videos and bags (use --step for images)", "topic": "ROS bags (.bag, .mcap, .db3, a ROS 2 bag folder)",
          "prefix": "an hloc .h5 of global features (its frames whose names begin with it)"}


def open_source(path, fps=None, step=None, max_frames=None, topic: str | None = None, prefix: str | None = None,
                prefix_flag: str = "--prefix") -> Source:
    """Open a folder, video, image-list file (.txt .lst), ROS bag or descriptor file (.npy .h5) as a :class:`Source`
    (the first of :data:`KINDS`).

    ``fps``: videos and bags resampled by timestamps; ``step``: every ``step``-th frame; ``max_frames``: frames
    attempted; ``topic``: a bag's camera topic (default its only image topic); ``prefix``: an ``.h5``'s frames whose
    names begin with it (hloc's ``db_prefix`` / ``query_prefix``; ``prefix_flag`` names it in a refusal). A missing
    path raises FileNotFoundError; an unknown kind, an option the kind does not take or a source that cannot be read
    ValueError.
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"no such file or folder: {p}")
    given = {k: v for k, v in (("fps", fps), ("step", step), ("max_frames", max_frames), ("topic", topic),
                               ("prefix", prefix)) if v is not None}
    for kind in KINDS:
        if kind.accepts(p):
            for option in sorted(set(given) - kind.options):
                flag = prefix_flag if option == "prefix" else f"--{option.replace('_', '-')}"
                raise ValueError(f"{p}: {flag} applies to {_WHERE[option]}, not to a {kind.kind}")
            if kind is DescriptorSource and "prefix" in given and p.suffix.lower() == ".npy":
                raise ValueError(f"{p}: {prefix_flag} applies to {_WHERE['prefix']}, not to a .npy")
            return kind(p, **given)
    raise ValueError(
        f"{p}: unknown source kind {p.suffix.lower() or '(no extension)'!r}; expected a folder of images, a video "
        f"({' '.join(sorted(VIDEO_EXTENSIONS))}), an image list ({' '.join(sorted(LIST_EXTENSIONS))}), a ROS bag "
        f"(.bag .mcap .db3, or a folder with metadata.yaml) or descriptors ({' '.join(DESCRIPTOR_EXTENSIONS)})")


def check_ordered(srcs, roles, methods) -> None:
    """Refuse, before a frame is read, a source whose frames come in no known order (a descriptor file that keeps
    none, its names carrying none: :attr:`DescriptorSource.order` None) where ``methods`` (names) read the frames as
    a sequence."""
    if not methods:
        return
    for src, role in zip(srcs, roles, strict=True):
        if isinstance(src, DescriptorSource) and src.order is None:
            raise ValueError(f"{role} {src.path}: its frame names carry no order (such as {src.all_names[0]!r}) and "
                             f"the file keeps none, but {', '.join(methods)} read{'s' if len(methods) == 1 else ''} "
                             "the frames as a sequence: write the .h5 with track_order=True in the frames' order, or "
                             "a .npy of rows in order; --methods pairwise compares single frames")


def _identity(src: Source) -> tuple:
    return (src.path.resolve(), getattr(src, "topic", None), getattr(src, "prefix", None))


def fingerprint(path) -> str:
    """What a recording holds, cheaply: its files' relative names and sizes, and the first and last MiB of its
    first and last file (a byte-identical copy under another name has the same; another recording does not)."""
    import hashlib

    root = Path(path)
    files = [root] if root.is_file() else sorted(p for p in root.rglob("*") if p.is_file())
    h = hashlib.sha256()
    for f in files:
        h.update(f"{f.relative_to(root) if f != root else ''}\0{f.stat().st_size}\0".encode("utf-8",
                                                                                         "surrogateescape"))
    for f in dict.fromkeys((files[0], files[-1])) if files else ():
        with open(f, "rb") as fh:
            h.update(fh.read(1 << 20))
            fh.seek(max(f.stat().st_size - (1 << 20), 0))
            h.update(fh.read(1 << 20))
    return h.hexdigest()


def open_sources(paths, topic=None, distinct: bool = True, prefix=None, prefix_flags=None,
                 **options) -> list[Source]:
    """:func:`open_source` of each of ``paths``, with a ``topic`` each (:func:`per_input`) and a ``prefix`` each (a
    sequence of one per input, None: none; ``prefix_flags``: the options that gave them), named apart.

    Two inputs that are the same source (the same file or folder, the same topic) are refused with ``distinct``
    (sessions of one robot, a map's sessions: a traverse learned twice closes perfect loops onto its own copy); else
    warned. Inputs whose names coincide (``run1/img``, ``run2/img``) are named by as much of their path as tells them
    apart (``run1/img``), so that outputs, tables and a ``traverse,frame,x,y`` file never mix them up.
    """
    import warnings

    paths = list(paths)
    prefixes = list(prefix) if prefix is not None else [None] * len(paths)
    flags = list(prefix_flags) if prefix_flags is not None else ["--prefix"] * len(paths)
    srcs = [open_source(p, topic=t, prefix=x, prefix_flag=f, **options)
            for p, t, x, f in zip(paths, per_input(topic, len(paths), "--topic"), prefixes, flags, strict=True)]
    seen: dict[tuple, int] = {}
    content: dict[tuple, int] = {}
    for k, src in enumerate(srcs):
        first = seen.setdefault(_identity(src), k)
        msg = None
        if first != k:
            msg = (f"{src.path} is given twice (inputs {first + 1} and {k + 1})"
                   + (f", topic {src.topic}" if getattr(src, "topic", None) else ""))
        elif len(srcs) > 1 and src.path.exists() and getattr(src, "prefix", None) is None:
            first = content.setdefault((fingerprint(src.path), getattr(src, "topic", None)), k)
            if first != k:
                msg = (f"{srcs[first].path} and {src.path} (inputs {first + 1} and {k + 1}) hold the same recording, "
                       "byte for byte")
        if msg is not None:
            if distinct:
                raise ValueError(f"{msg}: the same recording would be matched against itself; give each once")
            warnings.warn(f"{msg}: it is matched against itself (every match is trivially right)", UserWarning,
                          stacklevel=2)
    _name_apart(srcs)
    return srcs


def _name_apart(srcs) -> None:
    by_name: dict[str, list[Source]] = {}
    for src in srcs:
        by_name.setdefault(src.name, []).append(src)
    for same in by_name.values():
        parts = [src.path.resolve().parts for src in same]
        if len(same) < 2 or len(set(parts)) < len(parts):
            continue
        depth = next(d for d in range(1, max(map(len, parts)) + 1) if len({p[-d:] for p in parts}) == len(parts))
        for src, p in zip(same, parts, strict=True):
            src.name = "/".join(p[-depth:])


def load_all(source: Source, progress: bool = True) -> tuple[list[np.ndarray], list[str]]:
    """Every readable frame of ``source``: (uint8 BGR images, names); skipped frames are in ``source.skipped``."""
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
    batch_size = check_positive_int(batch_size, "batch_size")
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


#: How far on a cursor of a sequential source reads rather than seeking again (:func:`frame_reader`,
#: :func:`images_at`).
READ_ON = 64


class _Cursors:
    """Open reads of one sequential source (at most ``n``), each at the position it reads next: a frame at most
    :data:`READ_ON` ahead of one is read on from it, another starts a read there (the least recently used closed)."""

    def __init__(self, src: Source, n: int = 3):
        self.src, self.n, self.end = src, n, len(src.indices())
        self.open: list[list] = []  # [position read next, frames]; the most recently used last

    def read(self, pos: int, index: int):
        cur = next((c for c in self.open if c[0] <= pos <= c[0] + READ_ON), None)
        if cur is None:
            if len(self.open) == self.n:
                self.open.pop(0)[1].close()
            cur = [pos, self.src.iter_range(pos, self.end)]
            self.open.append(cur)
        else:
            self.open.remove(cur)
            self.open.append(cur)
        for f in cur[1]:
            if f.index == index:
                cur[0] = pos + 1
                return f.image
            if f.index > index:  # left out when read again
                break
        self.open.remove(cur)
        return None

    def close(self) -> None:
        """Close every open read."""
        while self.open:
            self.open.pop()[1].close()


def _read_at(src: Source, cursors: _Cursors | None, pos: int, index: int):
    """Frame ``index`` at position ``pos`` of ``src``, read on by ``cursors`` (a sequential source's) or alone; None
    where it cannot be read."""
    if cursors is not None:
        return cursors.read(pos, index)
    return next((f.image for f in src.iter_range(pos, pos + 1)), None)


def images_at(src: Source, positions) -> dict:
    """``{position: uint8 BGR image or None}``: the frames at these positions of ``src`` (of :meth:`Source.names`),
    None where one cannot be read. A sequential source (a video, a bag) is read on through the positions in order
    (:data:`READ_ON`) instead of opened again for each."""
    indices = src.indices()
    cursors = _Cursors(src) if src.sequential else None
    out = {pos: _read_at(src, cursors, pos, indices[pos]) for pos in sorted({int(p) for p in positions})}
    if cursors is not None:
        cursors.close()
    return out


def frame_reader(srcs, read):
    """``image(j)``: frame ``j`` of the sources' frames ``read`` (each source's frame numbers) one after the other,
    decoded again at the source's resolution (frames that were read once, e.g. for geometric verification). A
    sequential source (a video, a bag) is read on from the frames read last where the frame is a little ahead."""
    where = [(src, i) for src, numbers in zip(srcs, read, strict=True) for i in numbers]
    pos_of = {id(src): {k: p for p, k in enumerate(src.indices())} for src in srcs}
    cursors = {id(src): _Cursors(src) for src in srcs if src.sequential}

    def image(j: int):
        src, index = where[j]
        img = _read_at(src, cursors.get(id(src)), pos_of[id(src)][index], index)
        if img is None:
            raise ValueError(f"{src.path}: frame {index} could not be read again")
        return img

    return image
