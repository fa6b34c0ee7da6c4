"""Rendering speed of :mod:`vpr.render` on one core.

Renders frames of every traverse of a scene (default ``two_seasons``: a summer
day and a winter night with blur and noise) at 160 x 120 and 640 x 480 and
prints frames per second (min / median / max over repeats) next to the
targets (>= 200 frames/s at 160 x 120, >= 30 frames/s at
640 x 480). The one-off world/texture set-up is timed separately.

Run ``python research/benchmarks/bench_render.py [--scene two_seasons] [--repeats 5]``.
"""
from __future__ import annotations

import os

# one core: pin the process and keep BLAS/OpenCV from spawning threads (before importing them)
for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402

from vpr.render import SceneRenderer, load_spec  # noqa: E402
from vpr.render.scene import apply_overrides  # noqa: E402

TARGETS = {(160, 120): 200.0, (640, 480): 30.0}


def bench(scene: str, size, n_frames: int, repeats: int) -> dict:
    """Frames/s per repeat (all traverses of ``scene``, ``n_frames`` each) and the set-up time."""
    spec = apply_overrides(load_spec(scene), size=size)
    t0 = time.perf_counter()
    r = SceneRenderer(spec)
    plans = [(t, r.plan(t)) for t in spec["traverses"]]
    for t, _ in plans:
        r._atlas(t["conditions"])  # lit textures are built once per condition
    setup = time.perf_counter() - t0
    rates = []
    for _ in range(repeats):
        n, dt = 0, 0.0
        for t, plan in plans:
            gen = r.frames(t, plan)
            next(gen)  # per-traverse banks (noise, rain) are set up on the first frame
            t1 = time.perf_counter()
            for k, _img in enumerate(gen, 1):
                if k >= n_frames:
                    break
            dt += time.perf_counter() - t1
            n += k
        rates.append(n / dt)
    return {"setup_s": setup, "fps": rates}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="two_seasons")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--frames", type=int, default=0, help="frames per traverse and repeat (default: by size)")
    a = ap.parse_args(argv)
    cv2.setNumThreads(1)
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    print(f"scene {a.scene}, one core, {a.repeats} repeats")
    print(f"{'size':>9} {'set-up s':>9} {'fps min':>8} {'median':>8} {'max':>8} {'target':>7}  result")
    ok = True
    for size, target in TARGETS.items():
        n = a.frames or (200 if size[0] <= 320 else 60)
        res = bench(a.scene, size, n, a.repeats)
        f = res["fps"]
        med = statistics.median(f)
        good = med >= target
        ok &= good
        print(f"{size[0]:>4}x{size[1]:<4} {res['setup_s']:>9.2f} {min(f):>8.1f} {med:>8.1f} {max(f):>8.1f} "
              f"{target:>7.0f}  {'ok' if good else 'BELOW TARGET'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
