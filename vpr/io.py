"""Atomic output helpers: write to a temporary file beside the target, then rename.

A crash mid-write therefore never leaves a half-written result under the final name.
"""
from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["atomic_path", "atomic_open", "save_npy", "save_json", "save_figure", "save_image"]


@contextlib.contextmanager
def atomic_path(path, suffix: str | None = None):
    """Yield a temporary path in the target's folder; rename it to ``path`` on success.

    ``suffix`` defaults to the target's suffix so that libraries which pick a
    format from the file name (matplotlib, OpenCV, NumPy) still work.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix if suffix is not None else path.suffix,
                               dir=path.parent)
    os.close(fd)
    # mkstemp creates 0600; results should get the permissions of an ordinary new file
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def atomic_open(path, mode: str = "w", **kwargs):
    """Like :func:`open` for writing, but atomic."""
    with atomic_path(path) as tmp:
        with open(tmp, mode, **kwargs) as fh:
            yield fh


def save_npy(path, array) -> Path:
    """Atomically save one array as ``.npy``."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.save(fh, np.asarray(array))
    return Path(path)


def save_json(path, obj, indent: int = 2) -> Path:
    """Atomically write ``obj`` as JSON (NumPy scalars and arrays are converted)."""

    def default(o):
        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, Path):
            return str(o)
        raise TypeError(f"not JSON serialisable: {type(o).__name__}")

    with atomic_open(path, "w", encoding="utf-8") as fh:
        json.dump(obj, fh, indent=indent, default=default)
        fh.write("\n")
    return Path(path)


def save_figure(fig, path, **kwargs) -> Path:
    """Atomically save a matplotlib figure (format from the suffix)."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, **kwargs)
    return Path(path)


def save_image(path, img) -> Path:
    """Atomically write an image with OpenCV (format from the suffix)."""
    import cv2

    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), img):
            raise OSError(f"{path}: OpenCV could not encode the image")
    return Path(path)
