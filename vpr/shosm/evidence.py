"""rSHOSM-seq's graded sequence evidence: one engine, one frame at a time or a whole traverse."""
from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Protocol

import numba
import numpy as np
import scipy.sparse as sp
from tqdm import tqdm

from vpr import sdr as _sdr
from vpr.checks import check_choice, check_top_k
from vpr.similarity import TOP_K, best_matches
from vpr.statefile import joint_state, part_state
from vpr.types import Column, Decision

from .conf import BeamConf, EvidenceConf
from .graph import Beam, Graph
from .kernels import evidence as KE
from .memory import SequenceMemory

__all__ = ["EvidenceEngine", "Engine", "beam_params", "SpeedEngine", "make_engine", "merge_columns", "merge_evidence",
           "Evidence", "LoopEvidence", "query_evidence", "directions_evidence", "dense_evidence", "sparse_evidence"]

#: Query frames per call of the beam kernel and per block of finished columns of a traverse.
QUERY_CHUNK = 2048

#: ``"reversed"``: one forward pass over the query along the map's transitions reversed (the query running the map
#: backwards)
_DIRECTIONS = ("both", "forward", "reversed")
_ONE = np.zeros(1, np.int64)
#: A second pass that holds nothing (one direction).
_NO_PASS = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))


@dataclass
class Evidence:
    """The evidence of a traverse: the similarity (dense, or top-K csr), and per column its best frame and z-score.

    ``best`` is -1 (``z`` -inf) for a column without evidence.
    """

    similarity: np.ndarray | sp.csr_matrix
    best: np.ndarray
    z: np.ndarray


@dataclass
class LoopEvidence(Evidence):
    """The evidence of one stream's loop closure (:func:`vpr.shosm.loop_evidence`): also ``fill`` (per frame, the
    score of a candidate without evidence), ``exclude``, the stream's winner ``codes``, the sessions' first
    frames ``starts`` and each frame's ``decision``; it unpacks as ``similarity, codes``."""

    fill: np.ndarray
    exclude: int
    codes: sp.csr_matrix | None = None
    starts: tuple = (0,)
    decision: Decision | None = None

    def __iter__(self):
        return iter((self.similarity, self.codes))


def beam_params(evidence: EvidenceConf, beam: BeamConf, z_weight: float) -> tuple:
    """The scalar arguments of the beam kernel (``z_weight``: 0.5 when two directions are added, else 0)."""
    stay, skip = evidence.costs
    return (float(evidence.decay), stay, skip, float(z_weight), float(beam.floor), float(beam.rel_floor),
            float(beam.z_floor), *beam.caps)


def _finish(a, b, n_per_q, n_rows, top_k, normalise: bool):
    """Columns of one or two passes (``b`` empty: one) summed, standardised and cut to ``top_k``.

    Returns (similarity csr n_rows x n_q float32, best row per query, its z).
    """
    size = max(n_rows, 1)
    ptr, idx, val, best, z, _, _ = KE.finish_columns(a[0], a[1], a[2], b[0], b[1], b[2], n_per_q,
                                                     0 if top_k is None else int(top_k), normalise,
                                                     np.zeros(size), np.zeros(size, bool), np.zeros(size, np.int64))
    S = sp.csc_matrix((val, idx, ptr), shape=(n_rows, ptr.size - 1)).tocsr()
    S.sort_indices()
    return S, best, z


def _reversed(ptr, idx, val):
    """Sparse columns given in reverse query order, put back in order."""
    lens = np.diff(ptr)[::-1]
    starts = ptr[:-1][::-1]
    take = np.concatenate([np.arange(s, s + n) for s, n in zip(starts, lens, strict=True)]) if lens.sum() else \
        np.zeros(0, np.int64)
    return np.r_[0, np.cumsum(lens)].astype(np.int64), idx[take], val[take]


