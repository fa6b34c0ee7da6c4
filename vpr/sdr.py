"""Sparse distributed representations (SDRs)."""
from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
import scipy.sparse as sp

__all__ = [
    "UNMOVED_SHARE",
    "from_indices",
    "from_dense",
    "from_topk",
    "to_indices",
    "row_bits",
    "check_batch",
    "union",
    "density",
    "add_noise",
    "random_sdrs",
    "degenerate",
    "RowLog",
]


def _csr(indptr, indices, n_rows, n_bits) -> sp.csr_matrix:
    data = np.ones(len(indices), dtype=bool)
    m = sp.csr_matrix((data, indices, indptr), shape=(n_rows, n_bits))
    m.sort_indices()
    return m


def from_indices(rows: Sequence[Iterable[int]], n_bits: int) -> sp.csr_matrix:
    """An SDR batch from one array of active-bit indices per row (duplicates merged).

    A non-positive ``n_bits`` or a negative, out-of-range or non-integer index raise ValueError naming the row.
    """
    n_bits = int(n_bits)
    if n_bits <= 0:
        raise ValueError(f"n_bits must be positive, got {n_bits}")
    indptr = [0]
    chunks = []
    for r, idx in enumerate(rows):
        a = np.asarray(list(idx) if not isinstance(idx, np.ndarray) else idx)
        if a.size == 0:
            a = np.zeros(0, dtype=np.int64)
        if a.ndim != 1:
            raise ValueError(f"row {r}: expected a 1-D array of bit indices, got shape {a.shape}")
        if a.dtype.kind == "f":
            if np.isnan(a).any():
                raise ValueError(f"row {r}: NaN in bit indices")
            if not np.all(a == np.round(a)):
                raise ValueError(f"row {r}: non-integer bit indices")
        elif a.dtype.kind not in "iub":
            raise ValueError(f"row {r}: bit indices must be integers, got dtype {a.dtype}")
        a = a.astype(np.int64)
        if a.size and (a.min() < 0 or a.max() >= n_bits):
            bad = a[(a < 0) | (a >= n_bits)][0]
            raise ValueError(f"row {r}: bit index {bad} outside [0, {n_bits})")
        a = np.unique(a)
        chunks.append(a)
        indptr.append(indptr[-1] + a.size)
    indices = np.concatenate(chunks) if chunks else np.zeros(0, dtype=np.int64)
    return _csr(np.asarray(indptr, dtype=np.int64), indices, len(chunks), n_bits)


def from_dense(array) -> sp.csr_matrix:
    """Build an SDR batch from a dense 0/1 (or bool) array of shape (frames, bits).

    A 1-D array is taken as a single row.
    """
    a = np.asarray(array)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2:
        raise ValueError(f"expected a 2-D (frames x bits) array, got shape {a.shape}")
    if a.dtype != bool:
        if a.dtype.kind == "f":
            nan_rows = np.flatnonzero(np.isnan(a).any(axis=1))
            if nan_rows.size:
                raise ValueError(f"row {nan_rows[0]}: NaN in SDR")
        bad = (a != 0) & (a != 1)
        if bad.any():
            r = int(np.flatnonzero(bad.any(axis=1))[0])
            raise ValueError(f"row {r}: SDR values must be 0 or 1")
        a = a.astype(bool)
    return sp.csr_matrix(a)


#: Entries per block of rows in :func:`from_topk` (about 32 MB per float64 temporary).
_SORT_BLOCK = 2**22


