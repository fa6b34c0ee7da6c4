"""rshosm-seq's batch match against SeqSLAM's on aliased SDRs, both cores, the direction check included.

Data: ``vpr.simulate.aliased_traverses(n, n // 10, k=200)``: a database of n places, each showing one of n / 10
random SDRs (200 of 2,048 bits, the ``fast`` preset's density), and a query of about n frames over the same places
(speed 0.8-1.2 places a frame, 35 % of its bits moved). Each method runs in its own process (its peak RSS its own),
warm (kernels compiled on a small match first): ``vpr.methods.match("rshosm-seq")`` (learning, the evidence of both
directions, the causal and the reversed evidence of the direction check, the decisions) and SeqSLAM's top-K search
on the same SDRs (``vpr.seqslam.seqslam_topk``, the candidates of each query's best single frames).

Prints per size and method: wall seconds (min / median / max over ``--repeats``), peak RSS, R@1 within one place,
and rshosm-seq's seconds over SeqSLAM's in the same run.

    python research/benchmarks/bench_batch.py --sizes 20000,50000 [--repeats 1]
"""
from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _data(n: int, seed: int):
    from vpr import simulate

    return simulate.aliased_traverses(n, max(n // 10, 1), k=200, seed=seed)


def _match(method: str, db, q):
    from vpr import methods
    from vpr.seqslam import seqslam_topk
    from vpr.types import EncodedTraverse

    if method == "seqslam":
        return seqslam_topk(db, q, candidates="pairwise").best_db
    r = methods.match(method, EncodedTraverse(names=list(range(db.shape[0])), sdr=db),
                      EncodedTraverse(names=list(range(q.shape[0])), sdr=q))
    return r.best


def child(method: str, n: int, seed: int) -> None:
    tdb, tq, _, _ = _data(300, seed + 1)
    _match(method, tdb, tq)  # compile / load the kernels outside the timing
    db, q, dp, qp = _data(n, seed)
    t = time.perf_counter()
    best = _match(method, db, q)
    wall = time.perf_counter() - t
    print(json.dumps({"wall_s": wall, "r1": float(np.mean((best >= 0) & (np.abs(dp[best] - qp) <= 1))),
                      "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "n_q": int(q.shape[0])}))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="20000")
    ap.add_argument("--methods", default="rshosm-seq,seqslam")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--n", type=int, default=0, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        child(a.child, a.n, a.seed)
        return
    from children import child_json

    print("| frames | method | wall s (min / median / max) | peak MB | R@1 |")
    print("|---:|---|---|---:|---:|")
    for n in [int(s) for s in a.sizes.split(",")]:
        med = {}
        for m in a.methods.split(","):
            runs = [child_json([sys.executable, __file__, "--child", m, "--n", str(n), "--seed", str(a.seed + r)],
                               f"{m} at {n}") for r in range(a.repeats)]
            w = np.array([r["wall_s"] for r in runs])
            med[m] = float(np.median(w))
            print(f"| {n:,} | {m} | {w.min():.1f} / {np.median(w):.1f} / {w.max():.1f} | "
                  f"{max(r['peak_mb'] for r in runs):,.0f} | {min(r['r1'] for r in runs):.3f} |", flush=True)
        if "rshosm-seq" in med and "seqslam" in med:
            print(f"| {n:,} | rshosm-seq / seqslam | {med['rshosm-seq'] / med['seqslam']:.2f} | | |", flush=True)


if __name__ == "__main__":
    main()
