"""What a :class:`vpr.shosm.SequenceMemory` has learned, read-only."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["MemoryView", "Connections", "readonly"]


class MemoryView(NamedTuple):
    """Read-only views of what a :class:`SequenceMemory` has learned (``mem.view()``), for compiled kernels.

    Valid until the memory learns again (take a new view after each learning step).

    Attributes
    ----------
    bit_cols, bit_len : int32 arrays, n_inputs x width and n_inputs
        Row ``b``: the minicolumns connected to input bit ``b`` in its first ``bit_len[b]`` entries (line 3).
    e_src, e_dst : int64 arrays, n_connections
        Lateral connections ``e_src[k] -> e_dst[k]`` in the order learned (append-only).
    column_sizes : int64 array, n_columns
        Input bits of every minicolumn.
    thresholds : int32 array, n_columns
        Overlap a minicolumn needs to be active.
    n_columns, cells_per_column : int
    """

    bit_cols: np.ndarray
    bit_len: np.ndarray
    e_src: np.ndarray
    e_dst: np.ndarray
    column_sizes: np.ndarray
    thresholds: np.ndarray
    n_columns: int
    cells_per_column: int

    @property
    def n_cells(self) -> int:
        return self.n_columns * self.cells_per_column


def readonly(a: np.ndarray) -> np.ndarray:
    v = a.view()
    v.flags.writeable = False
    return v


class Connections:
    """Read-only copy of what a :class:`SequenceMemory` has learned (``mem.connections``), as htm.core's.

    Attributes
    ----------
    feedforward : scipy.sparse.csr_matrix, bool, n_columns x n_inputs
        Row ``m``: the input bits minicolumn ``m`` connects to (line 3).
    lateral : scipy.sparse.csr_matrix, bool, n_cells x n_cells
        ``lateral[s, d]``: cell ``s`` predicts cell ``d`` (lines 12-13).
    thresholds : ndarray, int64, n_columns
        ``ceil(threshold * size)``.
    cells_per_column, n_columns, n_cells, n_connections : int
    """

    def __init__(self, feedforward, lateral, thresholds, cells_per_column):
        self.feedforward = feedforward
        self.lateral = lateral
        self.thresholds = thresholds
        self.cells_per_column = int(cells_per_column)
        for a in (feedforward.data, feedforward.indices, feedforward.indptr, lateral.data, lateral.indices,
                  lateral.indptr, thresholds):
            a.flags.writeable = False

    @property
    def n_columns(self) -> int:
        return self.feedforward.shape[0]

    @property
    def n_cells(self) -> int:
        return self.lateral.shape[0]

    @property
    def n_connections(self) -> int:
        """Number of lateral connections."""
        return int(self.lateral.nnz)

    def column_sizes(self) -> np.ndarray:
        """Feed-forward connections (input bits) of every minicolumn, int64."""
        return np.diff(self.feedforward.indptr).astype(np.int64)

    def column_of(self, cells) -> np.ndarray:
        """Minicolumn of each cell index."""
        return np.asarray(cells, dtype=np.int64) // self.cells_per_column

    def columns_of_bit(self, bit: int) -> np.ndarray:
        """Minicolumns connected to input ``bit`` (sorted)."""
        return np.flatnonzero(self.feedforward[:, int(bit)].toarray().ravel())

    def __repr__(self) -> str:
        return (f"Connections(columns={self.n_columns}, cells={self.n_cells}, "
                f"lateral={self.n_connections}, feedforward={self.feedforward.nnz})")