class EvidenceEngine(Protocol):
    """What the localizer and loop closure step: :class:`Engine` (one speed model) and :class:`SpeedEngine`."""

    frames: int
    #: its speed models, one :class:`Engine` each (an :class:`Engine`: itself)
    lanes: list[Engine]

    def step(self, bits, n: int | None = None, capped: bool = True, frame: int = -1) -> Column: ...

    def grow(self) -> None: ...

    def reset(self) -> None: ...

    def state(self) -> tuple[dict, dict]: ...

    def load_state(self, header: dict, arrays: dict) -> EvidenceEngine: ...

    def run(self, query_batch, direction: str = "both", top_k: int | None = TOP_K, progress: bool = False,
            stats: dict | None = None) -> Evidence: ...


class Engine:
    """rSHOSM-seq's graded evidence over a :class:`~vpr.shosm.graph.Graph`: :meth:`step` one frame, :meth:`run` many.

    ``evidence``: an :class:`EvidenceConf`; ``beam``: a :class:`BeamConf` (not with ``exact``, which carries every
    relevant cell); ``threads``: :meth:`run`'s two passes on two threads at once when 2 or more (default: numba's, at
    most 2; same answers). The state between frames (:meth:`state`) is the last frame's evidence; :meth:`step` is
    causal, :meth:`run` starts afresh and may add a backward pass. ``z_weight``: the share of the frame's own
    feed-forward overlap taken out of :meth:`step`'s scores (0: none; two passes added count it ``2 - their sum``
    times, :func:`beam_params`).
    """

    def __init__(self, graph: Graph, evidence: EvidenceConf | None = None, beam: BeamConf | None = None,
                 exact: bool = False, threads: int | None = None, reverse: bool = False, z_weight: float = 0.0):
        self.graph, self.evidence, self.beam_conf = graph, evidence or EvidenceConf(), beam or BeamConf()
        self.exact = bool(exact)
        #: :meth:`step` follows the map's transitions reversed (the graph built ``backward``)
        self.reverse = bool(reverse)
        if self.reverse and graph.bwd is None:
            raise ValueError("an engine that follows the map backwards needs the graph built backward=True")
        self.threads = min(2, numba.config.NUMBA_NUM_THREADS) if threads is None else int(threads)
        self.normalise = self.evidence.normalise == "query"
        self.frames = 0
        self.z_weight = float(z_weight)
        self._params = {c: beam_params(self.evidence, self.beam_conf if c else self.beam_conf.uncapped(),
                                       self.z_weight) for c in (True, False)}
        if self.exact:
            self._rel, self._dense = graph.dense()
            self._e = np.zeros(self._rel.size, np.float64)
            self._out = np.zeros((graph.n_db, 1), np.float32)
        else:
            self._beam = Beam(graph)

    def column(self, rows, val, n: int, frame: int = -1) -> Column:
        """The standardised column of raw evidence ``val`` at ``rows`` over ``n`` candidates."""
        order = np.argsort(rows, kind="stable")
        val = np.asarray(val, np.float64)[order]
        mu, sd = KE.moments(val, n) if self.normalise and n > 0 else (0.0, 1.0)  # summed in the candidates' order
        z = ((val - mu) / sd).astype(np.float32)
        return Column(np.asarray(rows, np.int64)[order], z, float(np.float32(-mu / sd)), int(n), frame)

    @property
    def lanes(self) -> list[Engine]:
        """Its speed models: itself (:class:`EvidenceEngine`)."""
        return [self]

    def step(self, bits, n: int | None = None, capped: bool = True, frame: int = -1) -> Column:
        """The evidence of the next frame (its active bits, sorted) over candidates ``0 .. n - 1`` (default: all).

        Only cells learned by candidate ``n - 1`` take part (loop closure over a growing graph); ``capped``: the
        beam's caps apply.
        """
        return self.column(*self.step_raw(bits, n, capped), frame)

    def step_raw(self, bits, n: int | None = None, capped: bool = True) -> tuple[np.ndarray, np.ndarray, int]:
        """:meth:`step` before standardising: (candidate rows, their raw evidence, ``n``); a candidate left out
        scores 0."""
        g = self.graph
        n = g.n_db if n is None else int(n)
        q_ptr = np.array([0, bits.size], np.int64)
        if self.exact:
            self._out[:] = 0.0
            stay, skip = self.evidence.costs
            d = self._dense.reversed() if self.reverse else self._dense
            KE.evidence_frames(q_ptr, bits, _ONE, *d, float(self.evidence.decay), stay, skip, self.z_weight,
                               self._out, self._e, self.frames == 0)
            col = self._out[:, 0]
            rows = np.flatnonzero(col)
            val = col[rows].astype(np.float64)
        else:
            _, rows, val = self._beam.run(g, g.bwd if self.reverse else g.fwd, q_ptr, bits, _ONE, self._params[capped])
        self.frames += 1
        return np.asarray(rows, np.int64), np.asarray(val, np.float64), n

    def steps_raw(self, frames: list[np.ndarray], capped: bool = True) -> list[tuple[np.ndarray, np.ndarray]]:
        """:meth:`step_raw` of each of ``frames`` (active bits, sorted) in turn, in one call of the kernel: each
        frame's (candidate rows, raw evidence)."""
        g = self.graph
        k = len(frames)
        q_ptr = np.r_[0, np.cumsum([f.size for f in frames])].astype(np.int64)
        q_ind = np.concatenate(frames).astype(np.int64) if k else np.zeros(0, np.int64)
        order = np.arange(k, dtype=np.int64)
        out = []
        if self.exact:
            stay, skip = self.evidence.costs
            d = self._dense.reversed() if self.reverse else self._dense
            cols = np.zeros((g.n_db, k), np.float32)
            KE.evidence_frames(q_ptr, q_ind, order, *d, float(self.evidence.decay), stay, skip, self.z_weight, cols,
                               self._e, self.frames == 0)
            for i in range(k):
                rows = np.flatnonzero(cols[:, i])
                out.append((rows, cols[rows, i].astype(np.float64)))
        else:
            ptr, idx, val = self._beam.run(g, g.bwd if self.reverse else g.fwd, q_ptr, q_ind, order,
                                           self._params[capped])
            out = [(idx[ptr[i]:ptr[i + 1]].astype(np.int64), val[ptr[i]:ptr[i + 1]]) for i in range(k)]
        self.frames += k
        return out

    def grow(self) -> None:
        """Nothing to make room for: a learned database's graph does not grow."""

    def reset(self) -> None:
        """Forget the evidence carried from earlier frames (a new query traverse, a new session)."""
        self.frames = 0
        if self.exact:
            self._e[:] = 0.0
        else:
            self._beam.set_cells(np.zeros(0, np.int64), np.zeros(0))

    # ------------------------------------------------------------- state
    def state(self) -> tuple[dict, dict]:
        """(header, arrays) after the frames seen so far; :meth:`load_state` continues from them."""
        if self.exact:
            return {"frames": self.frames, "exact": True}, {"rel": self._rel.copy(), "e": self._e.copy()}
        cells, values = self._beam.cells()  # kept as the memory's cells
        return {"frames": self.frames, "exact": False}, {"beam_cells": self.graph.rel[cells], "beam_e": values,
                                                         "beam_st": self._beam.st.copy()}

    def load_state(self, header: dict, arrays: dict) -> Engine:
        """Continue from a :meth:`state` of an engine on the same graph and conf."""
        if "lanes" in header:
            raise ValueError(f"the state is of an engine of {header['lanes']} speed models, this one has one")
        if bool(header.get("exact")) != self.exact:
            raise ValueError(f"the state is of {'an exact' if header.get('exact') else 'a beam'} engine, "
                             f"this one is {'exact' if self.exact else 'a beam'}")
        self.frames = int(header["frames"])
        if self.exact:
            if not np.array_equal(arrays["rel"], self._rel):
                raise ValueError("the state is not of this memory and database")
            self._e[:] = arrays["e"]
            return self
        cells = np.asarray(arrays["beam_cells"], np.int64)
        r = self.graph.number(cells)
        if cells.size and (r.max() >= self.graph.n_rel or not np.array_equal(self.graph.rel[r], cells)):
            raise ValueError("the state has beam cells that carry no evidence in this memory: another memory's state?")
        self._beam.set_cells(r, np.asarray(arrays["beam_e"], np.float64))
        if "beam_st" in arrays:
            self._beam.st[:] = arrays["beam_st"]
        return self

    # ------------------------------------------------------------- a whole traverse
    def run(self, query_batch, direction: str = "both", top_k: int | None = TOP_K, progress: bool = False,
            stats: dict | None = None) -> Evidence:
        """The beam's evidence of every frame of ``query_batch``, the ``top_k`` best database frames per query.

        With ``normalise == "query"`` the scores are z-scores over **all** database frames, as the dense column would
        be (absent frames are 0). ``stats`` gets the largest beam and candidate set of any frame.
        """
        check_choice(direction, "direction", _DIRECTIONS)
        top_k = check_top_k(top_k)
        g = self.graph
        q = _sdr.check_batch(query_batch, n_bits=g.mem.n_inputs, name="query SDR batch")
        n_q, n_db = q.shape[0], g.n_db
        q_ptr, q_ind = q.indptr.astype(np.int64), q.indices.astype(np.int64)
        params = beam_params(self.evidence, self.beam_conf, 0.5 if direction == "both" else 0.0)
        seen = {"max_beam": 0, "max_candidates": 0}
        passes = [("rev" if direction == "reversed" else "fwd", np.arange(n_q, dtype=np.int64))]
        if direction == "both":
            passes.append(("bwd", np.arange(n_q, dtype=np.int64)[::-1].copy()))
        # Columns are finished (summed over the passes, standardised, cut to top_k) a chunk of queries at a time as
        # soon as every pass has given it, and the passes' columns of that chunk freed: the forward pass gives the
        # chunks first to last and the backward pass last to first, so at most half of each pass's columns are held at
        # once (float32 values, 32-bit frames), not both whole passes.
        chunk = QUERY_CHUNK
        starts = list(range(0, n_q, chunk))
        done: dict[int, tuple] = {}
        n_per_q = np.full(n_q, n_db, np.int64)
        pending: list[dict] = [{} for _ in passes]  # per pass: chunks given, not yet finished
        lock = threading.Lock()

        def give(k, c, cols):
            with lock:
                pending[k][c] = cols
                parts = [p.pop(c) for p in pending] if all(c in p for p in pending) else None
            if parts is not None:
                q0, q1 = starts[c], min(starts[c] + chunk, n_q)
                done[c] = _finish(parts[0], parts[1] if len(parts) > 1 else _NO_PASS, n_per_q[q0:q1], n_db, top_k,
                                  self.normalise)

        def run_pass(k, name, order, bar):
            """One direction's columns, per chunk, each given to :func:`give` as it is made."""
            b = Beam(g)
            adj = g.fwd if name == "fwd" else g.bwd
            ahead = name != "bwd"  # the query's frames in their order
            for c in (range(len(starts)) if ahead else range(len(starts) - 1, -1, -1)):
                q0, q1 = starts[c], min(starts[c] + chunk, n_q)
                frames = order[q0:q1] if ahead else order[n_q - q1:n_q - q0]
                cols = b.run(g, adj, q_ptr, q_ind, frames, params)
                cols = _reversed(*cols) if name == "bwd" else cols
                give(k, c, (cols[0], cols[1].astype(np.int32), cols[2].astype(np.float32)) if len(passes) > 1
                     else cols)
                with lock:
                    bar.update(q1 - q0)
            return b.largest

        with tqdm(total=n_q * len(passes), desc="rSHOSM evidence", unit="frame", leave=False,
                  disable=not progress) as bar:
            jobs = [(k, *p, bar) for k, p in enumerate(passes)]
            if len(passes) > 1 and self.threads > 1:  # the passes do not depend on each other: one per core
                with ThreadPoolExecutor(2) as pool:
                    largest = list(pool.map(lambda job: run_pass(*job), jobs))
            else:
                largest = [run_pass(*job) for job in jobs]
        for most in largest:
            seen["max_beam"] = max(seen["max_beam"], most[0])
            seen["max_candidates"] = max(seen["max_candidates"], most[1])
        if stats is not None:
            stats.update(seen)
        parts = [done[c] for c in range(len(starts))]
        if not parts:
            return Evidence(sp.csr_matrix((n_db, 0), dtype=np.float32), np.zeros(0, np.int64), np.zeros(0))
        S = sp.hstack([p[0] for p in parts], format="csr")
        S.sort_indices()
        return Evidence(S, np.concatenate([p[1] for p in parts]), np.concatenate([p[2] for p in parts]))

    def run_directions(self, query_batch, top_k: int | None = TOP_K, progress: bool = False) -> dict[str, Evidence]:
        """The evidence of every frame of ``query_batch`` in the three directions a batch match reads: ``"both"``
        (:meth:`run`'s), the causal ``"forward"`` and ``"reversed"`` (the query running the map backwards), the
        ``top_k`` best database frames per query each; each the same as :meth:`run` of that direction.

        Three passes, not four: the forward pass gives both the forward half of ``"both"`` and the causal evidence
        (they differ only in how much of each frame's own overlap is taken out), and runs with the reversed pass
        over the query's frames in the same order, each frame's overlaps counted once for both; the backward pass
        runs on the other core. The graph must be built ``backward``.
        """
        top_k = check_top_k(top_k)
        g = self.graph
        if g.bwd is None:
            raise ValueError("the directions' evidence needs the graph built backward=True")
        q = _sdr.check_batch(query_batch, n_bits=g.mem.n_inputs, name="query SDR batch")
        n_q, n_db = q.shape[0], g.n_db
        q_ptr, q_ind = q.indptr.astype(np.int64), q.indices.astype(np.int64)
        half, alone = (beam_params(self.evidence, self.beam_conf, w) for w in (0.5, 0.0))
        n_per_q = np.full(n_q, n_db, np.int64)
        chunk = QUERY_CHUNK
        starts = list(range(0, n_q, chunk))
        cols: dict[str, dict[int, tuple]] = {"fwd": {}, "causal": {}, "rev": {}, "bwd": {}}
        done: dict[str, dict[int, tuple]] = {"both": {}, "forward": {}, "reversed": {}}
        lock = threading.Lock()

        def narrow(c):
            return c[0], c[1].astype(np.int32), c[2].astype(np.float32)

        def finish(c: int) -> None:
            """Chunk ``c``'s columns of every direction, once every pass gave them (under the lock)."""
            q0, q1 = starts[c], min(starts[c] + chunk, n_q)
            if c in cols["fwd"] and c in cols["bwd"] and c not in done["both"]:
                a, b = cols["fwd"].pop(c), cols["bwd"].pop(c)
                done["both"][c] = _finish(a, b, n_per_q[q0:q1], n_db, top_k, self.normalise)
            for name, key in (("causal", "forward"), ("rev", "reversed")):
                if c in cols[name]:
                    done[key][c] = _finish(cols[name].pop(c), _NO_PASS, n_per_q[q0:q1], n_db, top_k, self.normalise)

        def ahead(bar):  # the forward pass (two outputs) with the reversed pass, the query's frames in order
            fwd, rev = Beam(g), Beam(g)
            for c in range(len(starts)):
                q0, q1 = starts[c], min(starts[c] + chunk, n_q)
                (both_half, causal), reversed_ = fwd.run_pair(rev, g, g.fwd, g.bwd, q_ptr, q_ind,
                                                              np.arange(q0, q1, dtype=np.int64), half, alone, 0.0)
                with lock:  # (a direction of one pass is finished as run() finishes it, in float64)
                    cols["fwd"][c], cols["causal"][c], cols["rev"][c] = narrow(both_half), causal, reversed_
                    finish(c)
                    bar.update(2 * (q1 - q0))

        def back(bar):  # the backward pass, the query's frames last to first
            b = Beam(g)
            order = np.arange(n_q, dtype=np.int64)[::-1].copy()
            for c in range(len(starts) - 1, -1, -1):
                q0, q1 = starts[c], min(starts[c] + chunk, n_q)
                got = _reversed(*b.run(g, g.bwd, q_ptr, q_ind, order[n_q - q1:n_q - q0], half))
                with lock:
                    cols["bwd"][c] = narrow(got)
                    finish(c)
                    bar.update(q1 - q0)

        with tqdm(total=3 * n_q, desc="rSHOSM evidence", unit="frame", leave=False, disable=not progress) as bar:
            if self.threads > 1:
                with ThreadPoolExecutor(2) as pool:
                    for f in [pool.submit(ahead, bar), pool.submit(back, bar)]:
                        f.result()
            else:
                ahead(bar)
                back(bar)
        out = {}
        for key, parts in done.items():
            ps = [parts[c] for c in range(len(starts))]
            if not ps:
                out[key] = Evidence(sp.csr_matrix((n_db, 0), dtype=np.float32), np.zeros(0, np.int64), np.zeros(0))
                continue
            S = sp.hstack([p[0] for p in ps], format="csr")
            S.sort_indices()
            out[key] = Evidence(S, np.concatenate([p[1] for p in ps]), np.concatenate([p[2] for p in ps]))
        return out

    def run_dense(self, query_batch, direction: str = "both", progress: bool = False,
                  clamp: bool = False) -> np.ndarray:
        """The raw evidence of every query frame for every database frame (n_db x n_q float32, not standardised).

        ``clamp`` floors the predicted term at 0, the beam's semantics (for tests).
        """
        check_choice(direction, "direction", _DIRECTIONS)
        stay, skip = self.evidence.costs
        g = self.graph
        q = _sdr.check_batch(query_batch, n_bits=g.mem.n_inputs, name="query SDR batch")
        rel, (bit_cols, bit_len, col_size, rel_col, rs, rd, db_ptr, db_ind, db_norm) = \
            (self._rel, self._dense) if self.exact else g.dense()
        n_q = q.shape[0]
        out = np.zeros((g.n_db, n_q), dtype=np.float32)
        passes = [(np.arange(n_q), *((rd, rs) if direction == "reversed" else (rs, rd)),
                   0.5 if direction == "both" else 0.0)]
        if direction == "both":
            passes.append((np.arange(n_q)[::-1].copy(), rd, rs, 0.5))
        q_ptr, q_ind = q.indptr.astype(np.int64), q.indices.astype(np.int64)
        chunk = 256 if progress else max(n_q, 1)
        with tqdm(total=n_q * len(passes), desc="rSHOSM evidence", unit="frame", leave=False,
                  disable=not progress) as bar:
            for order, a, b, zw in passes:
                e = np.zeros(rel.size, np.float64)
                for f0 in range(0, n_q, chunk):
                    KE.evidence_frames(q_ptr, q_ind, order[f0:f0 + chunk], bit_cols, bit_len, col_size, rel_col, a,
                                       b, db_ptr, db_ind, db_norm, float(self.evidence.decay), stay, skip, zw, out,
                                       e, f0 == 0, clamp)
                    bar.update(min(chunk, n_q - f0))
        return out


