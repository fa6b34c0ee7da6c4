"""``DIR/report.html`` (:func:`vpr.report.write`) with the frames of the run's sources, found by name."""
from __future__ import annotations

import warnings
from pathlib import Path

from vpr import report
from vpr.sources import decode_image, images_at

__all__ = ["write_report"]


def _frames(srcs):
    """``read(names) -> {name: image}``: frames of the sources by name (``SESSION/NAME`` too), or image paths."""
    where, paths = {}, {}
    for src in srcs:
        if not src.has_images:  # descriptor files: their images beside them where there are, else names alone
            for n, f in zip(src.names(), src.frame_paths() or [], strict=False):
                paths.setdefault(n, f)
                paths.setdefault(f"{src.name}/{n}", f)
            continue
        try:
            names = src.names()
        except ValueError:  # paths on stdin: read by their paths
            continue
        for pos, n in enumerate(names):
            where.setdefault(n, (src, pos))
            where.setdefault(f"{src.name}/{n}", (src, pos))

    def read(names) -> dict:
        out, wanted = {}, {}
        for n in set(names):
            if n in paths:
                out[n] = decode_image(paths[n])[0]
            elif n in where:
                wanted.setdefault(id(where[n][0]), []).append(n)
            elif n and Path(n).is_file():  # paths on stdin
                out[n] = decode_image(Path(n))[0]
        for group in wanted.values():  # each source read once through its frames, in order
            src = where[group[0]][0]
            images = images_at(src, [where[n][1] for n in group])
            out.update({n: images[where[n][1]] for n in group})
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
