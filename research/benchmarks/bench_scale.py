"""Beyond 20,000 frames: rshosm-seq, SeqSLAM, pairwise and rshosm at 5,000 - 50,000 frames, one core.

Data: ``vpr.simulate.aliased_traverses(n, n // 10)``: a database traverse of n
places and a query traverse of about n frames (speed 0.8-1.2 places per frame),
n / 10 appearances for n places (each SDR shown at about 10 places, so a
single frame is ambiguous and only sequences tell the places apart), 35 % of
the query's bits moved. 2,048 bits, 40 active.

For each method and size, in a fresh child process (so its peak RSS is its
own; one thread: NUMBA / OMP / OPENBLAS / MKL threads = 1):

* ``rshosm-seq``, ``rshosm``, ``pairwise``: ``vpr.methods.match`` with the
  default conf, the database learned inside the timing. ``vpr`` keeps the
  similarity dense up to :func:`vpr.similarity.dense_pairs` (at most 20,000 x
  20,000 pairs) and top-50 sparse per query above; here the sparse path runs
  at every size (the limit is set to 0 in the child) so that the exponent is
  that of the large-input path (``--dense-below-limit``: as ``vpr`` does);
* ``seqslam``: ``vpr.seqslam.seqslam_topk(db, q, candidates="pairwise")``
  (candidate windows from the single-frame top-50 by overlap, top-50 output).

Prints CPU seconds of the process (min / median / max over repeats; wall
seconds too, the machine may be shared), peak RSS, R@1 within one place, the
entries kept, and per method the growth exponent of the median CPU time from
the smallest to the largest size (least-squares slope of log time on log n),
then the load average. With ``--agree N`` it also runs rshosm-seq's dense and
sparse evidence on N frames and prints the share of queries with the same best
match.

Targets (50,000 x ~50,000, one core, rshosm-seq and seqslam): <= 3 minutes,
<= 4 GB, R@1 >= 0.9, exponent <= 1.5; pairwise and rshosm: the same sizes and memory.

Usage: python research/benchmarks/bench_scale.py [--sizes 5000,10000,20000,50000]
[--methods rshosm-seq,seqslam,pairwise,rshosm] [--repeats 1] [--agree 5000]
"""
from __future__ import annotations

import os

# one thread everywhere; must precede the NumPy / numba imports
for _var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
from children import child_json  # noqa: E402, I001 (run as a script: its own folder is on the path)

from vpr.types import EncodedTraverse  # noqa: E402

METHODS = ("rshosm-seq", "seqslam", "pairwise", "rshosm")


