"""The geometric second opinion's settings, on every stream where geometry can see, the renders at several sizes.

The geometric second opinion (:class:`vpr.verify.GeometricOpinion`) accepts a
closure the path has not reached when the pair has enough two-view inliers. A
fixed count has the units of the camera and the scene, so the rendered forward
drives are rendered at every size of ``--sizes`` (a stream ``NAME@WxH``; the
first size unnamed), the real streams at their own. The grid: ``min_inliers``;
``self_ratio`` (the pair must have that share of the inliers the earlier frame
has with its own neighbour ``self_gap`` frames on: a bar in the stream's own
units); ``distinct`` (only matches distinct within their own image count: a
pattern repeated within a frame, a crossing's stripes, verifies nothing); and
``verified_within`` (the 2 verified frames among the last that many checked);
``keep_inliers`` (the bar of the frames continuing a path geometry accepted);
``rising_inliers`` (the bar where the path score is already above 0).
Printed for each setting: recall and false closures (onto an identical copy
of a rendered stretch counted apart, as they are no error of the detector;
Nordland's 64 x 32 frames are blind); then the setting chosen by a rule
stated here, on all streams and with each stream held out in turn.

The rule: the setting with the fewest false closures over the streams (none,
where one has none), then the largest smallest recall over the revisit
streams, then the largest mean recall, then the more careful: the larger bar,
distinct matches, the shorter window, no tracking (else its larger bar).

Usage: VPR_DATASETS=../shared/datasets python -m research.studies.loop_calibration [--cache DIR]
[--inliers 20,30,40] [--ratios 0,0.5] [--distinct 0,1] [--within 2,3] [--keep 0,10,15]
[--rising 0,20] [--sizes 160x120,320x240,640x480]
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from unittest import mock

import numpy as np

from research.studies import loop_streams
from research.studies.loop_geometry import cell, count, images_of, stream_decisions
from vpr.shosm import LoopConf
from vpr.verify import OpinionConf, Verifier, second_opinion

REVISITS = ("gardens_point", "rtabmap_loop", "loop_revisits/laps")
FORWARD = ("two_seasons/summer_day", "two_seasons/winter_night", "speed_change/slow", "speed_change/fast",
           "aliased_corridor/lights_on")


def far_pairs(name, stream, d, res, verifier, alias, n: int, seed: int = 0) -> None:
    """Print the inliers of ``n`` random pairs of frames far apart (more than 60 frames) against those of the
    closures geometry accepted (true, false; onto a copy counted apart)."""
    rng = np.random.default_rng(seed)
    T = len(stream)
    j = rng.integers(61, T, n)
    i = (rng.random(n) * (j - 60)).astype(int)
    if not stream.forward_only:  # true revisits are not "far pairs that cannot be one place"
        keep = ~stream.soft[i, j]
        i, j = i[keep], j[keep]
    far = np.array([verifier.pair_inliers(int(a), int(b)) for a, b in zip(i, j, strict=True)])
    geo = np.flatnonzero(res.accepted & ~d.accepted)
    inl = np.array([verifier.pair_inliers(int(res.best[g]), int(g)) for g in geo])
    if stream.forward_only:
        copy = alias[res.best[geo], geo] if alias is not None else np.zeros(geo.size, bool)
        true = np.zeros(geo.size, bool)
    else:
        copy = np.zeros(geo.size, bool)
        true = stream.hard[res.best[geo], geo] | stream.soft[res.best[geo], geo]
    q = np.percentile(far, [50, 90, 95, 99]) if far.size else [np.nan] * 4
    print(f"  far pairs of {name}: {far.size}, inliers median {q[0]:.0f}, q90 {q[1]:.0f}, q95 {q[2]:.0f}, "
          f"q99 {q[3]:.0f}, max {far.max() if far.size else 0}; geometry's true {sorted(inl[true].tolist())}, "
          f"false {sorted(inl[~true & ~copy].tolist())}, copy {sorted(inl[copy].tolist())}", flush=True)


def grid_counts(names, grid, cache: Path, data: Path, far: int = 0, min_side: int = 120) -> dict:
    """{(min_inliers, self_ratio, distinct, verified_within, keep_inliers, rising_inliers): {stream: count}} with one
    verifier per
    stream and matching (its features and pairs computed once for every setting)."""
    conf = LoopConf()
    out: dict = {}
    for name in names:
        t = time.perf_counter()
        stream, alias, d = stream_decisions(name, cache, data, conf)
        image = images_of(stream)
        def one_verifier(a, b, shared={}, **kw):  # noqa: B006 - one verifier per stream and matching, by design
            if kw["distinct"] not in shared:
                shared[kw["distinct"]] = Verifier(a, b, **kw)
            return shared[kw["distinct"]]

        with mock.patch("vpr.verify.opinion.Verifier", one_verifier):
            for k, r, u, w, keep, rise in grid:
                res, _ = second_opinion(d, image, stream.x, conf.back, conf.ahead, conf.stop_ratio,
                                        OpinionConf(min_inliers=k, self_ratio=r, distinct=u, verified_within=w,
                                                    keep_inliers=keep, rising_inliers=rise, min_side=min_side),
                                        accept_score=conf.min_score)
                out.setdefault((k, r, u, w, keep, rise), {})[name] = count(stream, res.best, res.accepted, alias)
                if (k, r, u, w, keep, rise) == grid[0] and far:
                    far_pairs(name, stream, d, res, one_verifier.__defaults__[0][u], alias, far)
        print(f"  ({name}: {len(stream)} frames, {time.perf_counter() - t:.0f} s)", flush=True)
    return out


def setting(s: tuple) -> str:
    """A grid setting as the tables name it."""
    return (f"min_inliers {s[0]}, self_ratio {s[1]:g}, distinct {'yes' if s[2] else 'no'}, within {s[3]}, "
            f"keep_inliers {s[4]}, rising_inliers {s[5]}")


def choose(counts: dict, names) -> tuple:
    """The setting of the rule (module docstring) on the streams ``names``."""
    revisits = [n for n in names if n.split("@")[0] in REVISITS]

    def key(s):
        c = counts[s]
        false = sum(c[n]["false"] for n in names)
        rec = [c[n]["recall"] for n in revisits] or [0.0]
        # no false closure first (else the fewest), then the smallest recall, the mean recall, the more careful:
        # the larger bar, distinct matches, the shorter window, no tracking (else its larger bar)
        careful = s[0] + 100 * s[1] + 1000 * s[2] - 0.1 * s[3] + 0.01 * (s[4] or 1000) + 0.001 * (s[5] or 1000)
        return (-false, min(rec), sum(rec) / len(rec), careful)

    return max(counts, key=key)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", default="results/loop_streams")
    ap.add_argument("--data", default=None)
    ap.add_argument("--inliers", default="20,30,40")
    ap.add_argument("--ratios", default="0")
    ap.add_argument("--distinct", default="0,1", help="0: every match; 1: only matches distinct in their own image")
    ap.add_argument("--within", default="2,3", help="verified_within: the 2 verified frames among the last this many")
    ap.add_argument("--keep", default="0,10,15", help="keep_inliers: the bar of the frames continuing an accepted path")
    ap.add_argument("--rising", default="0", help="rising_inliers: the bar where the path score is above 0 (0: none)")
    ap.add_argument("--streams", default=",".join((*REVISITS, *FORWARD)))
    ap.add_argument("--far", type=int, default=0, help="also print the inliers of this many random far pairs")
    ap.add_argument("--sizes", default="160x120,320x240,640x480",
                    help="the sizes rendered streams are rendered at (each a stream of its own)")
    ap.add_argument("--min-side", type=int, default=OpinionConf().min_side, help="frames smaller are blind")
    a = ap.parse_args(argv)
    cache = Path(a.cache)
    cache.mkdir(parents=True, exist_ok=True)
    data = Path(a.data or os.environ.get("VPR_DATASETS", "../shared/datasets"))
    grid = [(int(k), float(r), bool(int(u)), int(w), int(keep), int(rise)) for u in a.distinct.split(",")
            for w in a.within.split(",") for k in a.inliers.split(",") for r in a.ratios.split(",")
            for keep in a.keep.split(",") for rise in a.rising.split(",")]
    counts, names = {}, []
    for k, size in enumerate(a.sizes.lower().split(",")):
        loop_streams.RENDER_SIZE = tuple(int(v) for v in size.split("x"))
        these = [n for n in a.streams.split(",") if k == 0 or n in FORWARD]  # the real streams have one size
        at = grid_counts(these, grid, cache if k == 0 else cache.with_name(f"{cache.name}_{size}"), data, a.far,
                         a.min_side)
        tag = "" if k == 0 else f"@{size}"
        for setting_, c in at.items():
            counts.setdefault(setting_, {}).update({n + tag: v for n, v in c.items()})
        names += [n + tag for n in these]
    print("\n| distinct | within | min_inliers | self_ratio | keep_inliers | rising_inliers | " + " | ".join(names)
          + " |")
    print("|---|---:|---:|---:|---:|---:|" + "---|" * len(names))
    for k, r, u, w, keep, rise in grid:
        print(f"| {'yes' if u else 'no'} | {w} | {k} | {r:g} | {keep} | {rise} | "
              + " | ".join(cell(counts[(k, r, u, w, keep, rise)][n]) for n in names) + " |")
    best = choose(counts, names)
    print(f"\nchosen on every stream: {setting(best)}")
    print("\n| held out | chosen on the others | held-out stream with it |")
    print("|---|---|---|")
    for held in names:
        s = choose(counts, [n for n in names if n != held])
        print(f"| {held} | {setting(s)} | {cell(counts[s][held])} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
