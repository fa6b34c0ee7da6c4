"""SDR overlaps on packed bitsets: the top-K of every query by popcount of 64-bit words, where they pay."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numba import njit, types
from numba.extending import intrinsic

from vpr.checks import check_top_k

__all__ = ["bitsets_pay", "pack_bits", "overlap_topk_bitsets"]


def bitsets_pay(A, B, against: str = "product") -> bool:
    """Whether packed bit sets beat the other way to the top-K overlap of these batches.

    A pair costs about one 64-bit word with bit sets; the others cost with the bits two rows are expected to share.
    ``against``: ``"product"`` (:func:`overlap_similarity`'s sparse product) or ``"index"`` (a count through an
    inverted index). Winner codes never take bit sets. Figures: ``research/docs/benchmarks.md``.
    """
    n_bits = A.shape[1]
    words = -(-n_bits // 64)
    shared = (A.nnz / max(A.shape[0], 1)) * (B.nnz / max(B.shape[0], 1)) / max(n_bits, 1)
    if against == "index":
        return words <= 4 * shared
    if against != "product":
        raise ValueError(f"against must be 'product' or 'index', got {against!r}")
    return words <= 64 + 16 * shared


def pack_bits(A: sp.csr_matrix) -> np.ndarray:
    """The rows of an SDR batch as bit sets: uint64, n x ceil(n_bits / 64), bit ``b`` in word ``b // 64``."""
    A = sp.csr_matrix(A)
    out = np.zeros((A.shape[0], max(-(-A.shape[1] // 64), 1)), np.uint64)
    rows = np.repeat(np.arange(A.shape[0]), np.diff(A.indptr))
    cols = A.indices.astype(np.int64)
    np.bitwise_or.at(out, (rows, cols // 64), np.left_shift(np.uint64(1), (cols % 64).astype(np.uint64)))
    return out


def overlap_topk_bitsets(A, B, na, nb, top_k: int) -> sp.csr_matrix:
    """:func:`overlap_similarity` with ``top_k`` by popcounts of packed rows: the same values, no dense block.

    Of the frames tied at the K-th value, those of larger tie key are kept (a fixed pseudo-random order of the frame
    numbers): on aliased SDRs, where one appearance ties many places, the kept ones spread over the database instead
    of crowding its start (candidate windows need that).
    """
    top_k = check_top_k(int(top_k), nullable=False)
    n_db, n_q = A.shape[0], B.shape[0]
    k = min(top_k, n_db)
    pa = pack_bits(A)
    pb = pa if B is A else pack_bits(B)
    norm = na is not None
    na = na if norm else np.ones(n_db)
    nb = nb if norm else np.ones(n_q)
    idx = np.zeros((n_q, k), np.int64)
    val = np.zeros((n_q, k), np.float32)
    if k:
        _topk_overlap_kernel(pa, pb, na, nb, norm, idx, val)
    # per query the kept rows (kept zeros stored, as topk_sparse does)
    S = sp.csc_matrix((val.ravel(), idx.ravel(), np.arange(n_q + 1) * k), shape=(n_db, n_q)).tocsr()
    S.sort_indices()
    return S


@intrinsic
def _popcount(typingctx, x):  # pragma: no cover - compiled
    # LLVM's ctpop: one POPCNT instruction where the CPU has it (NumPy's bitwise_count is not in numba)
    if not isinstance(x, types.Integer):
        return None

    def codegen(context, builder, sig, args):
        return builder.ctpop(args[0])

    return x(x), codegen


@njit(cache=True, inline="always")
def _tie_key(d):  # pragma: no cover - compiled
    # Fibonacci hashing: a fixed permutation of the frame numbers that spreads any run of them
    return np.uint64(d) * np.uint64(0x9E3779B97F4A7C15)


@njit(cache=True, inline="always")
def _below(hv, hi, a, b):  # pragma: no cover - compiled
    # heap order: smaller value first; of equal values the smaller tie key (it leaves first)
    return hv[a] < hv[b] or (hv[a] == hv[b] and _tie_key(hi[a]) < _tie_key(hi[b]))


@njit(cache=True, inline="always")
def _sift_down(hv, hi, i, k):  # pragma: no cover - compiled
    # restore the heap below node i
    while True:
        m = 2 * i + 1
        if m >= k:
            return
        if m + 1 < k and _below(hv, hi, m + 1, m):
            m += 1
        if not _below(hv, hi, m, i):
            return
        hv[m], hv[i] = hv[i], hv[m]
        hi[m], hi[i] = hi[i], hi[m]
        i = m


@njit(cache=True, nogil=True)
def _topk_overlap_kernel(pa, pb, na, nb, norm, out_idx, out_val):  # pragma: no cover - compiled
    # A block of queries stays in L1 while every database row streams past it once; per query a min-heap of its k best
    # (value, frame): a database frame enters when it beats the heap's least.
    n_db, words = pa.shape
    n_q, k = out_idx.shape
    block = 32
    hv = np.empty((block, k), np.float32)
    hi = np.empty((block, k), np.int64)
    for q0 in range(0, n_q, block):
        nq = min(block, n_q - q0)
        for d in range(k):  # the first k frames fill the heaps; then heapify
            for j in range(nq):
                s = 0
                for w in range(words):
                    s += _popcount(pa[d, w] & pb[q0 + j, w])
                den = np.float32(np.sqrt(na[d] * nb[q0 + j])) if norm else np.float32(1.0)
                hv[j, d] = np.float32(s) / den if den > 0 else np.float32(0.0)
                hi[j, d] = d
        for j in range(nq):
            for i in range(k // 2 - 1, -1, -1):  # heapify
                _sift_down(hv[j], hi[j], i, k)
        for d in range(k, n_db):
            for j in range(nq):
                s = 0
                for w in range(words):
                    s += _popcount(pa[d, w] & pb[q0 + j, w])
                den = np.float32(np.sqrt(na[d] * nb[q0 + j])) if norm else np.float32(1.0)
                v = np.float32(s) / den if den > 0 else np.float32(0.0)
                if v > hv[j, 0] or (v == hv[j, 0] and _tie_key(d) > _tie_key(hi[j, 0])):
                    hv[j, 0] = v
                    hi[j, 0] = d
                    _sift_down(hv[j], hi[j], 0, k)
        for j in range(nq):
            for i in range(k):
                out_idx[q0 + j, i] = hi[j, i]
                out_val[q0 + j, i] = hv[j, i]
