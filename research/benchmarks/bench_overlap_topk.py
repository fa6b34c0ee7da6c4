"""Top-K SDR overlap (the ``pairwise`` method above the dense limit): sparse product vs packed bit sets.

``vpr.similarity.overlap_similarity(db, q, top_k=K)`` picks one of two exact
paths: the sparse product ``db @ q.T`` densified per block of queries with a
partial sort, or popcounts of rows packed into 64-bit words with a heap per
query. Both give the same values (checked here per query); this prints the
CPU seconds of each path, one after the other in one process and one thread,
their ratio, and which path ``vpr`` takes. ``--candidates`` times SeqSLAM's
single-frame candidates on SDRs instead (top-K raw overlap, as
``seqslam_topk(..., candidates="pairwise")`` finds them): a lean count through
the database's inverted index against the same bit sets, and checks that both
give every query the same overlaps.

Data: SDR batches of n x n frames, either random with ``--active`` of 2,048
bits (40: the paper's SDRs; 200: the ``fast`` preset's), or the first n
frames of two ``vpr`` cache files (``--cache DB.npz Q.npz``, e.g. the
``make_large_folders.py`` folders encoded by ``vpr compare --cache``).

Usage: python research/benchmarks/bench_overlap_topk.py [--sizes 5000,20000] [--active 40,200] [--cache DB Q]
[--candidates]
"""
from __future__ import annotations

import os

for _var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402

from vpr import similarity  # noqa: E402


def _random(n, active, seed):
    rng = np.random.default_rng(seed)
    protos = rng.random((max(n // 10, 1), 2048)).argsort(axis=1)[:, :active]  # n / 10 appearances
    rows = protos[rng.integers(0, len(protos), n)].copy()
    moved = rng.random(rows.shape) < 0.35
    rows[moved] = rng.integers(0, 2048, moved.sum())
    ind = [np.unique(r) for r in rows]
    ptr = np.r_[0, np.cumsum([len(r) for r in ind])]
    return sp.csr_matrix((np.ones(ptr[-1], bool), np.concatenate(ind), ptr), shape=(n, 2048))


def _cached(path, n):
    with np.load(path, allow_pickle=False) as z:
        ptr, idx, shape = z["sdr_indptr"], z["sdr_indices"], tuple(z["sdr_shape"])
    return sp.csr_matrix((np.ones(idx.size, bool), idx, ptr), shape=shape)[:n]


def _time(fn, *args, **kw):
    c0 = time.process_time()
    out = fn(*args, **kw)
    return time.process_time() - c0, out


def _same_values(a, b) -> float:
    A, B = a.tocsc(), b.tocsc()
    same = [np.array_equal(np.sort(A[:, j].data), np.sort(B[:, j].data)) for j in range(A.shape[1])]
    return float(np.mean(same))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="5000,20000")
    ap.add_argument("--active", default="40,200", help="active bits of the random SDRs (ignored with --cache)")
    ap.add_argument("--cache", nargs=2, default=None, metavar=("DB", "QUERY"))
    ap.add_argument("--top-k", type=int, default=50)
    ap.add_argument("--candidates", action="store_true", help="SeqSLAM's SDR candidates: inverted index vs bit sets")
    a = ap.parse_args(argv)
    if a.candidates:
        return _candidates(a)
    sizes = [int(s) for s in a.sizes.split(",")]
    cases = [("cache", None)] if a.cache else [(f"random {k}/2048", int(k)) for k in a.active.split(",")]
    similarity._topk_overlap_kernel(*[np.zeros((1, 1), np.uint64)] * 2, np.ones(1), np.ones(1), True,
                                    np.zeros((1, 1), np.int64), np.zeros((1, 1), np.float32))  # compile
    print(f"top-{a.top_k} normalised SDR overlap, one thread, CPU seconds")
    print(f"{'SDRs':>16} {'n':>7} {'sparse product':>15} {'bit sets':>9} {'ratio':>6} {'same values':>12} vpr takes")
    real = similarity.bitsets_pay
    for label, active in cases:
        for n in sizes:
            if a.cache:
                db, q = _cached(a.cache[0], n), _cached(a.cache[1], n)
            else:
                db, q = _random(n, active, 1), _random(n, active, 2)
            try:
                similarity.bitsets_pay = lambda A, B: False
                t_sp, s_sp = _time(similarity.overlap_similarity, db, q, top_k=a.top_k)
                similarity.bitsets_pay = lambda A, B: True
                t_bs, s_bs = _time(similarity.overlap_similarity, db, q, top_k=a.top_k)
            finally:
                similarity.bitsets_pay = real
            takes = "bit sets" if real(db, q) else "sparse product"
            print(f"{label:>16} {n:>7} {t_sp:>15.1f} {t_bs:>9.1f} {t_sp / max(t_bs, 1e-9):>6.1f} "
                  f"{_same_values(s_sp, s_bs):>11.1%} {takes}", flush=True)


def _candidates(a):
    from vpr.seqslam import topk

    sizes = [int(s) for s in a.sizes.split(",")]
    print(f"SeqSLAM's single-frame candidates (top-{a.top_k} raw overlap), one thread, CPU seconds")
    print(f"{'SDRs':>16} {'n':>7} {'inverted index':>15} {'bit sets':>9} {'ratio':>6} {'same overlaps':>14} vpr takes")
    real = topk.bitsets_pay
    try:
        tiny = _random(60, 40, 0)
        for pay in (False, True):  # compile both paths outside the timing
            topk.bitsets_pay = lambda A, B, against, pay=pay: pay
            topk._Descriptors(tiny, tiny, "sad").candidates(5)
        for active in [int(k) for k in a.active.split(",")]:
            for n in sizes:
                db, q = _random(n, active, 1), _random(n, active, 2)
                d = topk._Descriptors(db, q, "sad")
                topk.bitsets_pay = lambda A, B, against: False
                t_ix, c_ix = _time(d.candidates, a.top_k)
                topk.bitsets_pay = lambda A, B, against: True
                t_bs, c_bs = _time(d.candidates, a.top_k)
                _row(active, n, t_ix, t_bs, _same_overlaps(db, q, c_ix, c_bs), real(db, q, against="index"))
    finally:
        topk.bitsets_pay = real


def _row(active, n, t_ix, t_bs, same, bits):
    takes = "bit sets" if bits else "inverted index"
    print(f"{f'random {active}/2048':>16} {n:>7} {t_ix:>15.1f} {t_bs:>9.1f} {t_ix / max(t_bs, 1e-9):>6.1f} "
          f"{same:>13.1%} {takes}", flush=True)


def _same_overlaps(db, q, a, b) -> float:
    """Share of queries whose candidates have the same overlaps (ties may pick other rows)."""
    same = []
    for j in range(0, q.shape[0], max(1, q.shape[0] // 500)):
        ra, rb = a[1][a[0][j]:a[0][j + 1]], b[1][b[0][j]:b[0][j + 1]]
        oa = np.sort(np.asarray(db[ra].multiply(q[j]).sum(axis=1)).ravel())
        ob = np.sort(np.asarray(db[rb].multiply(q[j]).sum(axis=1)).ravel())
        same.append(np.array_equal(oa, ob))
    return float(np.mean(same))


if __name__ == "__main__":
    main()
