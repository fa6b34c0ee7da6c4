"""Similarity matrices between SDR batches or dense descriptors, and what every method does with them."""
from __future__ import annotations

import contextlib
import contextvars

import numpy as np
import scipy.sparse as sp
from numba import njit

from vpr import sdr as _sdr
from vpr.bitsets import bitsets_pay, overlap_topk_bitsets, pack_bits
from vpr.checks import check_top_k, physical_memory

__all__ = ["overlap_similarity", "overlap_count", "stationary", "sdr_overlap_rows", "sdr_candidates", "cosine",
           "neg_sad", "mean_abs_diff", "topk_sparse", "DENSE_PAIRS_LIMIT", "DENSE_BYTES_PER_PAIR",
           "dense_budget", "dense_pairs", "default_dense_budget", "budget_setting",
           "best_matches", "mask_recent", "fits_dense", "top_k_or_dense", "check_dense", "pack_bits", "bitsets_pay",
           "TOP_K", "candidate_limit", "n_candidates"]

#: Above this many database x query pairs a dense matrix is never built, whatever the memory budget.
DENSE_PAIRS_LIMIT = 20_000 * 20_000
#: Peak bytes per database x query pair of a run that holds its matrices dense (SeqSLAM's difference and
#: enhanced matrices, the similarity, the ground truth; ``research/docs/benchmarks.md``, "Memory at the dense switch").
DENSE_BYTES_PER_PAIR = 40
_BUDGET: contextvars.ContextVar[int | None] = contextvars.ContextVar("dense_budget", default=None)


def default_dense_budget() -> int:
    """Bytes the dense matrices of a run may take by default: an eighth of this machine's memory (2 GiB where
    the system does not say)."""
    total = physical_memory()
    return 2**31 if total is None else total // 8



@contextlib.contextmanager
def dense_budget(nbytes: int | None):
    """Within the block, dense matrices take at most ``nbytes`` (None: :func:`default_dense_budget`)."""
    token = _BUDGET.set(None if nbytes is None else int(nbytes))
    try:
        yield
    finally:
        _BUDGET.reset(token)


def budget_setting() -> dict:
    """The memory budget in force as a run records it: ``bytes``, ``given`` (by ``--memory-budget``, or the
    default), ``dense_pairs`` and ``text``."""
    given = _BUDGET.get()
    budget, n = _budget(), dense_pairs()
    return {"bytes": budget, "given": given is not None, "dense_pairs": n,
            "text": f"{budget / 2**30:.2f} GiB: matrices dense up to {n:,} pairs ({int(n ** 0.5):,} x "
                    f"{int(n ** 0.5):,} frames), top-K beyond"}