def _data(n, seed):
    from vpr import simulate

    return simulate.aliased_traverses(n, max(n // 10, 1), seed=seed)


def _run(method, db, q):
    """(best_db, similarity) of one method; kernels already compiled."""
    from vpr import methods
    from vpr.seqslam import seqslam_topk

    if method == "seqslam":
        r = seqslam_topk(db, q, candidates="pairwise")
        return r.best_db, getattr(r, "similarity", None)
    names = list(range(db.shape[0])), list(range(q.shape[0]))
    r = methods.match(method, EncodedTraverse(names=names[0], sdr=db),
                      EncodedTraverse(names=names[1], sdr=q))
    return r.best, r.similarity


def child(method, n, seed, agree, dense_below_limit):
    if not dense_below_limit:
        from vpr import similarity

        similarity.DENSE_PAIRS_LIMIT = 0  # the large-input path (top-K sparse) at every size, for the growth exponent
    db, q, dp, qp = _data(n, seed)
    tdb, tq, _, _ = _data(200, seed + 1)
    _run(method, tdb, tq)  # compile / load the numba kernels outside the timing
    if method == "rshosm-seq":  # and the sparse beam's, which 200 frames do not reach
        from vpr.shosm import SequenceMemory, sparse_evidence

        m0 = SequenceMemory(threshold=0.75)
        sparse_evidence(m0, tq[:20], m0.run(tdb[:50]))
    c0, t0 = time.process_time(), time.perf_counter()
    best, S = _run(method, db, q)
    out = {"method": method, "n_db": int(db.shape[0]), "n_q": int(q.shape[0]), "cpu_s": time.process_time() - c0,
           "wall_s": time.perf_counter() - t0, "r1": float(np.mean((best >= 0) & (np.abs(dp[best] - qp) <= 1))),
           "sparse": bool(S is not None and sp.issparse(S)),
           "entries": int(S.nnz) if S is not None and sp.issparse(S) else (int(S.size) if S is not None else -1),
           "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
    if agree:
        from vpr.shosm import SequenceMemory, dense_evidence, sparse_evidence

        mem = SequenceMemory(threshold=0.75, seed=seed)
        codes = mem.run(db)
        mem.reset()
        c1 = time.process_time()
        r = sparse_evidence(mem, q, codes, top_k=50)
        c2 = time.process_time()
        dense = dense_evidence(mem, q, codes).argmax(axis=0)
        out.update(sparse_s=c2 - c1, dense_s=time.process_time() - c2, agree=float(np.mean(dense == r.best)),
                   dense_r1=float(np.mean(np.abs(dp[dense] - qp) <= 1)),
                   sparse_r1=float(np.mean(np.abs(dp[r.best] - qp) <= 1)))
    print(json.dumps(out))


def run_child(method, n, seed, agree=False, dense_below_limit=False):
    cmd = [sys.executable, __file__, "--child", method, "--n", str(n), "--seed", str(seed)]
    cmd += ["--dense-below-limit"] if dense_below_limit else []
    return child_json(cmd + (["--agree-child"] if agree else []), f"{method} at {n} frames")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="5000,10000,20000,50000")
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--agree", type=int, default=0, help="also compare rshosm-seq dense and sparse at this size")
    ap.add_argument("--dense-below-limit", action="store_true",
                    help="methods run dense below DENSE_PAIRS_LIMIT as in `vpr` (default: top-K at every size)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--n", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--agree-child", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child is not None:
        child(a.child, a.n, a.seed, a.agree_child, a.dense_below_limit)
        return
    sizes = [int(s) for s in a.sizes.split(",")]
    names = [m for m in a.methods.split(",") if m]
    if set(names) - set(METHODS) or a.repeats < 1:
        ap.error(f"--methods from {','.join(METHODS)}, --repeats >= 1")
    print(f"aliased SDR traverses (n/10 appearances, 35 % bits moved, speed 0.8-1.2), one thread; "
          f"CPU s and wall s min/median/max over {a.repeats} repeat(s); load average at start "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}; "
          + ("dense below DENSE_PAIRS_LIMIT" if a.dense_below_limit else "top-50 sparse at every size"))
    print(f"{'method':>10} {'n_db':>6} {'n_q':>6} {'CPU s':>20} {'wall s':>20} {'peak MB':>8} {'R@1':>7} "
          f"{'entries':>10}")
    for m in names:
        med = {}
        for n in sizes:
            runs = [run_child(m, n, a.seed + r, dense_below_limit=a.dense_below_limit) for r in range(a.repeats)]

            def mmm(key, runs=runs):
                v = np.array([r[key] for r in runs])
                return f"{v.min():6.1f}/{np.median(v):6.1f}/{v.max():6.1f}"

            med[n] = float(np.median([r["cpu_s"] for r in runs]))
            r0 = runs[0]
            kept = f"{r0['entries']}{' sp' if r0['sparse'] else ''}" if r0["entries"] >= 0 else "-"
            print(f"{m:>10} {n:6d} {r0['n_q']:6d} {mmm('cpu_s'):>20} {mmm('wall_s'):>20} "
                  f"{max(r['peak_rss_mb'] for r in runs):8.0f} {min(r['r1'] for r in runs):7.4f} {kept:>10}",
                  flush=True)
        if len(sizes) >= 2:
            x, y = np.log(sizes), np.log([med[n] for n in sizes])
            print(f"{m:>10} growth exponent of CPU time {sizes[0]} -> {sizes[-1]} frames: "
                  f"{np.polyfit(x, y, 1)[0]:.2f}", flush=True)
    if a.agree:
        r = run_child("rshosm-seq", a.agree, a.seed, agree=True)
        print(f"rshosm-seq dense vs sparse evidence at {a.agree} x {r['n_q']}: same best match for "
              f"{100 * r['agree']:.2f} % of queries; R@1 dense {r['dense_r1']:.4f}, sparse {r['sparse_r1']:.4f}; "
              f"evidence CPU s dense {r['dense_s']:.1f}, sparse {r['sparse_s']:.1f}")
    print(f"load average at end {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
