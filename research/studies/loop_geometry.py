"""The geometric second opinion of ``vpr loops`` (:class:`vpr.verify.GeometricOpinion`), on every loop stream.

For each stream of ``research.studies.loop_streams`` (and RTAB-Map's 84-frame indoor
loop, read with its own loop matrix), rSHOSM-seq decides with its defaults
(:class:`vpr.shosm.LoopConf`, the path score), then the second opinion
accepts too what geometry confirms: a frame whose best earlier frame moves on
consistently for ``frames`` frames and has at least ``min_inliers`` two-view
inliers with it, unless the camera never left (the stop check). Printed per
stream: closures accepted by the path and by geometry, true and false (onto an
identical copy of a rendered stretch counted apart), recall, the frames
verified and blind, and the milliseconds per verified frame; then the same
for every ``min_inliers`` of a small grid, so that the threshold's choice is
seen on every stream (forward drives must stay at 0 false).

Usage: python -m research.studies.loop_geometry [--cache DIR] [--data DIR] [--inliers 15,20,25,30]
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import cv2
import numpy as np

from research.studies.loop_decisions import aliases, evidence
from research.studies.loop_streams import FORWARD, REAL_REVISITS, RENDERED_REVISITS, Stream, encoder_for, load_stream
from vpr.groundtruth.formats import loop_matrix
from vpr.shosm import LoopConf, accept_loops, loop_evidence
from vpr.verify import OpinionConf, Verifier, second_opinion

EXCLUDE = 30
STREAMS = (*REAL_REVISITS, "rtabmap_loop", *RENDERED_REVISITS, *FORWARD)


def rtabmap_stream(data: Path, cache: Path):
    root = data / "rtabmap_loop"
    frames = [str(p) for p in sorted((root / "images").glob("*.jpg"))]
    enc = encoder_for("default")
    x = enc.encode([cv2.imread(f) for f in frames])
    g = loop_matrix(root / "loop_gt.bmp", list(range(len(frames))))
    hard = np.triu(g, 1)
    stream = Stream("rtabmap_loop", x, hard, hard.copy(), frames)
    return stream, loop_evidence(stream.x, exclude=EXCLUDE)


def images_of(stream: Stream):
    """``image(j)`` at the source's resolution (rendered streams are rendered again)."""
    if stream.frames is not None:
        return lambda j: cv2.imread(stream.frames[j])
    from research.studies import loop_streams
    from vpr.render import render_scene

    scene, traverse = stream.name.split("/")
    imgs = render_scene(scene, size=loop_streams.RENDER_SIZE, traverses=[traverse]).traverses[0].images
    return lambda j: imgs[j]


def count(stream: Stream, best, accepted, alias) -> dict:
    j = np.flatnonzero(accepted)
    b = best[j]
    if stream.forward_only:
        on_copy = alias[b, j] if alias is not None else np.zeros(j.size, bool)
        return {"true": 0, "false": int((~on_copy).sum()), "copy": int(on_copy.sum()), "recall": None}
    true = stream.hard[b, j]
    soft = stream.soft[b, j] & ~true
    frames = int(np.triu(stream.hard, EXCLUDE).any(axis=0).sum())
    return {"true": int(true.sum()), "false": int((~true & ~soft).sum()), "copy": 0,
            "recall": true.sum() / max(frames, 1)}


def why_not(stream: Stream, out, image, conf: OpinionConf) -> dict:
    """The revisit frames of ``stream`` by what became of them under the defaults' decisions ``out``: accepted, their
    best earlier frame wrong, blind, fewer than ``min_inliers`` inliers, or the rest (the verified run, the path's
    consistency, the camera never out of sight)."""
    v = Verifier(image, image, n_features=conf.n_features, max_error=conf.max_error, min_side=1,
                 distinct=conf.distinct)
    reasons: dict = {}
    for j in np.flatnonzero(np.triu(stream.hard, EXCLUDE).any(axis=0)):
        b = int(out.best[j])
        if out.accepted[j]:
            why = "accepted"
        elif b < 0 or not stream.hard[b, j]:
            why = "best frame wrong"
        elif min(image(j).shape[:2]) < conf.min_side or \
                min(len(v.query_features(j)), len(v.db_features(b))) < conf.min_keypoints:
            why = "blind"
        elif v.pair_inliers(b, j) < conf.min_inliers:
            why = f"fewer than {conf.min_inliers} inliers"
        else:
            why = "the run, the path or the view"
        reasons[why] = reasons.get(why, 0) + 1
    return reasons


def stream_decisions(name: str, cache: Path, data: Path, conf: LoopConf):
    """(stream, the copies' mask or None, the path rule's decisions) of the loop stream ``name``."""
    if name == "rtabmap_loop":
        stream, ev = rtabmap_stream(data, cache)
    else:
        stream = load_stream(name, preset="default", cache=cache, data=data)
        ev = evidence(stream, cache, "default")
    alias = aliases(name) if not stream.forward_only or "/" in name else None
    return stream, alias, accept_loops(ev, conf, sdr=stream.x)


def cell(c: dict) -> str:
    """A stream's count as a table cell: recall and false closures (onto a copy counted apart)."""
    out = f"{c['false']} false" + (f" (+{c['copy']} copy)" if c["copy"] else "")
    return out if c["recall"] is None else f"{c['recall']:.2f}, {out}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", default="results/loop_streams")
    ap.add_argument("--data", default=None)
    ap.add_argument("--inliers", default="15,20,25,30,40")
    ap.add_argument("--streams", default=",".join(STREAMS))
    a = ap.parse_args(argv)
    cache = Path(a.cache)
    cache.mkdir(parents=True, exist_ok=True)
    data = Path(a.data or os.environ.get("VPR_DATASETS", "../shared/datasets"))
    conf = LoopConf()
    grid = [int(v) for v in a.inliers.split(",")]
    rows = []
    print("| stream | frames | path: recall, false | + geometry: recall, false | by geometry | verified | blind | "
          "ms / verified frame |")
    print("|---|---|---|---|---|---|---|---|")
    per_grid = {}
    for name in a.streams.split(","):
        t = time.perf_counter()
        stream, alias, d = stream_decisions(name, cache, data, conf)
        image = images_of(stream)
        path_c = count(stream, d.best, d.accepted, alias)
        for k in grid:
            out, rep = second_opinion(d, image, stream.x, conf.back, conf.ahead, conf.stop_ratio,
                                      OpinionConf(min_inliers=k))
            per_grid.setdefault(k, {})[name] = count(stream, out.best, out.accepted, alias)
            if k == OpinionConf().min_inliers:
                both = per_grid[k][name]
                rows.append((name, len(stream), path_c, both, rep))
                print(f"| {name} | {len(stream):,} | {cell(path_c)} | {cell(both)} | {rep['accepted_by_geometry']} | "
                      f"{rep['frames_verified']} | {rep['frames_blind']} | {rep['ms_per_verified_frame']} |",
                      flush=True)
                if not stream.forward_only and rep["frames_verified"]:
                    reasons = why_not(stream, out, image, OpinionConf())
                    print(f"  ({name}'s revisit frames: " + ", ".join(f"{k} {n}" for k, n in reasons.items()) + ")")
        print(f"  ({name}: {time.perf_counter() - t:.0f} s)", flush=True)
    print("\nEvery min_inliers (recall, false closures; + copy: onto an identical copy of a rendered stretch):\n")
    names = [r[0] for r in rows]
    print("| min_inliers | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for k in grid:
        print(f"| {k} | " + " | ".join(cell(per_grid[k][n]) for n in names) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
