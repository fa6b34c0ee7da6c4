"""A fleet of query traverses against one map on Dask: 1 against 2 workers, and what is shipped.

Writes (once, into ``--data``) a 10,000-frame map folder and 8 query folders of
2,000 frames each, as ``make_large_folders.py`` does: smooth random 64 x 32
grey appearances, each reused at about ten places; a query drives a stretch of
the route again, darker, shifted by up to two pixels, with pixel noise. Then
runs ``pipelines.runs.run_fleet`` (what ``vpr match MAP Q1 ... Q8`` runs) with
the ``fast`` preset's encoder and ``rshosm-seq`` and ``pairwise``, on an
embedded local cluster of 1 and of 2 workers, and prints the wall time of each,
their ratio, the bytes of the map (sent to the cluster once) and of the largest
query task, and whether both runs answered the same.

Usage: python research/benchmarks/bench_fleet.py [--data DIR] [--map 10000] [--queries 8] [--frames 2000]
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

METHODS = ["rshosm-seq", "pairwise"]


def write_folders(out: Path, n_map: int, n_queries: int, n_frames: int, seed: int = 0) -> tuple[Path, list[Path]]:
    """The map folder and the query folders (written once; reused when complete)."""
    done = out / "done.json"
    want = {"map": n_map, "queries": n_queries, "frames": n_frames, "seed": seed}
    if done.is_file() and json.loads(done.read_text()) == want:
        return out / "map", [out / f"q{k}" for k in range(n_queries)]
    from make_large_folders import route_appearances

    rng = np.random.default_rng(seed)
    looks, place_look = route_appearances(n_map, rng)
    (out / "map").mkdir(parents=True, exist_ok=True)
    for i in range(n_map):
        cv2.imwrite(str(out / "map" / f"{i:06d}.png"), looks[place_look[i], 2:34, 2:66].astype(np.uint8))
    for k in range(n_queries):
        folder = out / f"q{k}"
        folder.mkdir(parents=True, exist_ok=True)
        start = int(rng.integers(0, n_map - n_frames))
        for j in range(n_frames):
            dx, dy = rng.integers(0, 5, 2)
            img = looks[place_look[start + j], dy:dy + 32, dx:dx + 64] * 0.7 + rng.normal(0, 6, (32, 64))
            cv2.imwrite(str(folder / f"{j:06d}.png"), np.clip(img, 0, 255).astype(np.uint8))
    done.write_text(json.dumps(want))
    return out / "map", [out / f"q{k}" for k in range(n_queries)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(Path(tempfile.gettempdir()) / "vpr_bench_fleet"))
    ap.add_argument("--map", type=int, default=10_000)
    ap.add_argument("--queries", type=int, default=8)
    ap.add_argument("--frames", type=int, default=2_000)
    a = ap.parse_args(argv)
    from pipelines.runs import RunOptions, run_fleet
    from vpr import presets

    t = time.perf_counter()
    db, queries = write_folders(Path(a.data), a.map, a.queries, a.frames)
    print(f"folders: map {a.map:,} frames, {a.queries} queries x {a.frames:,} frames in {a.data} "
          f"({time.perf_counter() - t:.0f} s)", flush=True)
    s = presets.resolve("fast")
    runs = {}
    with tempfile.TemporaryDirectory() as tmp:
        for workers in (1, 2):
            opts = RunOptions(out=Path(tmp) / f"w{workers}", methods=tuple(METHODS),
                              encoder=s["encoder"], encoder_conf=s["encoder_conf"],
                              preset="fast", progress=False, workers=workers)
            t = time.perf_counter()
            summary = run_fleet(db, queries, opts)
            runs[workers] = (time.perf_counter() - t, summary)
            print(f"{workers} worker(s): {runs[workers][0]:.0f} s wall (map built in "
                  f"{summary['params']['map_seconds']:.0f} s)", flush=True)
        same = all((Path(tmp) / "w1" / q.name / m / "matches.csv").read_text()
                   == (Path(tmp) / "w2" / q.name / m / "matches.csv").read_text() for q in queries for m in METHODS)
    shipped = runs[2][1]["params"]["shipped"]
    print(f"\n| workers | wall s | ratio to 1 worker |\n|---|---|---|\n| 1 | {runs[1][0]:.0f} | 1.00 |\n"
          f"| 2 | {runs[2][0]:.0f} | {runs[2][0] / runs[1][0]:.2f} |")
    print(f"\nmap sent to the cluster once: {shipped['map_bytes'] / 2**20:.1f} MB; largest query task: "
          f"{shipped['task_bytes'] / 2**10:.1f} kB; the same answers with 1 and 2 workers: {same}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