def merge_columns(columns: list[Column]) -> Column:
    """One frame's column of several speed models' columns: per candidate the largest score, a candidate a
    column lacks scoring that column's ``fill``."""
    if len(columns) == 1:
        return columns[0]
    rows = np.unique(np.concatenate([c.rows for c in columns]))
    z = np.full(rows.size, -np.inf, np.float32)
    for c in columns:
        v = np.full(rows.size, c.fill, np.float32)
        v[np.searchsorted(rows, c.rows)] = c.z
        np.maximum(z, v, out=z)
    first = columns[0]
    return Column(rows, z, max(float(c.fill) for c in columns), first.n, first.frame)


def merge_evidence(parts: list[Evidence], top_k: int | None) -> Evidence:
    """One traverse's evidence of several speed models' top-K evidences: per pair the largest score (an entry a
    part lacks counts as that part's lowest stored score of the column), cut to ``top_k`` per query."""
    if len(parts) == 1:
        return parts[0]
    cols = [sp.csc_matrix(p.similarity) for p in parts]
    n_db, n_q = cols[0].shape
    keyed = []
    for c in cols:
        c.sort_indices()
        lens = np.diff(c.indptr)
        keyed.append(c.indices.astype(np.int64) + n_db * np.repeat(np.arange(n_q, dtype=np.int64), lens))
    keys = np.unique(np.concatenate(keyed))
    key_col, key_row = keys // n_db, keys % n_db
    val = np.full(keys.size, -np.inf, np.float32)
    for c, k in zip(cols, keyed, strict=True):
        lowest = np.full(n_q, -np.inf, np.float32)
        filled = np.diff(c.indptr) > 0
        if filled.any():
            lowest[filled] = np.minimum.reduceat(c.data.astype(np.float32), c.indptr[:-1][filled])
        v = lowest[key_col]
        v[np.searchsorted(keys, k)] = c.data
        np.maximum(val, v, out=val)
    order = np.lexsort((key_row, -val, key_col))
    key_col, key_row, val = key_col[order], key_row[order], val[order]
    rank = np.arange(keys.size) - np.searchsorted(key_col, key_col)
    keep = np.isfinite(val) & (rank < (keys.size if top_k is None else int(top_k)))
    S = sp.csr_matrix((val[keep], (key_row[keep], key_col[keep])), shape=(n_db, n_q))
    S.sort_indices()
    best, z = best_matches(S)
    return Evidence(S, best, z)


