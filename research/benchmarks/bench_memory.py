"""Speed and memory of the rSHOSM memory (`vpr.SequenceMemory`).

Prints microseconds per observation and peak memory for:

1. a random walk over a 2,000-place grid world (40 x 50 places, 2048-bit SDRs with
   40 active bits, 20% noise), T = 200, 10,000 and 100,000 observations, each in a
   fresh process so that peak RSS is per run; per-window (1,000 observations)
   costs show whether the cost per step stays flat as T grows;
2. a route where every observation is a new place: the cost grows with the number
   of minicolumns per input bit; the slope of a linear fit is printed;
3. the speed ratio to the literal set-based reference implementation
   (`tests/reference.py`, the test oracle), measured in the same process.

The paper's Matlab implementation took ~8 ms per observation at T = 200.
Target here: median <= 100 us per observation at every T, peak < 2 GB at T = 100,000.

Times are CPU seconds of the benchmark process (the machine may be shared).

Usage: python research/benchmarks/bench_memory.py [--quick] [--walk-only] (from the repository root)
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time

import numpy as np
from children import child_json  # noqa: E402, I001 (run as a script: its own folder is on the path)

WINDOW = 1000


def _world_walk(T, seed):
    from vpr import simulate

    world = simulate.make_world(40, 50, seed=seed)
    traj = simulate.random_walk(40, 50, T, seed=seed + 1)
    return simulate.observe(world, traj, 0.2, seed=seed + 2)


def _timed_run(mem, obs, window):
    """Run in windows; return seconds per window and per-window observation counts."""
    times, counts = [], []
    for a in range(0, obs.shape[0], window):
        b = min(a + window, obs.shape[0])
        # CPU time of this process: the machine is shared, and waiting for a core is not our cost
        t = time.process_time()
        mem.run(obs[a:b])
        times.append(time.process_time() - t)
        counts.append(b - a)
    return np.array(times), np.array(counts)


def child_random_walk(T, seed):
    from vpr.shosm import SequenceMemory

    SequenceMemory(seed=0).run(_world_walk(50, 99))  # compile / load the kernel outside the timing
    obs = _world_walk(T, seed)
    mem = SequenceMemory(seed=seed)
    times, counts = _timed_run(mem, obs, min(WINDOW, T))
    per_obs = times / counts * 1e6
    arrays = mem.nbytes
    print(json.dumps({
        "T": T, "seed": seed, "total_s": float(times.sum()), "mean_us": float(times.sum() / T * 1e6),
        "window_us": per_obs.tolist(), "columns": mem.n_columns, "connections": mem.n_connections,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "arrays_mb": arrays / 2**20,
    }))


def child_new_places(T, seed):
    from vpr import sdr
    from vpr.shosm import SequenceMemory

    SequenceMemory(seed=0).run(sdr.random_sdrs(50, seed=1))
    obs = sdr.random_sdrs(T, seed=seed)
    mem = SequenceMemory(seed=seed)
    rows = []
    for a in range(0, T, WINDOW):
        t = time.process_time()
        mem.run(obs[a:a + WINDOW])
        dt = time.process_time() - t
        per_bit = mem.n_feedforward / mem.n_inputs  # feed-forward entries per input bit = minicolumns per bit
        rows.append((a + WINDOW, mem.n_columns, per_bit, dt / WINDOW * 1e6))
    print(json.dumps({"rows": rows, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))


def _child(kind, T, seed):
    env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    return child_json([sys.executable, __file__, "--child", kind, str(T), str(seed)], f"{kind} at {T} frames", env)


def _mmm(values):
    v = np.asarray(values, float)
    return f"{v.min():8.1f} {np.median(v):8.1f} {v.max():8.1f}"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="smaller T (for a smoke run)")
    ap.add_argument("--walk-only", action="store_true", help="only part 1 (the random walk)")
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        kind, T, seed = args.child
        (child_random_walk if kind == "walk" else child_new_places)(int(T), int(seed))
        return

    Ts = [200, 2000, 10_000] if args.quick else [200, 10_000, 100_000]
    repeats = {200: 5, 2000: 3, 10_000: 3, 100_000: 1}
    print("== rSHOSM, random walk over 2,000 places, 20% noise (one process per run, one thread)")
    print(f"{'T':>8} {'runs':>4} | us/obs per run (min median max) | us/obs per 1k window (min median max) |"
          f" first/last window | columns | peak RSS MB")
    for T in Ts:
        res = [_child("walk", T, s) for s in range(repeats[T])]
        runs = [r["mean_us"] for r in res]
        win = np.concatenate([r["window_us"] for r in res])
        first = np.median([r["window_us"][0] for r in res])
        last = np.median([r["window_us"][-1] for r in res])
        print(f"{T:>8} {len(res):>4} | {_mmm(runs)} | {_mmm(win)} | {first:7.1f} / {last:7.1f} |"
              f" {res[0]['columns']:>7} | {max(r['peak_rss_mb'] for r in res):8.0f}"
              f" (memory arrays {res[0]['arrays_mb']:.0f} MB)")

    if args.walk_only:
        return
    T_new = 5000 if args.quick else 20_000
    print(f"\n== every observation a new place, T = {T_new} (cost grows with minicolumns per input bit)")
    r = _child("new", T_new, 0)
    rows = np.array(r["rows"])
    for row in rows[:: max(1, len(rows) // 5)].tolist() + [rows[-1].tolist()]:
        print(f"  after {int(row[0]):>6} obs: {int(row[1]):>7} minicolumns, {row[2]:7.1f} per input bit,"
              f" {row[3]:8.1f} us/obs")
    slope, icpt = np.polyfit(rows[:, 2], rows[:, 3], 1)
    print(f"  linear fit: {slope * 100:.2f} us/obs per 100 minicolumns per input bit (+ {icpt:.1f} us);"
          f" peak RSS {r['peak_rss_mb']:.0f} MB")

    print("\n== ratio to the literal set-based reference (same process, same observations, T = 2,000)")
    from vpr.shosm import SequenceMemory
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    sys.path.insert(0, root)  # tests/ is not installed
    from tests.reference import ReferenceMemory

    obs = _world_walk(2000, 7)
    SequenceMemory(seed=0).run(obs[:50])
    fast, ref = [], []
    for rep in range(3):
        t = time.process_time()
        SequenceMemory(seed=rep).run(obs)
        fast.append((time.process_time() - t) / obs.shape[0] * 1e6)
        m = ReferenceMemory(seed=rep)
        t = time.process_time()
        for i in range(obs.shape[0]):
            m.step(obs.indices[obs.indptr[i]:obs.indptr[i + 1]])
        ref.append((time.process_time() - t) / obs.shape[0] * 1e6)
    print(f"  SequenceMemory us/obs (min median max): {_mmm(fast)}")
    print(f"  reference      us/obs (min median max): {_mmm(ref)}")
    print(f"  speed-up (median): {np.median(ref) / np.median(fast):.0f}x")


if __name__ == "__main__":
    main()
