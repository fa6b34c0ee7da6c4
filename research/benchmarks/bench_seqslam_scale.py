"""SeqSLAM beyond the dense limit: time, peak RSS and R@1 from 5,000 to 50,000 frames, one thread.

Data: the synthetic aliased SDR traverses of ``bench_scale.py``
(:func:`vpr.simulate.aliased_traverses`): ``n`` database places shown by
``n / 10`` appearances (each reused at about ten random places, so single
frames are ambiguous), a query traverse over the same places at a speed
drawn within 0.8-1.2 (a new value every 50-200 frames), 35 % of each query
frame's bits moved. ``bench_scale.py`` has the one-line figures of all
methods; this one adds the exact and dense SeqSLAM and their agreement.

For each size, in a fresh child process (so that its peak RSS is its own):

* ``seqslam_topk(db, q, candidates="pairwise")`` (candidate windows from the
  single-frame top-50 by overlap): seconds (min / median / max over
  ``--repeats``), peak RSS, R@1 within one place, cells searched; once with
  ``causal=True`` (its match is the trajectory's row at the query, so it does
  not carry OpenSeqSLAM's centred offset of up to one place at v != 1);
* up to ``--exact-max`` frames also the exact blocked mode
  (``candidates=None``, equal to the dense ``seqslam``) and the agreement of
  the candidate mode's best matches with it;
* up to ``--dense-max`` frames also the dense ``seqslam(difference_matrix())``
  and the agreement of both blocked modes with it.

Seconds are wall-clock and process CPU time (the machine may be shared).
Then the growth exponent of the candidate mode's median time (least-squares
slope of log time on log n) and, if there are two exact sizes, of the exact mode.

Usage: ``python research/benchmarks/bench_seqslam_scale.py [--sizes 5000 10000 20000 50000] [--repeats 3]
[--once-above 20000] [--exact-max 10000] [--dense-max 3000]``
"""
from __future__ import annotations

import os

# one thread everywhere; must precede the NumPy / numba imports
for _var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from children import child_json  # noqa: E402, I001 (run as a script: its own folder is on the path)

from vpr import simulate  # noqa: E402
from vpr.seqslam import difference_matrix, seqslam, seqslam_topk  # noqa: E402