class SpeedEngine:
    """:class:`Engine` for several speed models (:attr:`EvidenceConf.speeds`): one engine per model over one graph,
    stepped together, each frame's column their :func:`merge_columns` (a traverse's: :func:`merge_evidence`)."""

    def __init__(self, graph: Graph, evidence: EvidenceConf, beam: BeamConf | None = None, exact: bool = False,
                 threads: int | None = None):
        self.graph, self.evidence = graph, evidence
        self.lanes = [Engine(graph, lane, beam, exact, threads) for lane in evidence.split()]

    @classmethod
    def of_lanes(cls, graph, evidence: EvidenceConf, lanes: list) -> SpeedEngine:
        """The speed models' engines ``lanes`` (one per model of ``evidence``, over ``graph``), stepped together."""
        self = cls.__new__(cls)
        self.graph, self.evidence, self.lanes = graph, evidence, list(lanes)
        return self

    @property
    def frames(self) -> int:
        return self.lanes[0].frames

    def step(self, bits, n: int | None = None, capped: bool = True, frame: int = -1) -> Column:
        """As :meth:`Engine.step`, merged over the speed models."""
        return merge_columns([e.step(bits, n, capped, frame) for e in self.lanes])

    def grow(self) -> None:
        for e in self.lanes:
            e.grow()

    def reset(self) -> None:
        for e in self.lanes:
            e.reset()

    def state(self) -> tuple[dict, dict]:
        """(header, arrays): every model's :meth:`Engine.state`."""
        header, arrays = joint_state(**{f"lane{k}": e for k, e in enumerate(self.lanes)})
        return {**header, "lanes": len(self.lanes)}, arrays

    def load_state(self, header: dict, arrays: dict) -> SpeedEngine:
        """Continue from a :meth:`state` of an engine with the same speed models."""
        if header.get("lanes") != len(self.lanes):
            raise ValueError(f"the state is of an engine of {header.get('lanes', 1)} speed models, this one has "
                             f"{len(self.lanes)}")
        for k, e in enumerate(self.lanes):
            e.load_state(*part_state(header, arrays, f"lane{k}"))
        return self

    def run(self, query_batch, direction: str = "both", top_k: int | None = TOP_K, progress: bool = False,
            stats: dict | None = None) -> Evidence:
        """As :meth:`Engine.run`, merged over the speed models."""
        return merge_evidence([e.run(query_batch, direction, top_k, progress, stats) for e in self.lanes], top_k)


