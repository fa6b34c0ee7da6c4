"""Loop closure within one stream: learned online with Algorithm 1, scored with forward graded evidence.

**Our extension, not the paper's** scoring (the paper compares winner codes;
``rshosm`` does that). :func:`loop_evidence` gives every frame's evidence for
the frames far enough back; :func:`accept_loops` decides, frame by frame,
which closures are accepted; :func:`stationary_closures` tells a stop from a loop.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from tqdm import tqdm

from vpr import sdr as _sdr
from vpr.checks import check_count
from vpr.similarity import best_matches

from .beam import BIG, NO_PASS, Beam, beam_params, finish
from .conf import BeamConf, EvidenceConf, memory_params
from .kernels import beam as KB
from .memory import SequenceMemory

__all__ = ["loop_evidence", "accept_loops", "stationary_closures", "LOOP_UNCAPPED_MAX", "LOOP_DENSE_MAX"]

#: Streams up to this many frames are scored by :func:`loop_evidence` without beam caps (``caps="auto"``);
#: beyond, time and memory grow too fast (``benchmarks/bench_loops_scale.py``, ``docs/localize.md``).
LOOP_UNCAPPED_MAX = 10_000

#: Streams up to this many frames get a dense T x T loop matrix; beyond, top-50 sparse.
LOOP_DENSE_MAX = 20_000


def _grown(a, size, fill):
    out = np.full(size, fill, a.dtype)
    out[: a.size] = a
    return out


def loop_evidence(sdr_batch, exclude: int = 30, conf: EvidenceConf | None = None, top_k: int | None = None,
                  memory: dict | None = None, beam: BeamConf | None = None, caps: str | bool = "auto",
                  dense_max: int = LOOP_DENSE_MAX, progress: bool = False):
    """Loop closure within one stream with graded forward sequence evidence, learned online.

    Frame ``j`` is learned with Algorithm 1 (as the paper, one memory over the
    stream) and then scored against the frames ``i <= j - exclude`` with the
    forward (causal) evidence of :func:`vpr.shosm.sparse_evidence`: only the
    past counts. Cells first learned at a frame after ``j - exclude`` take no
    part in the evidence at ``j`` at all (not only masked in the output):
    within one traverse a frame's own evidence would otherwise linger, through
    the stay transition, on the frames just before it and win there.

    Parameters
    ----------
    sdr_batch : SDR batch (T x n_inputs), the stream.
    exclude : int >= 1
        Frames closer than this are not candidates.
    conf : EvidenceConf
        Decay, transition costs, standardisation (z-scores per frame over its candidate frames).
    top_k : int or None
        Earlier frames kept per frame (None: dense T x T up to ``dense_max``
        frames, top-50 beyond).
    memory : dict, optional
        :class:`SequenceMemory` parameters over rSHOSM-seq's (:func:`vpr.shosm.conf.memory_params`).
    beam : BeamConf
        The beam's floors and caps.
    caps : "auto" or bool
        Whether ``beam``'s caps apply. ``"auto"``: not up to
        :data:`LOOP_UNCAPPED_MAX` frames (and while the output is dense), yes
        beyond. Why: in one stream that changes condition, the frames of the
        current condition fill a capped beam and the other condition's frames
        of the same place never enter it (``docs/localize.md``).
    progress : bool
        tqdm progress bar.

    Returns
    -------
    S : T x T (rows: earlier frame i, columns: frame j); dense float32 with
        ``-inf`` outside ``i <= j - exclude``, or a top-K csr matrix.
    codes : csr bool (T x cells), the winner codes learned online.
    """
    conf, beam = conf or EvidenceConf(), beam or BeamConf()
    if int(exclude) < 1:
        raise ValueError(f"exclude must be >= 1, got {exclude}")
    if top_k is not None and int(top_k) < 1:
        raise ValueError(f"top_k must be >= 1 or None, got {top_k}")
    if not (caps == "auto" or isinstance(caps, bool)):
        raise ValueError(f"caps must be 'auto', True or False, got {caps!r}")
    exclude = int(exclude)
    mem = SequenceMemory(**memory_params(memory))
    x = _sdr.check_batch(sdr_batch, n_bits=mem.n_inputs, name="stream SDR batch")
    T = x.shape[0]
    if top_k is None and T > int(dense_max):
        top_k = 50  # a dense T x T would not fit (the project's limit on dense matrices)
    if caps == "auto":
        caps = T > min(int(dense_max), LOOP_UNCAPPED_MAX)
    q_ptr, q_ind = x.indptr.astype(np.int64), x.indices.astype(np.int64)
    params = beam_params(conf, beam if caps else beam.uncapped(), 0.0)
    cpc = mem.cells_per_column
    cap = 1024 * cpc
    g = {"cpc": cpc, "n_cells": cap, "col_size": np.zeros(cap // cpc), "relevant": np.zeros(cap, bool),
         "birth": np.full(cap, BIG, np.int64), "c_head": np.full(cap, -1, np.int64),
         "c_next": np.zeros(16 * T + 16, np.int64), "c_frame": np.zeros(16 * T + 16, np.int64),
         "db_norm": np.ones(max(T, 1), np.float64)}
    a_head, a_next, a_dst = np.full(cap, -1, np.int64), np.zeros(4096, np.int64), np.zeros(4096, np.int64)
    scratch = Beam(cap, cap // cpc, max(T, 1))
    n_nodes = 0
    ptrs, idxs, vals = [np.zeros(1, np.int64)], [], []
    base = 0
    codes_ptr, codes_idx = np.zeros(T + 1, np.int64), []
    for j in tqdm(range(T), desc="rSHOSM loops", unit="frame", leave=False, disable=not progress):
        old_len, ne_old = mem.view().bit_len.copy(), mem.n_connections
        w = mem.run(x[j]).indices.astype(np.int64)
        codes_idx.append(w)
        codes_ptr[j + 1] = codes_ptr[j] + w.size
        v = mem.view()
        if v.n_cells > g["n_cells"]:  # grow everything indexed by cell or minicolumn
            new = max(v.n_cells, 2 * g["n_cells"])
            for name, fill in (("relevant", False), ("birth", BIG), ("c_head", -1), ("col_size", 0.0)):
                g[name] = _grown(g[name], new if name != "col_size" else new // cpc, fill)
            a_head = _grown(a_head, new, -1)
            g["n_cells"] = new
            scratch.grow(new, new // cpc, max(T, 1))
        KB.count_new_entries(g["col_size"], q_ind[q_ptr[j]:q_ptr[j + 1]], old_len, v.bit_len, v.bit_cols)
        ne = v.e_src.size
        if ne > a_next.size:
            a_next, a_dst = np.resize(a_next, max(ne, 2 * a_next.size)), np.resize(a_dst, max(ne, 2 * a_dst.size))
        KB.append_lists(a_head, a_next, a_dst, ne_old, v.e_src[ne_old:], v.e_dst[ne_old:])
        if n_nodes + w.size > g["c_next"].size:
            g["c_next"] = np.resize(g["c_next"], 2 * (n_nodes + w.size))
            g["c_frame"] = np.resize(g["c_frame"], 2 * (n_nodes + w.size))
        KB.append_lists(g["c_head"], g["c_next"], g["c_frame"], n_nodes, w, np.full(w.size, j, np.int64))
        n_nodes += w.size
        g["relevant"][w] = True
        g["birth"][w] = np.minimum(g["birth"][w], j)
        g["db_norm"][j] = max(w.size, 1)
        g["bit_cols"], g["bit_len"] = v.bit_cols, v.bit_len
        p, i, val = scratch.run(g, (a_head, a_next, a_dst), q_ptr, q_ind, np.array([j], np.int64),
                                np.array([j - exclude], np.int64), params)
        ptrs.append(p[1:] + base)
        idxs.append(i)
        vals.append(val)
        base += i.size
    codes = sp.csr_matrix((np.ones(int(codes_ptr[-1]), bool), np.concatenate(codes_idx + [np.zeros(0, np.int64)]),
                           codes_ptr), shape=(T, max(mem.n_cells, 1)))
    cols = (np.concatenate(ptrs), np.concatenate(idxs + [np.zeros(0, np.int64)]),
            np.concatenate(vals + [np.zeros(0)]))
    n_cand = np.maximum(np.arange(T) - exclude + 1, 0).astype(np.int64)
    S_top, _, _, mean, sd = finish(cols, NO_PASS, n_cand, max(T, 1), top_k, conf.normalise == "query")
    if top_k is not None:
        return S_top[:T], codes
    S = np.full((T, T), -np.inf, np.float32)
    i, jj = np.indices((T, T))
    valid = i <= jj - exclude
    S[valid] = np.broadcast_to((-mean / sd).astype(np.float32), (T, T))[valid]
    coo = S_top.tocoo()
    S[coo.row, coo.col] = coo.data
    return S, codes


#: Steps of the best earlier frame between two frames that still continue one closure: a stop (0),
#: a faster revisit (up to 6 frames per frame) or a small step back where neighbouring frames tie.
_CONTINUES = (-2, 6)


def accept_loops(S, z_min: float = 6.0, confirm: int = 8, sdr=None, stop_ratio: float = 0.35):
    """Best earlier frame per frame of a :func:`loop_evidence` matrix and whether it is accepted.

    A closure at frame ``j`` is accepted when its z-score (how far the best
    earlier frame's evidence stands out from all candidate frames') is at least
    ``z_min`` at ``j`` and at the ``confirm`` frames before it, and the best
    earlier frame moved on consistently over them (as a revisit does: between
    -2 and +6 frames per frame). Causal: only frames up to ``j`` are used.
    With the stream's SDRs (``sdr``), a closure onto a place the camera never
    left is not a loop but a stop, and is refused (:func:`stationary_closures`).

    Why: on forward-only drives a wrong earlier frame can stand out for a few
    frames (a repeated facade, a tunnel), a revisit keeps standing out; and a vehicle
    standing at a station or a traffic light for longer than ``exclude`` sees
    the same place again without any loop (``studies/loops_acceptance.py``,
    ``docs/localize.md``).

    Parameters
    ----------
    S : dense or sparse T x T loop matrix (rows earlier frame, columns frame).
    z_min : float
        z-score the closure must reach at every frame of the confirmation.
    confirm : int >= 0
        Frames before ``j`` that must also pass (0: ``j`` alone).
    sdr : SDR batch (T rows), optional
        The stream; without it stops are not checked.
    stop_ratio : float in [0, 1)
        See :func:`stationary_closures` (0: stops are not checked).

    Returns
    -------
    best : int64 per frame (-1: no candidate), score : float64, accepted : bool
    """
    confirm = check_count(confirm, "confirm")
    if not 0.0 <= float(stop_ratio) < 1.0:
        raise ValueError(f"stop_ratio must be in [0, 1) (0: stops are not checked), got {stop_ratio}")
    best, score = best_matches(S)
    best = np.where(np.isfinite(score), best, -1)
    ok = (best >= 0) & (score >= float(z_min))
    step = np.diff(best, prepend=-1)
    link = np.zeros_like(ok)  # frame j continues frame j - 1's closure
    link[1:] = ok[1:] & ok[:-1] & (step[1:] >= _CONTINUES[0]) & (step[1:] <= _CONTINUES[1])
    run = np.zeros(len(ok), np.int64)  # frames in a row that pass, ending at j
    for j in np.flatnonzero(ok):
        run[j] = run[j - 1] + 1 if j and link[j] else 1
    ok = run > confirm
    if sdr is not None and float(stop_ratio) > 0:
        ok &= ~stationary_closures(sdr, best, ok, stop_ratio)
    return best, score, ok


def stationary_closures(sdr, best, accepted, ratio: float = 0.35, chunk: int = 256) -> np.ndarray:
    """Which accepted closures ``best[j] -> j`` are onto a place the camera never left.

    A loop closure means the camera went elsewhere and came back: some frame
    between ``i = best[j]`` and ``j`` looks less like ``j`` than ``ratio`` times
    the overlap of ``i`` and ``j`` (SDR overlap, as a fraction of ``j``'s
    bits). When every frame in between keeps at least that much, the vehicle
    stood still or crept (a station, a traffic light) and the "closure" is a
    stop (``docs/localize.md`` has the overlaps measured at stops, revisits
    and false closures).

    Parameters
    ----------
    sdr : SDR batch (T rows), the stream.
    best : int per frame, the closure's earlier frame (-1: none).
    accepted : bool per frame, the closures to check.
    ratio : float in (0, 1)
    chunk : int
        Frames compared at once (the scan stops at the first frame that left).

    Returns
    -------
    bool per frame: accepted and stationary.
    """
    ratio = float(ratio)
    if not 0.0 < ratio < 1.0:
        raise ValueError(f"stop_ratio must be in (0, 1), got {ratio}")
    x = _sdr.check_batch(sdr, name="sdr").astype(np.float32).tocsr()
    best, accepted = np.asarray(best), np.asarray(accepted, bool)
    if len(best) != x.shape[0] or len(accepted) != x.shape[0]:
        raise ValueError(f"best and accepted need one entry per frame of the stream ({x.shape[0]}), "
                         f"got {len(best)} and {len(accepted)}")
    out = np.zeros(x.shape[0], bool)
    for j in np.flatnonzero(accepted & (best >= 0)):
        i = int(best[j])
        xj = x[j].T
        o_i = (x[i] @ xj).toarray()[0, 0]
        left = False
        for a in range(i + 1, j, chunk):
            o = (x[a:min(a + chunk, j)] @ xj).toarray().ravel()
            if np.any(o < ratio * o_i):
                left = True
                break
        out[j] = not left
    return out