def from_topk(values, k: int) -> sp.csr_matrix:
    """SDR with exactly ``k`` bits per row: the ``k`` largest entries of each row.

    Ties are broken by the lower index so the result is deterministic. Rows are sorted a block at a time: the float64
    copy and the sort's indices of a whole 50,000-frame traverse would take several GB.
    """
    values = np.asarray(values)
    if values.ndim == 1:
        values = values[None, :]
    if values.ndim != 2:
        raise ValueError(f"expected a 2-D (frames x dims) array, got shape {values.shape}")
    n, d = values.shape
    k = int(k)
    if not 0 < k <= d:
        raise ValueError(f"k must be in [1, {d}], got {k}")
    idx = np.empty((n, k), np.int64)
    step = max(1, _SORT_BLOCK // max(d, 1))
    for r0 in range(0, n, step):
        v = values[r0:r0 + step].astype(np.float64)
        nan_rows = np.flatnonzero(np.isnan(v).any(axis=1))
        if nan_rows.size:
            raise ValueError(f"row {r0 + nan_rows[0]}: NaN in descriptor")
        # stable sort on -v keeps the lower index first among ties
        idx[r0:r0 + step] = np.argsort(-v, axis=1, kind="stable")[:, :k]
    idx.sort(axis=1)
    indptr = np.arange(0, n * k + 1, k, dtype=np.int64)
    return _csr(indptr, idx.ravel(), n, d)



def to_indices(batch: sp.csr_matrix) -> list[np.ndarray]:
    """List of active-bit index arrays, one per row."""
    b = check_batch(batch)
    return [b.indices[b.indptr[i]:b.indptr[i + 1]].copy() for i in range(b.shape[0])]


def row_bits(row, n_bits: int, name: str = "SDR row") -> np.ndarray:
    """Sorted active-bit indices (int64) of one SDR row: a 1-row batch, a dense row or bit indices.

    A 1-D array of exactly ``n_bits`` values is a dense row (bool or 0/1, else refused); any other integer array holds
    indices. Several rows, a wrong width or an index out of range raise ValueError naming ``name``.
    """
    n_bits = int(n_bits)
    if sp.issparse(row):
        b = check_batch(row, n_bits=n_bits, name=name)
        if b.shape[0] != 1:
            raise ValueError(f"{name}: one SDR row expected, got {b.shape[0]} rows")
        return b.indices.astype(np.int64)
    a = np.asarray(row)
    if a.ndim == 2 and a.shape[0] == 1:
        a = a[0]
    if a.ndim != 1:
        raise ValueError(f"{name} has shape {a.shape}: one row expected (dense {n_bits} bits or bit indices)")
    if a.dtype == bool:
        if a.size != n_bits:
            raise ValueError(f"{name} has shape {a.shape}, expected ({n_bits},)")
        return np.flatnonzero(a).astype(np.int64)
    if a.size == n_bits and a.size > 0:
        if not np.issubdtype(a.dtype, np.integer) and not np.issubdtype(a.dtype, np.floating):
            raise ValueError(f"{name} of dtype {a.dtype}: expected bool, 0/1 or bit indices")
        if not np.isin(a, (0, 1)).all():
            raise ValueError(f"{name} of {a.size} values (= n_bits) that are not all 0/1: ambiguous; "
                             f"pass a dense bool/0-1 row of {n_bits} values or fewer bit indices")
        return np.flatnonzero(a).astype(np.int64)
    if a.size and not np.issubdtype(a.dtype, np.integer):
        raise ValueError(f"{name}: bit indices must be integers, got dtype {a.dtype}")
    a = np.unique(a.astype(np.int64))
    if a.size and (a[0] < 0 or a[-1] >= n_bits):
        bad = a[0] if a[0] < 0 else a[-1]
        raise ValueError(f"{name}: bit index {bad} outside [0, {n_bits})")
    return a


def check_batch(batch, n_bits: int | None = None, name: str = "SDR batch") -> sp.csr_matrix:
    """An SDR batch (sparse or dense 0/1) as a canonical bool CSR matrix.

    Wrong width, non-binary values or NaN raise ValueError naming the first bad row.
    """
    if not sp.issparse(batch):
        b = from_dense(batch)
    else:
        b = sp.csr_matrix(batch)
        if b.dtype != bool:
            d = b.data
            if d.dtype.kind == "f" and np.isnan(d).any():
                r = int(np.searchsorted(b.indptr, np.flatnonzero(np.isnan(d))[0], side="right") - 1)
                raise ValueError(f"{name}: row {r}: NaN in SDR")
            bad = (d != 0) & (d != 1)
            if bad.any():
                r = int(np.searchsorted(b.indptr, np.flatnonzero(bad)[0], side="right") - 1)
                raise ValueError(f"{name}: row {r}: SDR values must be 0 or 1")
            b = b.astype(bool)
        b.eliminate_zeros()
        b.sum_duplicates()
        b.sort_indices()
    if n_bits is not None and b.shape[1] != n_bits:
        raise ValueError(f"{name}: expected {n_bits} bits per row, got {b.shape[1]}")
    return b


def union(batch) -> np.ndarray:
    """Indices of bits active in any row of the batch."""
    b = check_batch(batch)
    return np.unique(b.indices)


def density(batch) -> np.ndarray:
    """Fraction of active bits per row."""
    b = check_batch(batch)
    return np.diff(b.indptr) / b.shape[1]


def add_noise(batch, fraction: float, seed=None) -> sp.csr_matrix:
    """Move ``fraction`` of each row's 1-bits to random previously inactive positions.

    This is the paper's noise parameter n (section 5.2): with 40 active bits and n = 0.5, 20 bits are moved. The
    number moved per row is ``round(fraction * active)``; the row keeps its number of active bits.
    """
    if not 0.0 <= fraction <= 1.0 or not np.isfinite(fraction):
        raise ValueError(f"fraction must be in [0, 1], got {fraction}")
    b = check_batch(batch)
    rng = np.random.default_rng(seed)
    n_bits = b.shape[1]
    rows = []
    for r in range(b.shape[0]):
        act = b.indices[b.indptr[r]:b.indptr[r + 1]]
        n_move = int(round(fraction * act.size))
        if n_move == 0:
            rows.append(act)
            continue
        if act.size + n_move > n_bits:
            raise ValueError(f"row {r}: not enough free bits to move {n_move} of {act.size}")
        keep = rng.choice(act, size=act.size - n_move, replace=False)
        # rejection sampling of free positions: cheap because SDRs are sparse
        taken = set(act.tolist())
        new = []
        while len(new) < n_move:
            cand = rng.integers(0, n_bits, size=2 * n_move)
            for c in cand.tolist():
                if c not in taken:
                    taken.add(c)
                    new.append(c)
                    if len(new) == n_move:
                        break
        rows.append(np.concatenate([keep, np.asarray(new, dtype=np.int64)]))
    return from_indices(rows, n_bits)


def random_sdrs(n: int, n_bits: int = 2048, n_active: int = 40, seed=None) -> sp.csr_matrix:
    """``n`` independent random SDRs with exactly ``n_active`` bits each."""
    if n_active > n_bits:
        raise ValueError(f"n_active ({n_active}) > n_bits ({n_bits})")
    rng = np.random.default_rng(seed)
    idx = np.argsort(rng.random((n, n_bits)), axis=1)[:, :n_active] if n * n_bits <= 5e7 else \
        np.stack([rng.choice(n_bits, n_active, replace=False) for _ in range(n)])
    return from_indices(list(idx), n_bits)


#: The share of a frame's active bits kept from the frame before at which the camera did not move (:func:`unmoved`):
#: between what consecutive frames of a moving camera keep and what those of a standing camera keep
#: (``research/docs/decisions.md``, "Stands and direction").
UNMOVED_SHARE = 0.6


def unmoved(batch, share: float) -> np.ndarray:
    """Per frame of ``batch``, whether at least ``share`` of its active bits were active in the frame before (the
    first frame and an empty row: False): as a sequence memory of threshold ``share`` sees it, the camera did not
    move between them."""
    b = check_batch(batch)
    if b.shape[0] < 2:
        return np.zeros(b.shape[0], bool)
    kept = np.asarray(b[1:].multiply(b[:-1]).sum(axis=1)).ravel()
    size = np.diff(b.indptr)[1:]
    return np.r_[False, (size > 0) & (kept >= float(share) * size)]


def kept_share(bits: np.ndarray, before: np.ndarray) -> float:
    """The share of the active bits ``bits`` (indices) that were active in ``before`` (0 for an empty row)."""
    return float(np.isin(bits, before).sum() / bits.size) if bits.size else 0.0


def degenerate(x, duplicate_share: float = 0.1) -> str | None:
    """What is wrong with an SDR batch whose frames cannot be told apart: empty rows, or many identical rows.

    None when nothing is: no empty row, and fewer than ``duplicate_share`` of the frames repeat an earlier frame's SDR
    exactly (a stop repeats a few).
    """
    x = sp.csr_matrix(x)
    n = x.shape[0]
    if n == 0:
        return None
    empty = int((np.diff(x.indptr) == 0).sum())
    dup = n - len({x.indices[x.indptr[i]:x.indptr[i + 1]].tobytes() for i in range(n)})
    parts = []
    if empty:
        parts.append(f"{empty} of {n} frames have an empty SDR")
    if dup >= max(1, duplicate_share * n):
        parts.append(f"{dup} of {n} frames repeat another frame's SDR exactly")
    return "; ".join(parts) or None


class RowLog:
    """The SDR rows of a stream as they come, in CSR form (``ptr``, ``ind``), appended in amortised O(bits).

    ``ptr``, ``ind``: the rows so far (views: valid until the next :meth:`append`); start from a batch's ``indptr``
    and ``indices`` (or nothing).
    """

    def __init__(self, ptr=None, ind=None):
        self._ptr = np.array([0] if ptr is None else ptr, np.int64)
        self._ind = np.array([] if ind is None else ind, np.int64)
        if self._ptr.ndim != 1 or self._ptr.size < 1 or self._ptr[0] != 0 or int(self._ptr[-1]) != self._ind.size \
                or (np.diff(self._ptr) < 0).any():
            raise ValueError(f"RowLog: ptr must start at 0, never fall and end at the {self._ind.size} indices")
        self.rows = self._ptr.size - 1

    @property
    def ptr(self) -> np.ndarray:
        return self._ptr[: self.rows + 1]

    @property
    def ind(self) -> np.ndarray:
        return self._ind[: int(self._ptr[self.rows])]

    def append(self, bits) -> None:
        """Append the next row's active bits."""
        bits = np.asarray(bits, np.int64)
        n, end = self.rows, int(self._ptr[self.rows])
        if n + 2 > self._ptr.size:
            self._ptr = np.resize(self._ptr, 2 * (n + 2))
        if end + bits.size > self._ind.size:
            self._ind = np.resize(self._ind, max(2 * self._ind.size, end + bits.size))
        self._ind[end:end + bits.size] = bits
        self._ptr[n + 1] = end + bits.size
        self.rows = n + 1
