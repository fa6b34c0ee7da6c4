"""A robot's second run over its first: loop closure across sessions decided as localisation against a map.

``vpr loops S1 S2`` learns the sessions one after the other; a frame of S2 is
decided by the loop rule (:class:`vpr.shosm.LoopConf`) over every earlier
frame, and also against the earlier sessions alone as ``vpr localize``
decides against a map (:class:`vpr.shosm.PathConf`): either accepts. Printed
per pair of sessions: the recall of the accepted closures of the second
session's frames and the false ones, with the loop rule alone and with the
localisation between sessions. Pairs: Gardens Point day_left then day_right,
Nordland summer then winter (every 10th file; both from
:mod:`research.studies.loop_streams`), and rendered pairs at 160 x 120 (hard within
5 m, soft 10 m; their worlds' identical copies of a stretch are counted as
false here).

Usage: python -m research.studies.loop_sessions [--cache DIR] [--data DIR]
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from research.studies.loop_streams import encoder_for, load_stream
from vpr.shosm import LoopConf, PathConf, accept_loops, loop_evidence

RENDERED = (("two_seasons", "summer_day", "winter_night"), ("aliased_corridor", "lights_on", "night"),
            ("speed_change", "slow", "fast"))


def rendered(scene: str, a: str, b: str):
    """(SDRs of the two traverses one after the other, hard, soft, first frame of the second)."""
    from vpr.render import render_scene

    sc = render_scene(scene, size=(160, 120), traverses=[a, b])
    enc = encoder_for("default")
    xs = [sp.csr_matrix(enc.encode(list(t.images))) for t in sc.traverses]
    xy = np.concatenate([t.xy for t in sc.traverses])
    d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    trav = np.repeat([0, 1], [x.shape[0] for x in xs])
    upper = np.triu(np.ones(d.shape, bool), 1) & (trav[:, None] != trav[None])
    return sp.vstack(xs).tocsr(), upper & (d <= 5), upper & (d <= 10), xs[0].shape[0]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", default="results/loop_streams")
    ap.add_argument("--data", default=None)
    a = ap.parse_args(argv)
    data = Path(a.data or os.environ.get("VPR_DATASETS", "../shared/datasets"))
    pairs = {}
    for name, first in (("gardens_point", 200), ("nordland_stream", 358)):
        s = load_stream(name, cache=a.cache, data=data)
        pairs[name] = (s.x, s.hard, s.soft, first)
    for scene, t1, t2 in RENDERED:
        pairs[f"{scene}: {t1} + {t2}"] = rendered(scene, t1, t2)
    print("| sessions | frames with a loop | loop rule alone: recall, false | + localisation between sessions |")
    print("|---|---|---|---|")
    for name, (x, hard, soft, first) in pairs.items():
        ev = loop_evidence(x, exclude=30, sessions=[first])
        cells = []
        frames = int(hard[:, first:].any(axis=0).sum())
        for path in (PathConf(min_score=1e9), PathConf()):
            d = accept_loops(ev, LoopConf(), sdr=x, path=path)
            j = np.flatnonzero(d.accepted)
            b = d.best[j]
            true, near = hard[b, j], soft[b, j] & ~hard[b, j]
            cells.append(f"{true.sum() / max(frames, 1):.2f}, {int((~true & ~near).sum())} false")
        print(f"| {name} | {frames} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
