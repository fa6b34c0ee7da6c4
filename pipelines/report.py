"""``DIR/report.html`` (:func:`vpr.report.write`) with the frames of the run's sources, found by name."""
from __future__ import annotations

import warnings
from pathlib import Path

from vpr import report
from vpr.sources import decode_image

__all__ = ["write_report"]


def _frames(srcs):
    """``read(names) -> {name: image}``: frames of the sources by name (``SESSION/NAME`` too), or image paths."""
    where = {}
    for src in srcs:
        try:
            names = src.names()
        except ValueError:  # paths on stdin: read by their paths
            continue
        for pos, n in enumerate(names):
            where.setdefault(n, (src, pos))
            where.setdefault(f"{src.name}/{n}", (src, pos))

    def read(names) -> dict:
        out = {}
        for n in sorted(set(names), key=lambda n: (id(where[n][0]), where[n][1]) if n in where else (0, 0)):
            if n in where:
                src, pos = where[n]
                out[n] = next((f.image for f in src.iter_range(pos, pos + 1)), None)
            elif n and Path(n).is_file():  # paths on stdin
                out[n] = decode_image(Path(n))[0]
        return out

    return read


def write_report(out, db_srcs=(), q_srcs=(), kind: str = "match") -> Path | None:
    """``out/report.html`` of a run into ``out`` whose frames come from ``db_srcs`` and ``q_srcs``.

    The run's results are written before: a page that cannot be made (a file
    of the run removed meanwhile, a source that moved) is said, not an error.
    """
    try:
        return report.write(out, _frames(q_srcs), _frames(db_srcs or q_srcs), kind)
    except (OSError, ValueError, KeyError) as e:
        warnings.warn(f"{Path(out) / 'report.html'} not written: {e}", UserWarning, stacklevel=2)
        return None