def aliased_traverses(n: int, seed: int = 0):
    """``(db, q, gt)``: :func:`vpr.simulate.aliased_traverses` with ``n / 10`` appearances (as ``bench_scale.py``)
    and the database place of every query frame."""
    db, q, db_place, q_place = simulate.aliased_traverses(n, max(1, n // 10), seed=seed)
    return db, q, db_place[q_place]


def peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0   # Linux: KiB


def child(n: int, repeats: int, exact: bool, dense: bool, seed: int) -> dict:
    db, q, gt = aliased_traverses(n, seed=seed)
    tiny_db, tiny_q, _ = aliased_traverses(40, seed=1)
    seqslam_topk(tiny_db, tiny_q, candidates="pairwise")     # compile / load numba kernels, not timed
    seqslam_topk(tiny_db, tiny_q)
    out = {"n_db": db.shape[0], "n_q": q.shape[0], "rss_data": peak_rss_mib()}
    times, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        res = seqslam_topk(db, q, candidates="pairwise")
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    err = np.abs(res.best_db - gt)
    out.update(times=times, cpu=cpu, rss=peak_rss_mib(), r1=float(np.mean(err <= 1)), r2=float(np.mean(err <= 2)),
               cells=res.cells, exact_windows=res.exact, accepted=float(res.accepted.mean()))
    t0 = time.perf_counter()
    ca = seqslam_topk(db, q, candidates="pairwise", causal=True)
    out.update(t_causal=time.perf_counter() - t0, r1_causal=float(np.mean(np.abs(ca.best_db - gt) <= 1)))
    if exact:
        t0, c0 = time.perf_counter(), time.process_time()
        ex = seqslam_topk(db, q)
        out.update(t_exact=time.perf_counter() - t0, cpu_exact=time.process_time() - c0, rss_exact=peak_rss_mib(),
                   r1_exact=float(np.mean(np.abs(ex.best_db - gt) <= 1)),
                   agree=float(np.mean(ex.best_db == res.best_db)))
    if dense:
        t0 = time.perf_counter()
        de = seqslam(difference_matrix(db.toarray().astype(np.float32), q.toarray().astype(np.float32)))
        out.update(t_dense=time.perf_counter() - t0, r1_dense=float(np.mean(np.abs(de.best_db - gt) <= 1)),
                   agree_dense=float(np.mean(de.best_db == res.best_db)))
        if exact:
            out["agree_exact_dense"] = float(np.mean(de.best_db == ex.best_db))
    return out


def fit_exponent(ns, ts) -> float:
    return float(np.polyfit(np.log(ns), np.log(ts), 1)[0])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[5000, 10000, 20000, 50000])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--exact-max", type=int, default=10000, help="largest size also run in exact mode")
    ap.add_argument("--dense-max", type=int, default=3000, help="largest size also run densely")
    ap.add_argument("--once-above", type=int, default=20000, help="larger sizes run once")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        res = child(args.child, args.repeats, args.child <= args.exact_max, args.child <= args.dense_max, args.seed)
        print(json.dumps(res))
        return
    if args.repeats < 1 or min(args.sizes) < 100:
        ap.error("--repeats must be >= 1 and sizes >= 100")
    print("SeqSLAM top-K on aliased SDR traverses (2,048 bits, 40 on, n/10 appearances, 35 % bits moved, "
          "speed 0.8-1.2), one thread; candidates='pairwise' (top-50 overlap of every 4th query), 4 windows per "
          "64-query block; default centred SeqSLAM (ds=10, v 0.8-1.2) unless said")
    rows = []
    for n in args.sizes:
        reps = args.repeats if n <= args.once_above else 1
        cmd = [sys.executable, __file__, "--child", str(n), "--repeats", str(reps),
               "--exact-max", str(args.exact_max), "--dense-max", str(args.dense_max), "--seed", str(args.seed)]
        r = child_json(cmd, f"SeqSLAM at {n} frames")
        rows.append((n, r))
        t = r["times"]
        c = r["cpu"]
        line = (f"n={n:>6} ({r['n_db']} x {r['n_q']}): candidates {min(t):.1f} / {statistics.median(t):.1f} / "
                f"{max(t):.1f} s wall (min/med/max; CPU {min(c):.1f} / {statistics.median(c):.1f} / "
                f"{max(c):.1f} s), peak RSS {r['rss'] / 1024:.2f} GiB (data alone "
                f"{r['rss_data'] / 1024:.2f}), R@1 {r['r1']:.4f} (within 2: {r['r2']:.4f}), accepted "
                f"{r['accepted']:.3f}, cells {r['cells'] / (r['n_db'] * r['n_q']):.2%} of all"
                f"\n          causal=True: {r['t_causal']:.1f} s, R@1 {r['r1_causal']:.4f}")
        if "t_exact" in r:
            line += (f"\n          exact: {r['t_exact']:.1f} s wall, {r['cpu_exact']:.1f} s CPU, "
                     f"peak RSS {r['rss_exact'] / 1024:.2f} GiB, "
                     f"R@1 {r['r1_exact']:.4f}; best match candidate = exact {r['agree']:.2%}")
        if "t_dense" in r:
            line += (f"\n          dense seqslam: {r['t_dense']:.1f} s, R@1 {r['r1_dense']:.4f}; best match "
                     f"candidate = dense {r['agree_dense']:.2%}"
                     + (f", exact = dense {r['agree_exact_dense']:.2%}" if "agree_exact_dense" in r else ""))
        print(line, flush=True)
    if len(rows) > 1:
        ns = [r["n_q"] for _, r in rows]
        print(f"growth exponent (candidate mode, median time vs n, {ns[0]}..{ns[-1]}): wall "
              f"{fit_exponent(ns, [statistics.median(r['times']) for _, r in rows]):.2f}, CPU "
              f"{fit_exponent(ns, [statistics.median(r['cpu']) for _, r in rows]):.2f}")
        ex = [(r["n_q"], r["t_exact"], r["cpu_exact"]) for _, r in rows if "t_exact" in r]
        if len(ex) > 1:
            en, et, ec = zip(*ex, strict=True)
            print(f"growth exponent (exact mode, {en[0]}..{en[-1]}): wall {fit_exponent(en, et):.2f}, "
                  f"CPU {fit_exponent(en, ec):.2f}")


if __name__ == "__main__":
    main()
