"""Frames one at a time, as a robot gets them: from stdin or a source, with their latency and a JSON line each.

Shared by the online commands (``vpr localize``, ``vpr loops -``).
"""
from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np

from vpr.sources import decode_image

__all__ = ["stdin_frames", "source_frames", "latency_summary", "JsonLines"]


def stdin_frames(stream):
    """(index, name, image, reason) of the image paths read from ``stream`` as they arrive.

    Unreadable images come with ``image`` None and the reason; blank lines
    and ``#`` comments are skipped.
    """
    index = 0
    for line in stream:
        name = line.strip()
        if not name or name.startswith("#"):
            continue
        img, reason = decode_image(Path(name))
        if img is None:
            yield index, name, None, reason
        else:
            yield index, name, img, ""
        index += 1


def source_frames(src):
    """(index, name, image, reason) of a source's frames; its skipped frames last, with index -1."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # skipped frames are reported in metrics.json
        for f in src:
            yield f.index, f.name, f.image, ""
    for name, reason in src.skipped:
        yield -1, name, None, reason


def latency_summary(ms) -> dict:
    """Median, 95th percentile and maximum of latencies (None without any)."""
    ms = np.asarray(ms, np.float64)
    if not ms.size:
        return {"median": None, "p95": None, "max": None}
    return {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)), "max": float(ms.max())}


class JsonLines:
    """One flushed JSON line per frame; a reader that goes away (``| head``) stops the lines, not the run."""

    def __init__(self, stream):
        self.stream = stream
        self.open = True

    def write(self, obj: dict) -> None:
        if not self.open:
            return
        try:
            self.stream.write(json.dumps(obj) + "\n")
            self.stream.flush()
        except BrokenPipeError:  # keep going for the files
            self.open = False
