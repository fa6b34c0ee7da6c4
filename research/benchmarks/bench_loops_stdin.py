"""Online loop closure at camera rate: ``vpr loops -`` fed N frames, then their N revisits, as image paths on stdin.

The frames are ``make_large_folders.py``'s (64 x 32 grey PNGs; every appearance recurs at about ten places, so single
frames are ambiguous): the database folder's N frames, then the query folder's N frames (the same places, darker,
shifted, noisy), one stream of 2N frames in which frame N + i revisits frame i. ``vpr loops - --preset fast`` decides
it frame by frame, encoding included; its JSON lines give each frame's latency.

Prints, for each run: the median latency per block of frames (ms) and over the last 500, the 99th percentile and the
largest over the whole stream, the process's peak RSS, the closures accepted in the first pass (every one false: no
place is revisited there) and in the revisit (right within ``--tolerance`` frames of the place), and what the run
said on stderr of a revisit before frame N.

    python research/benchmarks/bench_loops_stdin.py --n 5000 [--runs 1] [--data DIR] [--method-conf KEY=VALUE ...]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def folders(root: Path, n: int) -> tuple[Path, Path]:
    """The database and query folders of ``n`` frames each (written once under ``root``)."""
    sys.path.insert(0, str(HERE))
    from make_large_folders import write_folders

    write_folders(root, n)
    return root / "db", root / "query"


def run_once(paths: list[str], out: Path, extra: list[str]) -> dict:
    """``vpr loops -`` over ``paths`` in a child process: its JSON lines, stderr, seconds and peak RSS (MB)."""
    argv = [sys.executable, "-m", "pipelines.cli", "loops", "-", "--out", str(out), "--preset", "fast",
            "--no-progress", *extra]
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t = time.perf_counter()
    with tempfile.TemporaryFile("w+") as err:
        p = subprocess.run(argv, input="\n".join(paths) + "\n", capture_output=False, stdout=subprocess.PIPE,
                           stderr=err, text=True, cwd=HERE.parent.parent, check=False)
        err.seek(0)
        said = err.read()
    seconds = time.perf_counter() - t
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    if p.returncode != 0:
        raise SystemExit(f"vpr loops - failed ({p.returncode}):\n{said[-2000:]}")
    lines = [json.loads(line) for line in p.stdout.splitlines() if line.startswith("{")]
    return {"lines": lines, "stderr": said, "seconds": seconds, "peak_mb": max(peak, before) / 1024}


def summary(r: dict, n: int, tolerance: int, block: int) -> dict:
    lines = sorted(r["lines"], key=lambda d: d["query"])
    lat = np.array([d["latency_ms"] for d in lines])
    frame = np.array([d["query"] for d in lines])
    best = np.array([-1 if d["best_db"] is None else d["best_db"] for d in lines])
    acc = np.array([d["accepted"] for d in lines], bool)
    first, second = frame < n, frame >= n
    right = second & acc & (np.abs(best - (frame - n)) <= tolerance)
    blocks = {f"{a:,}-{min(a + block, 2 * n):,}": float(np.median(lat[(frame >= a) & (frame < a + block)]))
              for a in range(0, 2 * n, block)}
    early = [line for line in r["stderr"].splitlines() if "revisit" in line or "faster" in line]
    return {"frames": int(frame.size), "blocks": blocks, "last_500": float(np.median(lat[-500:])),
            "p99": float(np.percentile(lat, 99)), "max": float(lat.max()), "peak_mb": r["peak_mb"],
            "seconds": r["seconds"], "false_first_pass": int((acc & first).sum()),
            "accepted_revisit": int((acc & second).sum()), "right_revisit": int(right.sum()),
            "wrong_revisit": int((acc & second & ~right).sum()), "said": early}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=5000, help="frames of the first pass (and of the revisit)")
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--data", default=None, help="where the folders are written (default: a folder under /tmp)")
    ap.add_argument("--tolerance", type=int, default=2)
    ap.add_argument("--block", type=int, default=1000)
    ap.add_argument("--method-conf", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--json", default=None, help="also write the summaries here")
    args = ap.parse_args(argv)
    root = Path(args.data or Path(tempfile.gettempdir()) / f"vpr-large-{args.n}")
    db, q = folders(root, args.n)
    paths = [str(db / f"{i:06d}.png") for i in range(args.n)] + [str(q / f"{i:06d}.png") for i in range(args.n)]
    extra = [a for kv in args.method_conf for a in ("--method-conf", f"rshosm-seq.{kv}")]
    results = []
    for k in range(args.runs):
        with tempfile.TemporaryDirectory() as tmp:
            s = summary(run_once(paths, Path(tmp) / "out", extra), args.n, args.tolerance, args.block)
        results.append(s)
        print(f"run {k + 1}: {s['frames']:,} frames in {s['seconds']:.0f} s, peak {s['peak_mb']:,.0f} MB")
        print("  median ms per block: " + ", ".join(f"{b} {v:.1f}" for b, v in s["blocks"].items()))
        print(f"  last 500 median {s['last_500']:.1f} ms, p99 {s['p99']:.1f}, max {s['max']:.0f}")
        print(f"  first pass: {s['false_first_pass']} accepted (all false); revisit: {s['accepted_revisit']} "
              f"accepted, {s['right_revisit']} right, {s['wrong_revisit']} wrong")
        for line in s["said"][:3]:
            print(f"  said: {line[:200]}")
    if len(results) > 1:
        for key in ("last_500", "p99", "peak_mb", "seconds"):
            v = [r[key] for r in results]
            print(f"{key}: min {min(v):.1f} / median {float(np.median(v)):.1f} / max {max(v):.1f}")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    os.environ.setdefault("PYTHONWARNINGS", "ignore")
    main()