def make_engine(graph: Graph, evidence: EvidenceConf | None = None, beam: BeamConf | None = None,
                exact: bool = False, threads: int | None = None) -> EvidenceEngine:
    """The evidence engine of ``evidence``'s speed models: an :class:`Engine` for one, a :class:`SpeedEngine`
    for several."""
    lanes = (evidence or EvidenceConf()).split()
    if len(lanes) == 1:
        return Engine(graph, lanes[0], beam, exact, threads)
    return SpeedEngine(graph, evidence, beam, exact, threads)


def directions_evidence(mem: SequenceMemory, query_batch, db_codes, conf: EvidenceConf | None = None,
                        top_k: int | None = None, beam: BeamConf | None = None,
                        progress: bool = False) -> dict[str, Evidence]:
    """:func:`query_evidence` of the directions ``"both"``, ``"forward"`` and ``"reversed"`` at once (what a batch
    match and its direction check read): the same evidences, the sparse ones in three passes over one graph
    (:meth:`Engine.run_directions`)."""
    conf = conf or EvidenceConf()
    if check_top_k(top_k) is None or len(conf.split()) > 1:
        return {d: query_evidence(mem, query_batch, db_codes, conf, d, top_k, beam, progress) for d in _DIRECTIONS}
    return Engine(Graph.of(mem, db_codes, backward=True), conf, beam).run_directions(query_batch, top_k, progress)


