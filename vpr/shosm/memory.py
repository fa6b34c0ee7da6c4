"""rSHOSM: the simplified HTM higher-order sequence memory of Neubert, Ahmad and
Protzel, "A Sequence-Based Neuronal Model for Mobile Robot Localization", KI 2018."""
from __future__ import annotations

import inspect
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from vpr import sdr as _sdr
from vpr.statefile import MemoryFileError, read_file, write_file

from .connections import Connections, MemoryView, readonly
from .kernels import memory as K

__all__ = ["SequenceMemory", "MemoryFileError", "pad_codes"]

_FORMAT = "vpr.SequenceMemory"
_FORMAT_VERSION = 1


class SequenceMemory:
    """Simplified higher-order sequence memory with randomised connections (rSHOSM, Algorithm 1).

    Parameters
    ----------
    n_inputs : int
        Width of the input SDRs (paper: 2048).
    cells_per_column : int
        Cells per minicolumn (paper: 32).
    new_columns : int
        Minicolumns created for an input that activates none (line 3; paper: 10).
    connectivity : float
        Fraction of the input's 1-bits each new minicolumn connects to (paper: 0.5).
    threshold : float
        A minicolumn is active at an overlap of at least this fraction of its connections (paper: 0.25).
    p_extra : float
        rSHOSM's probability of a lateral connection although the previous winner's minicolumn already connects to the
        cell (section 4.3; 0.0: SHOSM; paper 0.01, 0.05).
    k_active : int
        **Our extension:** with learning off and no minicolumn at the threshold, the ``k_active`` of highest non-zero
        overlap are active, so that a query still has winner cells.
    seed : int or None
        For the connections, ties between bursting cells and the rSHOSM coin flips.
    """

    def __init__(self, n_inputs: int = 2048, cells_per_column: int = 32, new_columns: int = 10,
                 connectivity: float = 0.5, threshold: float = 0.25, p_extra: float = 0.05,
                 k_active: int = 10, seed=0):
        p = self.check_params(n_inputs, cells_per_column, new_columns, connectivity, threshold, p_extra, k_active,
                              seed)
        self.n_inputs, self.cells_per_column, self.new_columns = p["n_inputs"], p["cells_per_column"], p["new_columns"]
        self.connectivity, self.threshold, self.p_extra = p["connectivity"], p["threshold"], p["p_extra"]
        self.k_active, self.seed = p["k_active"], seed
        self._rng = np.random.default_rng(seed)
        self._st = np.zeros(K.STATE_SIZE, dtype=np.int64)
        self._bit_cols = np.zeros((self.n_inputs, 16), dtype=np.int32)  # input bit -> minicolumns
        self._bit_len = np.zeros(self.n_inputs, dtype=np.int32)
        self._tape = np.zeros(0, dtype=np.float64)
        self._alloc_cols(64)
        self._alloc_edges(4096)
        # hash sets of (source minicolumn, target cell) and (source cell, target cell) keys
        self._col_cell = np.full(8192, -1, np.int64)
        self._edge_set = np.full(8192 if self.p_extra > 0 else 1, -1, np.int64)
        self.reset()

    # ------------------------------------------------------------ storage
    @staticmethod
    def _grown(arr, size, fill=0):
        out = np.full(size, fill, dtype=arr.dtype) if fill else np.zeros(size, dtype=arr.dtype)
        out[: arr.shape[0]] = arr
        return out

    def _alloc_cols(self, cap):
        cells = cap * self.cells_per_column
        if not hasattr(self, "_col_thr"):
            self._col_thr = np.zeros(cap, np.int32)
            self._counts = np.zeros(cap, np.int32)
            self._touched = np.zeros(cap, np.int64)
            self._active = np.zeros(cap, np.int64)
            self._out_head = np.full(cells, -1, np.int64)
            self._outdeg = np.zeros(cells, np.int32)
            self._is_pred = np.zeros(cells, bool)
            self._is_next = np.zeros(cells, bool)
            self._pred_list = np.zeros(cells, np.int64)
            self._next_list = np.zeros(cells, np.int64)
            self._prev = np.zeros(cells, np.int64)
            self._cur = np.zeros(cells, np.int64)
            return
        g = self._grown
        self._col_thr, self._counts = g(self._col_thr, cap), g(self._counts, cap)
        self._touched, self._active = g(self._touched, cap), g(self._active, cap)
        self._out_head = g(self._out_head, cells, -1)
        self._outdeg = g(self._outdeg, cells)
        self._is_pred, self._is_next = g(self._is_pred, cells), g(self._is_next, cells)
        self._pred_list, self._next_list = g(self._pred_list, cells), g(self._next_list, cells)
        self._prev, self._cur = g(self._prev, cells), g(self._cur, cells)

    def _alloc_bit_cols(self, width):
        grown = np.zeros((self.n_inputs, width), dtype=np.int32)
        grown[:, : self._bit_cols.shape[1]] = self._bit_cols
        self._bit_cols = grown

    def _alloc_edges(self, cap):
        if not hasattr(self, "_e_src"):
            self._e_src, self._e_dst = np.zeros(cap, np.int64), np.zeros(cap, np.int64)
            self._e_onext = np.zeros(cap, np.int64)
            return
        g = self._grown
        self._e_src, self._e_dst = g(self._e_src, cap), g(self._e_dst, cap)
        self._e_onext = g(self._e_onext, cap)

    # the kernel's array groups (see vpr.shosm.kernels.memory); rebuilt per call because growing replaces arrays
    def _ff(self):
        return self._bit_cols, self._bit_len, self._col_thr

    def _lat(self):
        return self._out_head, self._outdeg, self._e_src, self._e_dst, self._e_onext, self._col_cell, self._edge_set

    def _cells(self):
        return self._is_pred, self._is_next, self._pred_list, self._next_list, self._prev, self._cur

    def _rehash(self, need, edges=False):
        old = self._edge_set if edges else self._col_cell
        size = 1 << int(np.ceil(np.log2(max(need, 2 * old.size))))
        table = np.full(size, -1, np.int64)
        st = self._st
        n = K.rebuild_sets(table, self._e_src, self._e_dst, st[K.N_EDGES], 0 if edges else self.cells_per_column)
        if edges:
            self._edge_set = table
        else:
            self._col_cell = table
            st[K.N_KEYS] = n

    def _refill_tape(self, need):
        # keep the unread rest so the numbers are consumed exactly in generator order
        st = self._st
        rest = self._tape[st[K.TAPE_POS]: st[K.TAPE_LEN]]
        fresh = self._rng.random(max(int(need), 65536))
        self._tape = np.concatenate([rest, fresh])
        st[K.TAPE_POS] = 0
        st[K.TAPE_LEN] = self._tape.size

    # ------------------------------------------------------------------ state
    @property
    def n_columns(self) -> int:
        """Number of minicolumns created so far."""
        return int(self._st[K.N_COLS])

    @property
    def n_cells(self) -> int:
        """Number of cells (grows with the number of minicolumns)."""
        return self.n_columns * self.cells_per_column

    @property
    def n_connections(self) -> int:
        """Number of lateral (prediction) connections."""
        return int(self._st[K.N_EDGES])

    def view(self, sizes: bool = True) -> MemoryView:
        """Read-only views of the learned arrays (see :class:`MemoryView`); what kernels read. ``sizes`` False: no
        :meth:`column_sizes` (None), for a reader that keeps them itself after every frame."""
        nc, ne = self.n_columns, self.n_connections
        return MemoryView(readonly(self._bit_cols), readonly(self._bit_len), readonly(self._e_src[:ne]),
                          readonly(self._e_dst[:ne]), self.column_sizes() if sizes else None,
                          readonly(self._col_thr[:nc]), nc, self.cells_per_column)

    @property
    def connections(self) -> Connections:
        """What the memory has learned, as SciPy matrices (a read-only copy; see :class:`Connections`)."""
        v = self.view()
        cells = v.n_cells
        rows = np.arange(v.bit_cols.shape[1])[None, :] < v.bit_len[:, None]
        bits = np.repeat(np.arange(self.n_inputs, dtype=np.int64), v.bit_len)
        ff = sp.csr_matrix((np.ones(bits.size, bool), (v.bit_cols[rows].astype(np.int64), bits)),
                           shape=(v.n_columns, self.n_inputs))
        lat = sp.csr_matrix((np.ones(v.e_src.size, bool), (v.e_src, v.e_dst)), shape=(cells, cells))
        for m in (ff, lat):
            m.sort_indices()
        return Connections(ff, lat, v.thresholds.astype(np.int64), self.cells_per_column)

    @property
    def active_columns(self) -> np.ndarray:
        """Minicolumns active in the last step (sorted)."""
        return self._active[: self._st[K.N_ACTIVE]].copy()

    @property
    def winner_cells(self) -> np.ndarray:
        """Winner cells of the last step (sorted)."""
        return self._prev[: self._st[K.N_PREV]].copy()

    @property
    def predictive_cells(self) -> np.ndarray:
        """Cells predicted for the next step (sorted)."""
        return np.sort(self._pred_list[: self._st[K.N_PRED]])

    def reset(self) -> None:
        """Forget the sequence context (previous winners and predictions), keep what was learned."""
        st = self._st
        self._is_pred[self._pred_list[: st[K.N_PRED]]] = False
        st[K.N_PRED] = 0
        st[K.N_PREV] = 0
        st[K.N_ACTIVE] = 0

    # ------------------------------------------------------------------- API
    def _input_bits(self, sdr_row) -> sp.csr_matrix:
        """One input row as a checked 1-row SDR batch (see :func:`vpr.sdr.row_bits` for what a row may be)."""
        return _sdr.from_indices([_sdr.row_bits(sdr_row, self.n_inputs, name="input SDR")], self.n_inputs)

    def _run_batch(self, batch: sp.csr_matrix, learn: bool, progress: bool = False):
        """Run the kernel over all rows of a checked batch; return (indptr, indices) of winners."""
        n = batch.shape[0]
        ind_ptr = batch.indptr.astype(np.int64)
        ind = batch.indices.astype(np.int64)
        out_ptr = np.zeros(n + 1, np.int64)
        out_idx = np.zeros(max(1024, 16 * batch.nnz // 2), np.int64)
        keys = np.zeros(self.n_inputs, np.float64)
        st = self._st
        st[K.OUT_POS] = 0
        params = (self.cells_per_column, self.new_columns, self.k_active, self.connectivity, self.threshold,
                  self.p_extra)
        bar = None
        if progress:
            from tqdm import tqdm  # only for the progress bar

            bar = tqdm(total=n, desc="rSHOSM", unit="frame", leave=False)
        f = 0
        chunk = 2048 if progress else n
        while f < n:
            stop = min(n, f + chunk)
            f_new = K.run_frames((ind_ptr, ind), f, stop, learn, params, st, self._ff(), self._lat(), self._cells(),
                                 (self._counts, self._touched, self._active, keys), self._tape, (out_idx, out_ptr))
            if bar is not None:
                bar.update(f_new - f)
            f = f_new
            kind, size = st[K.NEED_KIND], int(st[K.NEED_SIZE])
            if f < stop or kind != K.DONE:
                if kind == K.NEED_COLS:
                    self._alloc_cols(max(size, 2 * self._col_thr.size))
                elif kind == K.NEED_ENTRIES:
                    self._alloc_bit_cols(max(size, 2 * self._bit_cols.shape[1]))
                elif kind == K.NEED_EDGES:
                    self._alloc_edges(max(size, 2 * self._e_src.size))
                elif kind == K.NEED_HASH:
                    self._rehash(size)
                elif kind == K.NEED_EDGE_HASH:
                    self._rehash(size, edges=True)
                elif kind == K.NEED_TAPE:
                    self._refill_tape(size)
                elif kind == K.NEED_OUT:
                    out_idx = self._grown(out_idx, max(size, 2 * out_idx.size))
                st[K.NEED_KIND] = K.DONE
        if bar is not None:
            bar.close()
        return out_ptr, out_idx[: out_ptr[-1]]

    def step(self, sdr_row, learn: bool = True, keep_overlaps: bool = False) -> np.ndarray:
        """Process one input SDR (one pass of Algorithm 1); returns the sorted winner cells (int64).

        ``sdr_row``: a 1-row SDR batch, a dense row of ``n_inputs`` values or active bit indices
        (:func:`vpr.sdr.row_bits`). With ``learn`` off nothing is created or learned and no random numbers are drawn
        (bursting ties by a fixed per-cell key): a query leaves the memory as it found it. ``keep_overlaps`` (while
        learning): the step's overlap counts (line 1) are kept for the caller, :meth:`overlaps`.
        """
        if keep_overlaps and not learn:
            raise ValueError("keep_overlaps applies to a step that learns")
        self._st[K.KEEP_COUNTS] = int(keep_overlaps)
        try:
            _, idx = self._run_batch(self._input_bits(sdr_row), learn)
        finally:
            self._st[K.KEEP_COUNTS] = 0
        self._kept = keep_overlaps
        return idx.copy()

    def overlaps(self) -> tuple[np.ndarray, np.ndarray, int]:
        """(counts per minicolumn, the minicolumns touched, how many) of the last step run with ``keep_overlaps``:
        each minicolumn's overlap with that step's input, before it learned (the minicolumns it created are not
        touched). The caller uses them and sets the touched counts back to 0 before the next step."""
        if not getattr(self, "_kept", False):
            raise ValueError("no overlaps kept: run step(..., keep_overlaps=True) first")
        self._kept = False
        return self._counts, self._touched, int(self._st[K.N_TOUCHED])

    compute = step  # htm.core's name

    def run(self, sdr_batch, learn: bool = True, reset: bool = False, progress: bool = False) -> sp.csr_matrix:
        """Process an SDR batch row by row; return the winner codes (frames x cells, csr bool).

        The returned width is the number of cells after the last frame; codes of different runs on one memory can be
        brought to one width with
        :func:`pad_codes`. ``reset=True`` clears the sequence context first.
        """
        batch = _sdr.check_batch(sdr_batch, n_bits=self.n_inputs, name="input SDR batch")
        if reset:
            self.reset()
        ptr, idx = self._run_batch(batch, learn, progress)
        # winners come out sorted and unique
        return sp.csr_matrix((np.ones(idx.size, bool), idx, ptr), shape=(batch.shape[0], max(self.n_cells, 1)))

    def column_sizes(self) -> np.ndarray:
        """Number of feed-forward connections (input bits) of every minicolumn, int64 (a copy).

        Kept up to date from the entries added since the last call (learning only appends to the inverted index), so
        that reading it after every frame of an online stream does not cost a pass over the whole index.
        """
        nc = self.n_columns
        cache = getattr(self, "_col_sizes", None)
        if cache is None or cache[1].shape != self._bit_len.shape or np.any(self._bit_len < cache[1]):
            rows = np.arange(self._bit_cols.shape[1])[None, :] < self._bit_len[:, None]
            sizes = np.bincount(self._bit_cols[rows], minlength=nc)[:nc].astype(np.int64)
        else:
            sizes, old = cache
            grew = np.flatnonzero(self._bit_len > old)
            if sizes.size < nc:
                sizes = np.concatenate([sizes, np.zeros(nc - sizes.size, np.int64)])
            if grew.size:
                lo, hi = old[grew].astype(np.int64), self._bit_len[grew].astype(np.int64)
                rep = np.repeat(grew, hi - lo)
                pos = np.arange(rep.size) - np.repeat(np.cumsum(hi - lo) - (hi - lo), hi - lo) + np.repeat(lo, hi - lo)
                np.add.at(sizes, self._bit_cols[rep, pos], 1)
        self._col_sizes = (sizes, self._bit_len.copy())
        return sizes.copy()

    @property
    def nbytes(self) -> int:
        """Bytes of the learned state and sequence context (what :meth:`save` writes, uncompressed)."""
        return int(sum(a.nbytes for a in self._arrays().values()))

    @property
    def n_feedforward(self) -> int:
        """Number of feed-forward connections (input bit, minicolumn) of all minicolumns."""
        return int(self._st[K.N_ENTRIES])

    # ------------------------------------------------------------ persistence
    @staticmethod
    def check_params(n_inputs, cells_per_column, new_columns, connectivity, threshold, p_extra, k_active,
                     seed) -> dict:
        """Every parameter checked and normalised, without building a memory (ValueError naming a bad one).

        The defaults are the constructor's (:meth:`default_params` reads them there).
        """
        if int(n_inputs) <= 0:
            raise ValueError(f"n_inputs must be positive, got {n_inputs}")
        if int(cells_per_column) <= 0:
            raise ValueError(f"cells_per_column must be positive, got {cells_per_column}")
        if int(new_columns) <= 0:
            raise ValueError(f"new_columns must be positive, got {new_columns}")
        if not 0.0 < connectivity <= 1.0:
            raise ValueError(f"connectivity must be in (0, 1], got {connectivity}")
        if not 0.0 < threshold <= 1.0:
            raise ValueError(f"threshold must be in (0, 1], got {threshold}")
        if not 0.0 <= p_extra <= 1.0:
            raise ValueError(f"p_extra must be in [0, 1], got {p_extra}")
        if int(k_active) < 0:
            raise ValueError(f"k_active must be >= 0, got {k_active}")
        return {"n_inputs": int(n_inputs), "cells_per_column": int(cells_per_column), "new_columns": int(new_columns),
                "connectivity": float(connectivity), "threshold": float(threshold), "p_extra": float(p_extra),
                "k_active": int(k_active), "seed": seed}

    @classmethod
    def default_params(cls) -> dict:
        """The constructor's parameters and their defaults (read from its signature: one source)."""
        return {k: p.default for k, p in inspect.signature(cls.__init__).parameters.items() if k != "self"}

    def get_params(self) -> dict:
        return {k: getattr(self, k) for k in ("n_inputs", "cells_per_column", "new_columns", "connectivity",
                                              "threshold", "p_extra", "k_active", "seed")}

    def _arrays(self) -> dict:
        st = self._st
        nc, nd = self.n_columns, int(st[K.N_EDGES])
        cells = nc * self.cells_per_column
        rows = np.arange(self._bit_cols.shape[1])[None, :] < self._bit_len[:, None]
        return {
            "bit_len": self._bit_len, "bit_cols": self._bit_cols[rows], "col_thr": self._col_thr[:nc],
            "out_head": self._out_head[:cells], "outdeg": self._outdeg[:cells],
            "e_src": self._e_src[:nd], "e_dst": self._e_dst[:nd], "e_onext": self._e_onext[:nd],
            "pred": self._pred_list[: st[K.N_PRED]],
            "prev": self._prev[: st[K.N_PREV]], "active": self._active[: st[K.N_ACTIVE]],
            "tape": self._tape[st[K.TAPE_POS]: st[K.TAPE_LEN]],
        }

    def state(self) -> tuple[dict, dict]:
        """(header, arrays): what :meth:`load_state` needs to continue exactly as this memory would.

        The header (parameters, the random generator's state) is JSON; the arrays are the learned state and the
        sequence context.
        """
        return {"params": self.get_params(), "rng": self._rng.bit_generator.state}, self._arrays()

    def load_state(self, header: dict, arrays: dict) -> SequenceMemory:
        """Continue from a :meth:`state` of a memory with this one's parameters.

        Raises
        ------
        MemoryFileError
            Arrays that are inconsistent (the kernels do not bounds-check).
        """
        if header["params"] != self.get_params():
            raise MemoryFileError("the state is of a memory with other parameters")
        self._rng.bit_generator.state = header["rng"]
        self._restore(arrays)
        return self

    def save(self, path) -> Path:
        """Save the learned memory and its sequence context to a versioned ``.npz`` (atomically).

        A loaded memory continues exactly as this one would (same random stream).
        """
        header, arrays = self.state()
        return write_file(path, _FORMAT, _FORMAT_VERSION, header, {"": arrays})

    @classmethod
    def load(cls, path) -> SequenceMemory:
        """Load a memory written by :meth:`save`.

        Raises
        ------
        MemoryFileError
            Missing, corrupt or foreign file, or an unsupported format version.
        """
        with read_file(path, _FORMAT, _FORMAT_VERSION, "SequenceMemory", prefixes=()) as (header, parts, _):
            return cls(**header["params"]).load_state(header, parts.get("", {}))

    def _restore(self, d: dict) -> None:
        nc, nd = d["col_thr"].size, d["e_src"].size
        cells = nc * self.cells_per_column

        def check(name, lo, hi, size=None):
            a = d[name]
            if size is not None and a.size != size:
                raise MemoryFileError(f"array {name!r} has {a.size} entries, expected {size}")
            if a.size and (a.min() < lo or a.max() >= hi):
                raise MemoryFileError(f"array {name!r} has values outside [{lo}, {hi})")

        # the kernel does not bounds-check, so a file must be consistent before it is used
        check("bit_len", 0, nc + 1, self.n_inputs)
        check("bit_cols", 0, nc, int(d["bit_len"].sum()))
        check("out_head", -1, nd, cells)
        check("outdeg", 0, nd + 1, cells)
        for name in ("e_src", "e_dst"):
            check(name, 0, cells, nd)
        check("e_onext", -1, nd, nd)
        for name in ("pred", "prev"):
            check(name, 0, cells)
        check("active", 0, nc)
        self._alloc_cols(max(64, nc))
        self._alloc_edges(max(4096, nd))
        self._bit_len[:] = d["bit_len"]
        self._col_sizes = None
        self._alloc_bit_cols(max(16, int(self._bit_len.max())))
        self._bit_cols[np.arange(self._bit_cols.shape[1])[None, :] < self._bit_len[:, None]] = d["bit_cols"]
        self._col_thr[:nc] = d["col_thr"]
        self._out_head[:cells], self._outdeg[:cells] = d["out_head"], d["outdeg"]
        self._e_src[:nd], self._e_dst[:nd] = d["e_src"], d["e_dst"]
        self._e_onext[:nd] = d["e_onext"]
        st = self._st
        st[K.N_COLS], st[K.N_ENTRIES], st[K.N_EDGES] = nc, int(self._bit_len.sum()), nd
        npred, nprev, nact = d["pred"].size, d["prev"].size, d["active"].size
        self._pred_list[:npred] = d["pred"]
        self._is_pred[d["pred"]] = True
        self._prev[:nprev] = d["prev"]
        self._active[:nact] = d["active"]
        st[K.N_PRED], st[K.N_PREV], st[K.N_ACTIVE] = npred, nprev, nact
        self._rehash(4 * nd + 8192)
        if self.p_extra > 0:
            self._rehash(4 * nd + 8192, edges=True)
        self._tape = d["tape"].astype(np.float64)
        st[K.TAPE_POS], st[K.TAPE_LEN] = 0, self._tape.size

    def __repr__(self) -> str:
        return (f"SequenceMemory(columns={self.n_columns}, cells={self.n_cells}, "
                f"connections={self.n_connections}, p_extra={self.p_extra})")


def pad_codes(*batches) -> list[sp.csr_matrix]:
    """Give winner-code batches from one memory (different times) the same width."""
    width = max(b.shape[1] for b in batches)
    out = []
    for b in batches:
        b = sp.csr_matrix(b, copy=True)
        b.resize((b.shape[0], width))
        out.append(b)
    return out
