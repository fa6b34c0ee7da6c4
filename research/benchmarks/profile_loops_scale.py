"""Where the online loop detector's update spends its time on a long stream: a profile of its last frames.

The stream of ``bench_loops_scale.py`` (its second half revisits the first: from there on every frame's closure
waits for its confirmation and is placed), :class:`vpr.LoopDetector` with the defaults, one ``update`` (and
``take_late``) per frame; the frames from ``--from`` on are profiled (cProfile) and timed. Prints their median
latency and the functions that took the most time (``tottime``).

    python research/benchmarks/profile_loops_scale.py [--frames 30000] [--from 28000] [--top 14]
"""
from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import time
from pathlib import Path

import numpy as np


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=30_000)
    ap.add_argument("--from", dest="start", type=int, default=28_000)
    ap.add_argument("--top", type=int, default=14)
    a = ap.parse_args(argv)
    if not 0 <= a.start < a.frames:
        raise SystemExit("--from must be below --frames")
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_loops_scale import stream

    from vpr.shosm import LoopDetector

    x, _, second = stream(a.frames)
    det = LoopDetector()
    det.warm_up()
    prof, lat = cProfile.Profile(), []
    t0 = time.perf_counter()
    for j in range(a.frames):
        bits = x.indices[x.indptr[j]:x.indptr[j + 1]]
        if j == a.start:
            prof.enable()
        t = time.perf_counter()
        det.update(bits)
        det.take_late()
        if j >= a.start:
            lat.append(time.perf_counter() - t)
    prof.disable()
    print(f"{a.frames:,} frames (the revisit from frame {second:,}), {time.perf_counter() - t0:.0f} s; frames "
          f"{a.start:,}-{a.frames - 1:,}: median update {np.median(lat) * 1e3:.2f} ms (profiled)")
    pstats.Stats(prof).sort_stats("tottime").print_stats(a.top)


if __name__ == "__main__":
    main()
