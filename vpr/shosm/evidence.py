"""rSHOSM-seq's graded sequence evidence of a query traverse against a learned database.

**Our extension, not the paper's.** A database traverse is learned with
Algorithm 1 (:class:`vpr.shosm.SequenceMemory`); a query frame is then scored
with graded evidence instead of binary winner cells (whose overlap cannot rank
a query that is only partly like its place). The learned memory is read,
never changed:

* feed-forward: a cell's input evidence ``z`` is the fraction of its
  minicolumn's connections that are 1-bits of the query SDR (the quantity
  Alg. 1 line 1 thresholds);
* sequence: a cell's evidence is ``z + decay * p``, where ``p`` is the best
  evidence of a cell that predicts it through a learned lateral connection at
  the previous query frame (the prediction of lines 7 and 10, graded instead of
  binary); ``stay`` and ``skip`` admit a repeated or a skipped database frame
  at that cost (:class:`vpr.shosm.EvidenceConf`);
* ``direction="both"`` also runs the query traverse backwards along the
  reversed connections and adds the two (the input term counted once), so that
  evidence, like OpenSeqSLAM's centred window, comes from both sides of a
  frame; ``"forward"`` is causal.

The similarity of database frame ``j`` and query frame ``q`` is the mean
evidence of ``j``'s winner cells at ``q``, standardised per query.

:func:`query_evidence` is the entry point; it runs :func:`dense_evidence`
(every cell, every frame; a dense n_db x n_q matrix) or, with ``top_k``,
:func:`sparse_evidence` (only the cells above the beam's floors are carried,
top-K database frames per query; for large inputs). The streaming version is
:class:`vpr.shosm.ForwardEvidence`, loop closure :func:`vpr.shosm.loop_evidence`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from tqdm import tqdm

from vpr import sdr as _sdr
from vpr.checks import check_choice, check_top_k
from vpr.similarity import TOP_K, best_matches

from .beam import BIG, NO_PASS, Beam, beam_params, check_codes, db_graph, finish, reverse_columns
from .conf import BeamConf, EvidenceConf
from .kernels import evidence as KE
from .memory import SequenceMemory

__all__ = ["query_evidence", "dense_evidence", "sparse_evidence", "zscore_columns", "EvidenceResult"]

#: Query frames per call of the beam kernel and per block of finished columns (:func:`sparse_evidence`).
QUERY_CHUNK = 2048

_DIRECTIONS = ("both", "forward")


@dataclass
class EvidenceResult:
    """Evidence of a query traverse: ``similarity`` (n_db x n_q: dense ndarray, or top-K csr), best
    database frame and score per query.

    ``best_db`` is -1 (score -inf) for a query frame that no database frame has evidence for.
    """

    similarity: np.ndarray | sp.csr_matrix
    best_db: np.ndarray
    score: np.ndarray


def _check_top_k(top_k) -> int | None:
    return check_top_k(top_k)


def query_evidence(mem: SequenceMemory, query_batch, db_codes, conf: EvidenceConf | None = None,
                   direction: str = "both", top_k: int | None = None, beam: BeamConf | None = None,
                   progress: bool = False) -> EvidenceResult:
    """Graded evidence of every query frame for the database frames, standardised as ``conf.normalise`` says.

    Parameters
    ----------
    mem : SequenceMemory
        The memory that learned the database.
    query_batch : SDR batch (n_q x n_inputs)
    db_codes : csr matrix (n_db x cells)
        Winner codes of the database traverse from ``mem.run``.
    conf : EvidenceConf
        Decay, transition costs and standardisation (default: the defaults).
    direction : {"both", "forward"}
    top_k : int or None
        None: the dense evidence of every database frame (n_db x n_q ndarray).
        An int: the sparse beam (:func:`sparse_evidence`, with ``beam``), the
        ``top_k`` best database frames per query as a csr matrix.
    beam : BeamConf
        Floors and caps of the sparse beam (only with ``top_k``).
    progress : bool
        tqdm progress bar.
    """
    conf = conf or EvidenceConf()
    if _check_top_k(top_k) is not None:
        return sparse_evidence(mem, query_batch, db_codes, conf, direction, top_k=top_k, beam=beam, progress=progress)
    S = dense_evidence(mem, query_batch, db_codes, conf, direction, progress)
    if conf.normalise == "query":
        S = zscore_columns(S)
    best, score = best_matches(S)
    return EvidenceResult(S, best, score)


def zscore_columns(S: np.ndarray) -> np.ndarray:
    """Standardise every query column of a dense S in place (``EvidenceConf.normalise == "query"``).

    Each query's evidence has its own scale (how well that frame matches
    anything); z-scores make one threshold mean the same for every query, as
    SeqSLAM's contrast enhancement does.
    """
    for c0 in range(0, S.shape[1], 1024):
        blk = S[:, c0:c0 + 1024]
        sd = blk.std(axis=0)
        blk -= blk.mean(axis=0)
        blk /= np.where(sd > 0, sd, 1.0)
    return S


def dense_graph(mem: SequenceMemory, db: sp.csr_matrix) -> tuple:
    """The dense kernel's view of a memory and its database codes, on the relevant cells only.

    Only cells in database codes or on a connection can carry evidence to the
    output; they are renumbered ``0 .. n_rel - 1``. Returns
    ``(rel, (bit_cols, bit_len, col_size, rel_col, src, dst, db_ptr, db_ind, db_norm))``
    with ``rel`` the memory's cell index of each relevant cell.
    """
    v = mem.view()
    rel = np.unique(np.concatenate([db.indices.astype(np.int64), v.e_src, v.e_dst]))
    db_ptr = db.indptr.astype(np.int64)
    return rel, (v.bit_cols, v.bit_len, v.column_sizes.astype(np.float64), rel // v.cells_per_column,
                 np.searchsorted(rel, v.e_src).astype(np.int64), np.searchsorted(rel, v.e_dst).astype(np.int64),
                 db_ptr, np.searchsorted(rel, db.indices.astype(np.int64)).astype(np.int64),
                 np.diff(db_ptr).astype(np.float64))


def dense_evidence(mem: SequenceMemory, query_batch, db_codes, conf: EvidenceConf | None = None,
                   direction: str = "both", progress: bool = False, clamp: bool = False) -> np.ndarray:
    """Raw graded sequence evidence of every query frame for every database frame (dense, not standardised).

    Cost per query frame is linear in the number of learned connections.
    ``conf.normalise`` is not applied here (:func:`query_evidence` applies it).
    ``clamp=True`` floors the predicted term at 0, the semantics of
    :func:`sparse_evidence` (for tests).

    Returns
    -------
    ndarray, float32, n_db x n_q (higher = more similar).
    """
    conf = conf or EvidenceConf()
    check_choice(direction, "direction", _DIRECTIONS)
    stay, skip = conf.costs
    q = _sdr.check_batch(query_batch, n_bits=mem.n_inputs, name="query SDR batch")
    db = check_codes(mem, db_codes)
    rel, (bit_cols, bit_len, col_size, rel_col, rs, rd, db_ptr, db_ind, db_norm) = dense_graph(mem, db)
    n_db, n_q = db.shape[0], q.shape[0]
    out = np.zeros((n_db, n_q), dtype=np.float32)
    passes = [(np.arange(n_q), rs, rd, 0.5 if direction == "both" else 0.0)]
    if direction == "both":
        passes.append((np.arange(n_q)[::-1].copy(), rd, rs, 0.5))
    q_ptr, q_ind = q.indptr.astype(np.int64), q.indices.astype(np.int64)
    chunk = 256 if progress else max(n_q, 1)
    with tqdm(total=n_q * len(passes), desc="rSHOSM evidence", unit="frame", leave=False, disable=not progress) as bar:
        for order, a, b, zw in passes:
            e = np.zeros(rel.size, np.float64)
            for f0 in range(0, n_q, chunk):
                KE.evidence_frames(q_ptr, q_ind, order[f0:f0 + chunk], bit_cols, bit_len, col_size, rel_col, a, b,
                                   db_ptr, db_ind, db_norm, float(conf.decay), stay, skip, zw, out, e, f0 == 0, clamp)
                bar.update(min(chunk, n_q - f0))
    return out


def sparse_evidence(mem: SequenceMemory, query_batch, db_codes, conf: EvidenceConf | None = None,
                    direction: str = "both", top_k: int | None = TOP_K, beam: BeamConf | None = None,
                    progress: bool = False, stats: dict | None = None) -> EvidenceResult:
    """Graded sequence evidence carried only where it is; the top-K database frames per query.

    The same evidence as :func:`dense_evidence`, but per query frame only the
    cells whose evidence is above ``max(floor, rel_floor * largest)`` are
    carried (a beam), and a minicolumn's cells enter by feed-forward only when
    its overlap fraction is above ``z_floor`` (found through the memory's
    inverted index, so the cost per frame follows the beam, not the database);
    ``max_beam`` and ``max_enter`` cap both (:class:`vpr.shosm.BeamConf`).
    A cell outside the beam has evidence 0 (evidence is never negative here; the
    dense version lets a cell that nothing predicts drift below 0). With all
    floors 0 and no caps the result equals ``dense_evidence(..., clamp=True)``.

    Parameters
    ----------
    mem, query_batch, db_codes, conf, direction
        As :func:`query_evidence`. With ``conf.normalise == "query"`` the
        scores are z-scores over **all** database frames, exactly as the dense
        column would be standardised (the mean and standard deviation are sums
        over the carried entries; absent frames are 0).
    top_k : int or None
        Database frames kept per query (None: all that have evidence).
    beam : BeamConf
        Floors and caps (default: :class:`BeamConf`'s).
    progress : bool
        tqdm progress bar.
    stats : dict, optional
        Filled with ``max_beam`` and ``max_candidates``: the largest beam and
        candidate set of any frame (to check the caps).

    Returns
    -------
    EvidenceResult (similarity: csr n_db x n_q float32).
    """
    conf, beam = conf or EvidenceConf(), beam or BeamConf()
    check_choice(direction, "direction", _DIRECTIONS)
    top_k = _check_top_k(top_k)
    q = _sdr.check_batch(query_batch, n_bits=mem.n_inputs, name="query SDR batch")
    db = check_codes(mem, db_codes)
    g = db_graph(mem, db, backward=direction == "both")
    n_q, n_db = q.shape[0], db.shape[0]
    q_ptr, q_ind = q.indptr.astype(np.int64), q.indices.astype(np.int64)
    params = beam_params(conf, beam, 0.5 if direction == "both" else 0.0)
    limits = np.full(n_q, BIG, np.int64)
    seen = {"max_beam": 0, "max_candidates": 0}
    passes = [("fwd", np.arange(n_q, dtype=np.int64))]
    if direction == "both":
        passes.append(("bwd", np.arange(n_q, dtype=np.int64)[::-1].copy()))
    # Columns are finished (summed over the passes, standardised, cut to top_k) a chunk of queries at a
    # time, as soon as every pass has given them: the forward pass's columns wait for the backward pass
    # (which runs the chunks in reverse), the backward pass's never wait. Only the forward columns are
    # ever held whole: on SDRs that share many bits between places a column holds thousands of frames.
    chunk = QUERY_CHUNK
    starts = list(range(0, n_q, chunk))
    held: dict[int, tuple] = {}
    done: dict[int, tuple] = {}
    n_per_q = np.full(n_q, n_db, np.int64)

    def finish_chunk(c, a, b):
        q0, q1 = starts[c], min(starts[c] + chunk, n_q)
        done[c] = finish(a, b, n_per_q[q0:q1], n_db, top_k, conf.normalise == "query")[:3]

    with tqdm(total=n_q * len(passes), desc="rSHOSM evidence", unit="frame", leave=False, disable=not progress) as bar:
        for adj_name, order in passes:
            b = Beam(g["n_cells"], g["n_cols"], n_db)
            chunks = range(len(starts)) if adj_name == "fwd" else range(len(starts) - 1, -1, -1)
            for c in chunks:
                q0, q1 = starts[c], min(starts[c] + chunk, n_q)
                frames = order[q0:q1] if adj_name == "fwd" else order[n_q - q1:n_q - q0]
                cols = b.run(g, g[adj_name], q_ptr, q_ind, frames, limits[q0:q1], params)
                bar.update(q1 - q0)
                if adj_name == "bwd":  # columns came in reverse query order
                    finish_chunk(c, held.pop(c), reverse_columns(*cols))
                elif len(passes) == 1:
                    finish_chunk(c, cols, NO_PASS)
                else:
                    # held until the backward pass comes back to this chunk: stored as the dense
                    # evidence is (float32), with 32-bit frame numbers, half the bytes of the pass's own
                    held[c] = (cols[0], cols[1].astype(np.int32), cols[2].astype(np.float32))
            largest_beam, largest_cand = b.largest
            seen["max_beam"] = max(seen["max_beam"], largest_beam)
            seen["max_candidates"] = max(seen["max_candidates"], largest_cand)
            del b
    if stats is not None:
        stats.update(seen)
    parts = [done[c] for c in range(len(starts))]
    if parts:
        S = sp.hstack([p[0] for p in parts], format="csr")
        S.sort_indices()
        best, score = np.concatenate([p[1] for p in parts]), np.concatenate([p[2] for p in parts])
    else:
        S, best, score = sp.csr_matrix((n_db, 0), dtype=np.float32), np.zeros(0, np.int64), np.zeros(0)
    return EvidenceResult(S, best, score)
