"""rSHOSM-seq beyond 20,000 frames: sparse top-K evidence (vpr.evidence.sparse_evidence), issue 13.

Data: ``vpr.simulate.aliased_traverses(n, n // 10)``: a database traverse of n
places and a query traverse of about n frames (speed 0.8-1.2 places per frame),
5,000 appearances for 50,000 places (each SDR shown at about 10 places, so a
single frame is ambiguous), 35 % of the query's bits moved.

For each size, in a fresh process (peak RSS per run): learn the database with
Algorithm 1 (threshold 0.75), then the evidence in both directions, top-50 per
query, z-scores per query. Prints CPU seconds (learn, evidence, total; min /
median / max over repeats), peak RSS, R@1 within one place, and the growth
exponent of the total time from the smallest to the largest size (log-log fit).
With ``--agree N`` it also runs the dense evidence (``SequenceMemory.evidence``)
on N frames and prints the share of queries whose best match is the same.

Targets (50,000 x ~50,000, one core): <= 3 minutes, <= 4 GB, R@1 >= 0.9, exponent <= 1.5.

Usage: python benchmarks/bench_scale.py [--sizes 5000,10000,20000,50000] [--repeats 1] [--agree 5000]
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import numpy as np


def child(n, seed, agree):
    from vpr import evidence, simulate
    from vpr.memory import SequenceMemory

    db, q, dp, qp = simulate.aliased_traverses(n, max(n // 10, 1), seed=seed)
    # compile / load the kernels outside the timing
    m0 = SequenceMemory(threshold=0.75)
    evidence.sparse_evidence(m0, q[:20], m0.run(db[:50]))
    t0 = time.process_time()
    mem = SequenceMemory(threshold=0.75, seed=seed)
    codes = mem.run(db)
    mem.reset()
    t1 = time.process_time()
    r = evidence.sparse_evidence(mem, q, codes, direction="both", top_k=50)
    t2 = time.process_time()
    out = {"n_db": n, "n_q": int(q.shape[0]), "learn_s": t1 - t0, "evidence_s": t2 - t1, "total_s": t2 - t0,
           "r1": float(np.mean(np.abs(dp[np.maximum(r.best_db, 0)] - qp) <= 1)), "nnz": int(r.similarity.nnz),
           "connections": mem.n_connections, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
    if agree:
        D = mem.evidence(q, codes)
        best = D.argmax(axis=0)
        out["dense_s"] = time.process_time() - t2
        out["agree"] = float(np.mean(best == r.best_db))
        out["dense_r1"] = float(np.mean(np.abs(dp[best] - qp) <= 1))
    print(json.dumps(out))


def run_child(n, seed, agree=False):
    cmd = [sys.executable, __file__, "--child", str(n), "--seed", str(seed)] + (["--agree-child"] if agree else [])
    res = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="5000,10000,20000,50000")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--agree", type=int, default=0, help="also compare with the dense evidence at this size")
    ap.add_argument("--child", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--agree-child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    if a.child is not None:
        child(a.child, a.seed, a.agree_child)
        return
    sizes = [int(s) for s in a.sizes.split(",")]
    print("rshosm-seq, sparse top-50 evidence (both directions), CPU seconds, min/median/max over "
          f"{a.repeats} repeat(s)")
    print(f"{'n_db':>7} {'n_q':>7} {'learn s':>20} {'evidence s':>22} {'total s':>22} {'peak MB':>8} {'R@1':>7}")
    med = {}
    for n in sizes:
        runs = [run_child(n, a.seed + r) for r in range(a.repeats)]

        def mmm(key, runs=runs):
            v = np.array([r[key] for r in runs])
            return f"{v.min():6.1f}/{np.median(v):6.1f}/{v.max():6.1f}"

        med[n] = float(np.median([r["total_s"] for r in runs]))
        print(f"{n:7d} {runs[0]['n_q']:7d} {mmm('learn_s'):>20} {mmm('evidence_s'):>22} {mmm('total_s'):>22} "
              f"{max(r['peak_rss_mb'] for r in runs):8.0f} {min(r['r1'] for r in runs):7.4f}", flush=True)
    if len(sizes) >= 2:
        x, y = np.log(sizes), np.log([med[n] for n in sizes])
        print(f"growth exponent of total time {sizes[0]} -> {sizes[-1]} frames: {np.polyfit(x, y, 1)[0]:.2f}")
    if a.agree:
        r = run_child(a.agree, a.seed, agree=True)
        print(f"dense vs sparse at {a.agree} x {r['n_q']}: same best match for {100 * r['agree']:.2f} % of queries; "
              f"R@1 dense {r['dense_r1']:.4f}, sparse {r['r1']:.4f}; dense evidence {r['dense_s']:.1f} s, "
              f"sparse {r['evidence_s']:.1f} s")


if __name__ == "__main__":
    main()