def query_evidence(mem: SequenceMemory, query_batch, db_codes, conf: EvidenceConf | None = None,
                   direction: str = "both", top_k: int | None = None, beam: BeamConf | None = None,
                   progress: bool = False) -> Evidence:
    """Graded evidence of every query frame for the database frames, standardised as ``conf.normalise`` says.

    ``mem``: the memory that learned the database; ``db_codes``: its winner codes (``mem.run``); ``conf``: an
    :class:`EvidenceConf`; ``direction``: ``"both"``, ``"forward"`` or ``"reversed"`` (:data:`_DIRECTIONS`); ``top_k``
    None: dense (n_db x n_q ndarray), an int: the beam's ``top_k`` best database frames per query (csr), with ``beam``
    its :class:`BeamConf`.
    """
    conf = conf or EvidenceConf()
    if check_top_k(top_k) is not None:
        return sparse_evidence(mem, query_batch, db_codes, conf, direction, top_k=top_k, beam=beam, progress=progress)
    S = None
    for lane in conf.split():
        M = dense_evidence(mem, query_batch, db_codes, lane, direction, progress)
        if conf.normalise == "query":
            KE.zscore_dense(M)
        S = M if S is None else np.maximum(S, M, out=S)
    best, z = best_matches(S)
    return Evidence(S, best, z)