def dense_pairs() -> int:
    """Database x query pairs above which matrices are top-K: the memory budget over
    :data:`DENSE_BYTES_PER_PAIR`, at most :data:`DENSE_PAIRS_LIMIT` (both read at call time)."""
    return min(DENSE_PAIRS_LIMIT, _budget() // DENSE_BYTES_PER_PAIR)


def _budget() -> int:
    """Bytes of the budget in force."""
    given = _BUDGET.get()
    return default_dense_budget() if given is None else given

# Pairs per dense block when assembling top-K output: the block, its negation and argpartition's int64 indices take
# about 16 bytes per pair (64 MiB here).
_BLOCK_PAIRS = 2**22


def _norm_overlap_block(A, B, na, nb):
    ov = (A @ B.T).toarray().astype(np.float32)
    denom = np.sqrt(np.outer(na, nb)).astype(np.float32)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(denom > 0, ov / np.where(denom > 0, denom, 1), 0.0)
    return out.astype(np.float32)


def overlap_similarity(A, B=None, top_k: int | None = None, normalise: bool = True, chunk: int = 2048):
    """Normalised overlap |a & b| / sqrt(|a| |b|) between the rows of SDR batches (0 for an empty row).

    Parameters
    ----------
    A : SDR batch (database), shape (n_db, n_bits)
    B : SDR batch (query), shape (n_q, n_bits); ``None`` compares ``A`` with itself.
    top_k : int, optional
        Keep each query's ``top_k`` highest database entries (a csr_matrix, no size limit); required above
        :func:`dense_pairs`.
    normalise : bool
        ``False``: raw overlap counts.
    chunk : int
        Queries per top-K block (fewer for a large ``n_db``).

    Returns float32 (n_db, n_q), or a csr_matrix with ``top_k``. An invalid batch or a dense output above
    :func:`dense_pairs` raise ValueError before any work.
    """
    A = _sdr.check_batch(A, name="database SDRs")
    B = A if B is None else _sdr.check_batch(B, n_bits=A.shape[1], name="query SDRs")
    Ai = A.astype(np.int32)
    Bi = Ai if B is A else B.astype(np.int32)
    na = np.diff(A.indptr).astype(np.float64)
    nb = np.diff(B.indptr).astype(np.float64)
    if not normalise:
        na = nb = None
    if top_k is None:
        if not fits_dense(A.shape[0], B.shape[0]):
            raise ValueError(
                f"{A.shape[0]} x {B.shape[0]} pairs exceed the dense limit of {dense_pairs()} (the memory "
                f"budget); pass top_k")
        if na is None:
            return (Ai @ Bi.T).toarray().astype(np.float32)
        return _norm_overlap_block(Ai, Bi, na, nb)

    if bitsets_pay(A, B):
        return overlap_topk_bitsets(A, B, na, nb, top_k)

    def block(q0, q1):
        if na is None:
            return (Ai @ Bi[q0:q1].T).toarray().astype(np.float32)
        return _norm_overlap_block(Ai, Bi[q0:q1], na, nb[q0:q1])

    return topk_sparse(block, A.shape[0], B.shape[0], top_k, chunk)


def overlap_count(a, b=None) -> np.ndarray:
    """Overlap counts |a_i & b_j| between the rows of two SDR batches (dense int array).

    For the normalised similarity matrix, and for large batches (``top_k``), use :func:`overlap_similarity`.
    """
    A = _sdr.check_batch(a).astype(np.int32)
    B = A if b is None else _sdr.check_batch(b, n_bits=A.shape[1]).astype(np.int32)
    return np.asarray((A @ B.T).toarray(), dtype=np.int64)




@njit(cache=True)
def _overlap(ptr, ind, a, b):
    i, j, c = ptr[a], ptr[b], 0
    while i < ptr[a + 1] and j < ptr[b + 1]:
        if ind[i] == ind[j]:
            c += 1
            i += 1
            j += 1
        elif ind[i] < ind[j]:
            i += 1
        else:
            j += 1
    return c


@njit(cache=True)
def stationary(ptr, ind, b, j, ratio, n_bits):  # pragma: no cover - compiled
    """Whether the camera never left place ``b`` before frame ``j`` (rows of a batch's sorted CSR ``ptr``, ``ind``, of
    ``n_bits`` columns).

    A loop closure means the camera went elsewhere and came back: some frame between ``b`` and ``j`` shares fewer than
    ``ratio`` times the bits ``b`` shares with ``j``. When every frame in between keeps at least that much, the
    vehicle stood still or crept (a station, a traffic light): a stop, not a loop. Bits are counted beyond what two
    rows share by chance (``|row k| * |row j| / n_bits``): frames that share nothing beyond it are not one place, and
    the chance overlap every frame has with ``j`` is no sign that the camera stood.
    """
    size_j = ptr[j + 1] - ptr[j]
    e_b = _overlap(ptr, ind, b, j) - (ptr[b + 1] - ptr[b]) * size_j / n_bits
    if e_b <= 0.0:
        return False
    for k in range(b + 1, j):
        if _overlap(ptr, ind, k, j) - (ptr[k + 1] - ptr[k]) * size_j / n_bits < ratio * e_b:
            return False
    return True


@njit(cache=True, nogil=True)
def sdr_overlap_rows(indptr, indices, r0, r1, qptr, qcols, out):  # pragma: no cover - compiled
    # overlap counts of database rows r0..r1 with the block's queries, through the block's inverted index (bit ->
    # query columns): cost ~ active bits x postings
    for r in range(r0, r1):
        lr = r - r0
        for p in range(indptr[r], indptr[r + 1]):
            b = indices[p]
            for t in range(qptr[b], qptr[b + 1]):
                out[lr, qcols[t]] += 1


@njit(cache=True, nogil=True)
def sdr_candidates(post_ptr, post_rows, q_indptr, q_indices, k, counts, out):  # pragma: no cover - compiled
    # Single-frame candidates: per query the k database rows of largest overlap, through the database's inverted index
    # (bit -> rows). Rows reaching an overlap of 2 are listed as they do (random rows rarely do, so the list is
    # short); a histogram of their counts gives the k-th largest without sorting. Only if fewer than k rows reach 2
    # are rows with overlap 1 added. ``counts`` (n_db, zeros) is uint16 when overlaps fit: half the cache footprint.
    n_db = counts.shape[0]
    listed = np.empty(n_db + 1, np.int64)
    max_bits = 0
    for q in range(q_indptr.shape[0] - 1):
        max_bits = max(max_bits, q_indptr[q + 1] - q_indptr[q])
    hist = np.zeros(max_bits + 2, np.int64)
    for q in range(q_indptr.shape[0] - 1):
        counts[:] = 0
        nl = 0
        for p in range(q_indptr[q], q_indptr[q + 1]):
            b = q_indices[p]
            for t in range(post_ptr[b], post_ptr[b + 1]):
                r = post_rows[t]
                c = counts[r] + 1
                counts[r] = c
                listed[nl] = r                   # branch-free: no unpredictable branch in the inner loop
                nl += c == 2
        for t in range(nl):
            hist[counts[listed[t]]] += 1
        thr = 2
        cum = 0
        for c in range(max_bits, 1, -1):
            if cum + hist[c] >= k:
                thr = c
                break
            cum += hist[c]
        n_out = 0
        for t in range(nl):                      # strictly above the threshold: all fit
            if counts[listed[t]] > thr:
                out[q, n_out] = listed[t]
                n_out += 1
        for t in range(nl):                      # at the threshold: in listing order until k
            if n_out == k:
                break
            if counts[listed[t]] == thr:
                out[q, n_out] = listed[t]
                n_out += 1
        if n_out < k:                            # few rows share 2 bits: fill with overlap 1, lowest rows first
            for r in range(n_db):
                if n_out == k:
                    break
                if counts[r] == 1:
                    out[q, n_out] = r
                    n_out += 1
        hist[:] = 0


def _check_top_k(top_k) -> int:
    top_k = int(top_k)
    top_k = check_top_k(top_k, nullable=False)
    return top_k


def topk_sparse(block_fn, n_db: int, n_q: int, top_k: int, chunk: int = 2048) -> sp.csr_matrix:
    """Assemble a sparse db x query matrix keeping the ``top_k`` db entries per query.

    ``block_fn(q0, q1)`` returns the dense (n_db x (q1 - q0)) similarity block. Entries that are exactly representable
    as 0 but kept are stored explicitly so that "kept with score 0" and "not kept" stay distinguishable. Blocks hold
    at most ``chunk`` queries and about 2**22 pairs, and only the kept entries of each block are retained, so memory
    grows with ``n_q * top_k``, not with ``n_db * n_q``.
    """
    top_k = _check_top_k(top_k)
    k = min(top_k, n_db)
    chunk = max(1, min(int(chunk), _BLOCK_PAIRS // max(n_db, 1)))
    rows, cols, vals = [], [], []
    for q0 in range(0, n_q, chunk):
        q1 = min(q0 + chunk, n_q)
        S = block_fn(q0, q1)
        # copy: a slice would keep the whole n_db x block argpartition output alive
        idx = np.argpartition(-S, k - 1, axis=0)[:k].copy() if k < n_db else np.broadcast_to(
            np.arange(n_db)[:, None], (n_db, q1 - q0))
        rows.append(idx.ravel())
        cols.append(np.broadcast_to(np.arange(q0, q1), idx.shape).ravel())
        vals.append(np.take_along_axis(S, idx, axis=0).ravel())
    r = np.concatenate(rows) if rows else np.zeros(0, int)
    c = np.concatenate(cols) if cols else np.zeros(0, int)
    v = np.concatenate(vals).astype(np.float32) if vals else np.zeros(0, np.float32)
    # coo -> csr sums duplicates; there are none since each (db, q) appears once
    m = sp.coo_matrix((v, (r, c)), shape=(n_db, n_q)).tocsr()
    return m


def _as_2d_float(X, name):
    X = np.asarray(X, dtype=np.float32)
    if X.ndim == 1:
        X = X[None, :]
    if X.ndim != 2:
        X = X.reshape(X.shape[0], -1)
    if not np.isfinite(X).all():
        r = int(np.flatnonzero(~np.isfinite(X).all(axis=1))[0])
        raise ValueError(f"{name}: row {r} has NaN or infinite values")
    return X


def cosine(X, Y=None) -> np.ndarray:
    """Cosine similarity between dense descriptor rows (db x query, float32).

    Zero vectors have similarity 0 to everything.
    """
    X = _as_2d_float(X, "database descriptors")
    Y = X if Y is None else _as_2d_float(Y, "query descriptors")
    if X.shape[1] != Y.shape[1]:
        raise ValueError(f"descriptor sizes differ: database {X.shape[1]}, query {Y.shape[1]}")
    nx = np.linalg.norm(X, axis=1)
    ny = np.linalg.norm(Y, axis=1)
    Xn = X / np.where(nx > 0, nx, 1)[:, None]
    Yn = Y / np.where(ny > 0, ny, 1)[:, None]
    return (Xn @ Yn.T).astype(np.float32)


@njit(cache=True, fastmath=True, nogil=True)
def _sad_block(a, b, out):  # pragma: no cover - compiled
    # tiled over b: a few rows of b stay in cache while every row of a streams past them
    n, d = a.shape
    m = b.shape[0]
    tile = 64
    for j0 in range(0, m, tile):
        j1 = min(j0 + tile, m)
        for i in range(n):
            for j in range(j0, j1):
                s = np.float32(0.0)
                for k in range(d):
                    s += abs(a[i, k] - b[j, k])
                out[i, j] = s / d


def mean_abs_diff(X, Y=None) -> np.ndarray:
    """Mean absolute difference between dense descriptor rows (db x query, float32; lower = more similar)."""
    X = _as_2d_float(X, "database descriptors")
    Y = X if Y is None else _as_2d_float(Y, "query descriptors")
    if X.shape[1] != Y.shape[1]:
        raise ValueError(f"descriptor sizes differ: database {X.shape[1]}, query {Y.shape[1]}")
    out = np.empty((X.shape[0], Y.shape[0]), dtype=np.float32)
    _sad_block(np.ascontiguousarray(X), np.ascontiguousarray(Y), out)
    return out


def neg_sad(X, Y=None) -> np.ndarray:
    """Negative mean absolute difference between dense descriptor rows (db x query).

    The similarity of SeqSLAM's difference matrix: 0 for identical rows, lower (more negative) for more different
    ones.
    """
    return -mean_abs_diff(X, Y)


# ------------------------------------------------------------------ what methods do with S
def fits_dense(n_db: int, n_q: int, limit: int | None = None) -> bool:
    """Whether a dense ``n_db x n_q`` matrix is within :func:`dense_pairs` and ``limit``."""
    return n_db * n_q <= (dense_pairs() if limit is None else min(dense_pairs(), limit))


#: Frames kept per query where a dense matrix would be too large (every method's ``top_k``, SeqSLAM's
#: single-frame candidates): the one default of the project.
TOP_K = 50


def top_k_or_dense(n_db: int, n_q: int, top_k: int, dense_pairs: int | None = None) -> int | None:
    """``top_k`` when a dense ``n_db x n_q`` matrix would exceed :func:`dense_pairs`, else None.

    ``dense_pairs``: a method's own, lower switch (where its top-K path becomes the faster one).
    """
    return None if fits_dense(n_db, n_q, dense_pairs) else top_k


def check_dense(what: str, n_db: int, n_q: int, hint: str = "subsample the traverses (--step)") -> None:
    """Refuse a dense ``n_db x n_q`` matrix above :func:`dense_pairs` (before any work is done)."""
    if not fits_dense(n_db, n_q):
        need = n_db * n_q * DENSE_BYTES_PER_PAIR / 2**30
        raise ValueError(f"{what} needs a dense {n_db} x {n_q} matrix (about {need:.1f} GiB, above the memory "
                         f"budget: {dense_pairs()} pairs; --memory-budget); {hint}")


def best_matches(S) -> tuple[np.ndarray, np.ndarray]:
    """Best database index and its score per query of a dense or sparse db x query matrix.

    Ties go to the lowest database index. Queries without any stored entry (sparse) get ``best_db = -1`` and score
    ``-inf``.
    """
    if sp.issparse(S):
        S = sp.csc_matrix(S)
        n_q = S.shape[1]
        best = np.full(n_q, -1, dtype=np.int64)
        score = np.full(n_q, -np.inf, dtype=np.float64)
        counts = np.diff(S.indptr)
        cols = np.repeat(np.arange(n_q), counts)
        # within each column: highest value first, then the lowest row
        order = np.lexsort((S.indices, -S.data.astype(np.float64), cols))
        have = np.flatnonzero(counts)
        first = order[S.indptr[have]]
        best[have], score[have] = S.indices[first], S.data[first]
        return best, score
    S = np.asarray(S)
    best = np.argmax(S, axis=0).astype(np.int64)
    return best, S[best, np.arange(S.shape[1])].astype(np.float64)


def n_candidates(j: int, exclude: int, start: int = 0) -> int:
    """Frames ``0 .. n - 1`` are frame ``j``'s loop-closure candidates: those at least ``exclude`` back, and every
    frame of the earlier sessions (this one began at ``start``); the rule of :func:`candidate_limit`, one frame."""
    return max(j - max(int(exclude), 1) + 1, start, 0)


def candidate_limit(T: int, exclude: int, starts=None) -> np.ndarray:
    """``n[j]``: earlier frames ``0 .. n[j] - 1`` are frame ``j``'s loop-closure candidates.

    Those at least ``exclude`` back, and every frame of an earlier session (``starts``: the first frame of each
    session; ``exclude`` holds within one).
    """
    idx = np.arange(T)
    n = idx - max(int(exclude), 1) + 1
    if starts is not None and len(starts) > 1:
        starts = np.asarray(sorted(starts), np.int64)
        n = np.maximum(n, starts[np.searchsorted(starts, idx, side="right") - 1])
    return np.maximum(n, 0)


def mask_recent(S, exclude: int, starts=None):
    """Keep only the loop-closure candidates of a T x T loop matrix (:func:`candidate_limit`): earlier frames,
    far enough back within a session.

    Dense: other entries become ``-inf`` (a float32 copy); sparse: they are dropped.
    """
    n = candidate_limit(S.shape[1], exclude, starts)
    if sp.issparse(S):
        C = sp.coo_matrix(S)
        keep = C.row < n[C.col]
        return sp.csr_matrix((C.data[keep], (C.row[keep], C.col[keep])), shape=S.shape)
    S = np.array(S, dtype=np.float32, copy=True)
    i, j = np.indices(S.shape)
    S[i >= n[j]] = -np.inf
    return S
