"""A late frame accepted on its path ahead, and not just after a query stand: each taken out.

``vpr localize`` answers each frame ``rshosm-seq.lag`` frames late. A frame is accepted where the path rule accepts
its path, at its own frame or on one of the frames waiting after it (:meth:`vpr.shosm.PathDecider.accepted_ahead`),
except within the evidence's memory (``1 / (1 - decay)`` frames) after a query frame that did not move and on which
no path was accepted. This study runs ``vpr localize`` (defaults, the decision benchmark's maps and ground truth)
three ways: the defaults; the stand's exception taken out (frames just after such a stand accepted ahead too); the
acceptance ahead taken out (each frame on its own path score). Rows: the decision benchmark's database -> query
rows, and cases the exception was not chosen on: the queries of Nordland every 10th file and of Gardens Point with
a stop inserted (one frame repeated 40 times) at the start, before any path, and in the middle; and the case it was
chosen on (Nordland's first files: the map's first 17 frames black, both trains standing) rebuilt on those streams:
17 black frames before the map, the query's first frame repeated 17 times.

Each cell: accepted, P(acc), R(acc). The runs are kept under ``--out``; the defaults' runs are read from the
benchmark's ``--runs`` where they are there.

Usage: VPR_DATASETS=../shared/datasets python -m research.studies.stand_ahead --runs results/decisions
    [--out results/stand_ahead]
"""
from __future__ import annotations

import argparse
import contextlib
from pathlib import Path
from unittest import mock

from research.studies.cells import decisions_cell
from research.studies.decisions import Streams, data_root, learned_map, match_pairs, run
from vpr.shosm import Lagged, PathDecider

#: (name, the patch that takes a mechanism out, or None)
VARIANTS = (
    ("defaults", None),
    ("accepted ahead just after a stand too", "stand"),
    ("on its own path score only", "ahead"),
)


def _taken_out(what: str | None):
    if what == "stand":  # every frame counts as settled after a stand
        init = Lagged.__init__

        def settled(self, *a, **k):
            init(self, *a, **k)
            self.memory_frames = 0
        return mock.patch.object(Lagged, "__init__", settled)
    if what == "ahead":
        return mock.patch.object(PathDecider, "accepted_ahead", lambda self, columns: False)
    return contextlib.nullcontext()


def stop_pairs(s: Streams):
    """(name, database, query, radius, soft) of the queries with a stop of 40 frames inserted."""
    s10 = s.nl("s10", s.summer[::10], 10)
    w10 = s.winter[::10]
    yield "Nordland every 10th, a stop at the start", s10, s.nl("w10_stop0", [w10[0]] * 40 + w10, 10), 1, 3
    yield ("Nordland every 10th, a stop at 150", s10, s.nl("w10_stop150", w10[:150] + [w10[150]] * 40 + w10[150:], 10),
           1, 3)
    left, right = s.gp("left", s.left), s.right
    yield "Gardens Point, a stop at the start", left, s.gp("right_stop0", [right[0]] * 40 + right), 2, 8
    yield ("Gardens Point, a stop at 100", left, s.gp("right_stop100", right[:100] + [right[100]] * 40 + right[100:]),
           2, 8)


def _black(s: Streams, like: Path) -> Path:
    """A black image of ``like``'s size and format (a camera's first frames before it shows anything)."""
    from PIL import Image
    out = s.root / f"black-{like.stem}{like.suffix}"
    if not out.exists():
        s.root.mkdir(parents=True, exist_ok=True)
        with Image.open(like) as im:
            Image.new(im.mode, im.size).save(out)
    return out


def dark_start_pairs(s: Streams):
    """(name, database, query, radius, soft): the map starting with 17 black frames where the query stands 17
    frames (its first frame repeated), as the benchmark's first Nordland files (the case the exception is for)."""
    w10, left, right = s.winter[::10], s.left, s.right
    s10 = [_black(s, s.summer[0])] * 17 + s.summer[::10]
    def at(number):  # a black frame at the route's start
        return lambda f: 0.0 if f.stem.startswith("black") else number(f)

    yield ("Nordland every 10th, the map's start black, a stop at the start",
           s.folder("s10_dark", s10, at(lambda f: int(f.stem.split("-")[-1]) / 100)),
           s.nl("w10_stop17", [w10[0]] * 17 + w10, 10), 1, 3)
    yield ("Gardens Point, the map's start black, a stop at the start",
           s.folder("left_dark", [_black(s, left[0])] * 17 + left, at(lambda f: int(f.stem.removeprefix("Image")))),
           s.gp("right_stop17", [right[0]] * 17 + right), 2, 8)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=Path, required=True, help="the decision benchmark's --out (its maps and streams)")
    ap.add_argument("--out", type=Path, default=Path("results/stand_ahead"))
    a = ap.parse_args(argv)
    s = Streams(data_root(), a.runs)
    print("| query | " + " | ".join(v for v, _ in VARIANTS) + " |")
    print("|---" * (len(VARIANTS) + 1) + "|")
    pairs = [*(p for p in match_pairs(s) if "reversed" not in p[0]), *stop_pairs(s), *dark_start_pairs(s)]
    for name, (db, p_db), (q, p_q), radius, soft in pairs:
        key = f"{db.name}-{q.name}"
        cells = []
        for _, what in VARIANTS:
            kept = a.runs / "localize" / key
            out = kept if what is None and (kept / "metrics.json").exists() else a.out / (what or "defaults") / key
            with _taken_out(what):
                m, _ = run(["localize", learned_map(db, p_db, a.runs), q, "--gt", p_q, "--radius", radius,
                            "--gt-soft", soft], out)
            cells.append(decisions_cell(m["rshosm-seq"], frames=False))
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