def dense_evidence(mem: SequenceMemory, query_batch, db_codes, conf: EvidenceConf | None = None,
                   direction: str = "both", progress: bool = False, clamp: bool = False) -> np.ndarray:
    """Raw evidence of every query frame for every database frame (dense n_db x n_q float32, not standardised).

    ``clamp=True`` floors the predicted term at 0, the semantics of :func:`sparse_evidence` (for tests).
    """
    check_choice(direction, "direction", _DIRECTIONS)
    return Engine(Graph.of(mem, db_codes), conf).run_dense(query_batch, direction, progress, clamp)


def sparse_evidence(mem: SequenceMemory, query_batch, db_codes, conf: EvidenceConf | None = None,
                    direction: str = "both", top_k: int | None = TOP_K, beam: BeamConf | None = None,
                    progress: bool = False, stats: dict | None = None) -> Evidence:
    """The beam's evidence (:meth:`Engine.run`): the top-K database frames per query.

    Per query frame only the cells whose evidence is above ``max(floor, rel_floor * largest)`` are carried, and a
    minicolumn's cells enter by feed-forward only when its overlap fraction is above ``z_floor`` (found through the
    memory's inverted index, so the cost per frame follows the beam, not the database); ``max_beam`` and ``max_enter``
    cap both. A cell outside the beam has evidence 0. With all floors 0 and no caps the result equals
    ``dense_evidence(..., clamp=True)`` standardised.
    """
    check_choice(direction, "direction", _DIRECTIONS)
    g = Graph.of(mem, db_codes, backward=direction != "forward")
    return make_engine(g, conf, beam).run(query_batch, direction, top_k, progress, stats)
