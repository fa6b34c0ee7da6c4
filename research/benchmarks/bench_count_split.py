"""Algorithm 1's overlap count on one thread and split over two: does learning gain from the second core?

Learns ``aliased_traverses(n, n // 10, k=200)``'s database, then counts the
overlaps of ``--frames`` query frames with its minicolumns through the
inverted index (:func:`vpr.shosm.kernels.overlap.count_overlaps`, what
learning and the beam count), ``--repeats`` times: sequentially, and in two
halves of the active bits on two numba threads summed into one count (the
active set is sorted afterwards, so the order does not matter). Prints ms per
frame of each run (the first of each compiles) and whether the counts agree.

    python research/benchmarks/bench_count_split.py [--size 20000] [--frames 2000] [--repeats 3]
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from numba import njit, prange

from vpr.shosm.kernels.overlap import count_overlaps


@njit(parallel=True)
def _count_halves(bits, bit_cols, bit_len, counts2, touched2, n2):  # pragma: no cover - compiled
    h = bits.shape[0] // 2
    for k in prange(2):
        part = bits[:h] if k == 0 else bits[h:]
        n2[k] = count_overlaps(part, bit_cols, bit_len, counts2[k], touched2[k])


@njit
def split(ptr, ind, bit_cols, bit_len, counts, touched, counts2, touched2, n2):  # pragma: no cover - compiled
    """Every frame counted in two halves and summed into ``counts`` (first met first); a checksum."""
    total = 0
    for f in range(ptr.shape[0] - 1):
        _count_halves(ind[ptr[f]:ptr[f + 1]], bit_cols, bit_len, counts2, touched2, n2)
        n = 0
        for i in range(n2[0]):
            c = touched2[0, i]
            touched[n] = c
            counts[c] = counts2[0, c] + counts2[1, c]
            n += 1
        for i in range(n2[1]):
            c = touched2[1, i]
            if counts2[0, c] == 0:
                touched[n] = c
                counts[c] = counts2[1, c]
                n += 1
        for k in range(2):
            for i in range(n2[k]):
                counts2[k, touched2[k, i]] = 0
        for i in range(n):
            total += counts[touched[i]] * (touched[i] + 1)
            counts[touched[i]] = 0
    return total


@njit
def sequential(ptr, ind, bit_cols, bit_len, counts, touched):  # pragma: no cover - compiled
    """Every frame counted on one thread; the same checksum."""
    total = 0
    for f in range(ptr.shape[0] - 1):
        n = count_overlaps(ind[ptr[f]:ptr[f + 1]], bit_cols, bit_len, counts, touched)
        for i in range(n):
            total += counts[touched[i]] * (touched[i] + 1)
            counts[touched[i]] = 0
    return total


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=20000)
    ap.add_argument("--frames", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args(argv)
    from vpr import simulate
    from vpr.shosm import SequenceMemory

    db, q = simulate.aliased_traverses(a.size, a.size // 10, k=200, seed=0)[:2]
    mem = SequenceMemory(n_inputs=db.shape[1])
    mem.run(db)
    v = mem.view()
    bit_cols, bit_len = np.ascontiguousarray(v.bit_cols), np.ascontiguousarray(v.bit_len)
    n_cols = int(bit_cols[np.arange(bit_cols.shape[1])[None, :] < bit_len[:, None]].max()) + 1
    print(f"{a.size:,} database frames: {n_cols:,} minicolumns, {bit_len.mean():.0f} per input bit; "
          f"{a.frames:,} query frames")
    ptr, ind = q.indptr[:a.frames + 1].astype(np.int64), q.indices.astype(np.int64)
    counts, touched = np.zeros(n_cols, np.int32), np.zeros(n_cols, np.int32)
    c2, t2, n2 = np.zeros((2, n_cols), np.int32), np.zeros((2, n_cols), np.int32), np.zeros(2, np.int64)
    for _ in range(a.repeats):
        t0 = time.perf_counter()
        x = sequential(ptr, ind, bit_cols, bit_len, counts, touched)
        t1 = time.perf_counter()
        y = split(ptr, ind, bit_cols, bit_len, counts, touched, c2, t2, n2)
        t2_ = time.perf_counter()
        print(f"one thread {(t1 - t0) * 1e3 / a.frames:.3f} ms a frame, two halves on two threads "
              f"{(t2_ - t1) * 1e3 / a.frames:.3f} ms a frame, the same counts: {x == y}")


if __name__ == "__main__":
    main()
