"""Benchmark SeqSLAM on a Nordland-sized problem (3,576 x 3,576) on one thread.

Prints, for a synthetic route with 2,048-dim descriptors (64 x 32 pixels):

* ``difference_matrix`` (numba SAD) and, for comparison, SciPy's
  ``cdist(..., "cityblock")`` on a row subset, extrapolated;
* ``seqslam(D)`` with the defaults (min / median / max over ``--repeats`` runs)
  and its ``enhance_contrast`` share;
* ``seqslam_topk(db, q)`` (blocked, exact, top-50 output) from the
  descriptors, and its agreement with the dense result;
* the brute-force per-query reference from ``tests/test_seqslam.py`` on a
  subset (query columns for the trajectory search, database columns for the
  contrast enhancement), extrapolated linearly to the full matrix, and the
  ratio reference / vectorised; plus agreement on the subset.

Usage: ``python research/benchmarks/bench_seqslam.py [--n 3576] [--repeats 3] [--ref-queries 20]``
"""
from __future__ import annotations

import os

# one thread everywhere; must precede the NumPy / numba imports
for _var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.spatial.distance import cdist  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))
from test_seqslam import ref_enhance, ref_offsets, ref_score_column  # noqa: E402

from vpr.seqslam import difference_matrix, enhance_contrast, seqslam, seqslam_topk  # noqa: E402


def synthetic_route(n: int, dim: int, noise: float = 10.0, seed: int = 0):
    """Database and query descriptors of one route with a varying query speed.

    Database descriptors follow a smooth AR(1) walk; query frame j shows place
    ``gt[j] = j + 6 sin(2 pi j / 400)`` (speed 0.9..1.1 of the database's) under
    a contrast change plus Gaussian noise of std ``noise`` (10 makes single
    frames ambiguous, so the sequence search matters).
    """
    rng = np.random.default_rng(seed)
    db = np.empty((n, dim), dtype=np.float32)
    x = rng.standard_normal(dim).astype(np.float32)
    for t in range(n):
        x = 0.8 * x + 0.6 * rng.standard_normal(dim).astype(np.float32)
        db[t] = x
    j = np.arange(n)
    gt = np.clip(np.round(j + 6 * np.sin(2 * np.pi * j / 400)), 0, n - 1).astype(int)
    q = 0.7 * db[gt] + 0.2 + noise * rng.standard_normal((n, dim)).astype(np.float32)
    return db, q.astype(np.float32), gt


def timed(fn, repeats: int):
    out, times = None, []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return out, times


def fmt(times) -> str:
    return f"min {min(times):.3f} / median {statistics.median(times):.3f} / max {max(times):.3f} s"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=3576, help="database = query length")
    ap.add_argument("--dim", type=int, default=2048, help="descriptor length")
    ap.add_argument("--noise", type=float, default=10.0, help="query noise std (descriptor std ~1)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--ref-queries", type=int, default=20, help="query columns timed for the reference")
    ap.add_argument("--ref-cols", type=int, default=100, help="columns timed for the reference enhancement")
    args = ap.parse_args(argv)
    if args.repeats < 1 or args.ref_queries < 1 or args.ref_cols < 1 or args.n < 12:
        ap.error("--repeats, --ref-queries, --ref-cols must be >= 1 and --n >= 12")
    n = args.n
    print(f"SeqSLAM benchmark: {n} x {n}, {args.dim}-dim descriptors, one thread, {args.repeats} runs")

    db, q, gt = synthetic_route(n, args.dim, args.noise)

    difference_matrix(db[:2], q[:2])          # numba compile, not timed
    D, t_diff = timed(lambda: difference_matrix(db, q), args.repeats)
    print(f"difference_matrix (numba SAD):        {fmt(t_diff)}")
    sub = min(256, n)
    _, t_cd = timed(lambda: cdist(db[:sub], q, "cityblock"), 1)
    print(f"scipy cdist cityblock, {sub} rows x{n / sub:.1f}:  {t_cd[0] * n / sub:.3f} s (extrapolated)")

    _, t_enh = timed(lambda: enhance_contrast(D), args.repeats)
    print(f"enhance_contrast:                     {fmt(t_enh)}")
    res, t_seq = timed(lambda: seqslam(D), args.repeats)
    print(f"seqslam(D) defaults (incl. enhance):  {fmt(t_seq)}")
    _, t_causal = timed(lambda: seqslam(D, causal=True), 1)
    print(f"seqslam(D, causal=True):              {t_causal[0]:.3f} s (1 run)")
    err = np.abs(res.best_db - gt)
    single = np.mean(np.abs(np.argmin(D, axis=0) - gt) <= 2)
    print(f"  sanity: best_db within 2 frames of ground truth {np.mean(err <= 2):.3f}, "
          f"(single frame: {single:.3f}), accepted {res.accepted.mean():.3f}, "
          f"precision of accepted {np.mean(err[res.accepted] <= 2) if res.accepted.any() else float('nan'):.3f}")

    seqslam_topk(db[:20], q[:20])             # numba compile, not timed
    blk, t_blk = timed(lambda: seqslam_topk(db, q), args.repeats)
    print(f"seqslam_topk(db, q) blocked exact:    {fmt(t_blk)} (difference matrix included)")
    print(f"  best match = dense {np.mean(blk.best_db == res.best_db):.2%}, max |best score difference| "
          f"{np.max(np.abs(blk.best_score - res.best_score)):.1e}")

    # reference: enhancement on a column subset, trajectory search on a query subset
    ncols = min(args.ref_cols, n)
    _, t_ref_enh = timed(lambda: ref_enhance(D[:, :ncols]), 1)
    t_ref_enh_full = t_ref_enh[0] * n / ncols
    DD = enhance_contrast(D)
    offsets = ref_offsets(10, 0.8, 1.2, 0.1)
    qs = np.linspace(0, n - 1, min(args.ref_queries, n)).round().astype(int)
    t0 = time.perf_counter()
    cols = [ref_score_column(DD, int(qq), offsets, 10, False) for qq in qs]
    t_ref_cols = time.perf_counter() - t0
    t_ref_search_full = t_ref_cols * n / len(qs)
    t_ref = t_ref_enh_full + t_ref_search_full
    print(f"reference per-query loop: enhancement {t_ref_enh[0]:.2f} s on {ncols} columns -> "
          f"{t_ref_enh_full:.1f} s; search {t_ref_cols:.2f} s on {len(qs)} queries -> "
          f"{t_ref_search_full:.1f} s; total {t_ref:.1f} s (extrapolated, not run in full)")
    print(f"ratio reference / vectorised (median): {t_ref / statistics.median(t_seq):.0f}x")

    S_ref = np.stack([c[0] for c in cols], axis=1)
    S_vec = res.score[:, qs]
    same_inf = np.array_equal(np.isinf(S_ref), np.isinf(S_vec))
    fin = np.isfinite(S_ref)
    rel = float(np.max(np.abs(S_vec[fin] - S_ref[fin]) / np.maximum(np.abs(S_ref[fin]), 1.0)))
    print(f"  agreement on the {len(qs)} reference queries: same infeasible entries {same_inf}, "
          f"max rel. score difference {rel:.1e}, same best row "
          f"{int(np.sum(np.argmin(S_ref, axis=0) == res.best_db[qs]))}/{len(qs)}")


if __name__ == "__main__":
    main()
