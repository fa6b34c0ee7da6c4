"""``rshosm-seq``: rSHOSM's learned memory, queried for graded sequence evidence.

Our extension for matching a query traverse against a learned database
(:meth:`vpr.memory.SequenceMemory.evidence`): the same learned memory, but the
query's feed-forward overlaps and predictions are graded evidence accumulated
along the learned connections in both directions, and each query's scores are
standardised (``normalise="query"``); see ``docs/experiments.md`` for what each
part contributes on Nordland.
"""
from __future__ import annotations

import numpy as np

from vpr import sdr
from vpr.evidence import accept_loops, loop_evidence, sparse_evidence
from vpr.memory import SequenceMemory

from .base import EncodedTraverse, Method, best_matches, need, top_k_or_dense
from .rshosm import warm_up_memory

__all__ = ["RshosmSeq"]


def normalise_columns(S: np.ndarray, how: str) -> np.ndarray:
    """Standardise every query column of a dense S in place (``how="query"``) or leave it (``"none"``)."""
    if how == "none":
        return S
    if how != "query":
        raise ValueError(f"rshosm-seq: normalise must be 'query' or 'none', got {how!r}")
    # each query's evidence has its own scale (how well that winter frame matches anything);
    # z-scores make one threshold mean the same for every query, as SeqSLAM's enhancement does
    for c0 in range(0, S.shape[1], 1024):
        blk = S[:, c0:c0 + 1024]
        sd = blk.std(axis=0)
        blk -= blk.mean(axis=0)
        blk /= np.where(sd > 0, sd, 1.0)
    return S


class RshosmSeq(Method):
    """Learn the database with rSHOSM, then score the query by graded sequence evidence.

    Conf: the :class:`~vpr.memory.SequenceMemory` parameters (``threshold``
    0.75 instead of the paper's 0.25: it keeps a database frame from reusing
    minicolumns sampled from other frames, docs/experiments.md) and the
    arguments of :meth:`~vpr.memory.SequenceMemory.evidence`: ``decay``,
    ``stay`` and ``skip`` (a float >= 0, or ``None`` -- ``"none"`` on the
    command line -- to disable that transition), ``direction``; ``normalise``
    (``"query"`` or ``"none"``); ``z_min`` and ``confirm``: a loop closure is
    accepted when its z-score is at least ``z_min`` at the frame and at the
    ``confirm`` frames before it (:meth:`loops`; :func:`vpr.evidence.accept_loops`),
    and not onto a place the camera never left (``stop_ratio``,
    :func:`vpr.evidence.stationary_closures`);
    ``top_k`` (database frames kept per query
    when database x query exceeds :data:`~vpr.similarity.DENSE_PAIRS_LIMIT`).

    Below the limit the evidence is dense (every cell, every frame; the whole
    matrix is ranked). Above it, :func:`vpr.evidence.sparse_evidence` carries
    only the cells above its floors and keeps the top-``top_k`` database frames
    per query, with the z-scores of the full column. Measured agreement: the
    same best match as the dense evidence for 99.98 % of the queries of aliased
    synthetic traverses of 5,000 x 4,987 frames (``benchmarks/bench_scale.py
    --agree 5000``; ``tests/test_scale.py`` asserts >= 97 % at 600 frames).
    Cost: 50,000 x 49,737 frames of 40-of-2,048-bit SDRs in 71-75 s on one core,
    1.3 GiB peak. SDRs that share many bits between places (pixel encoder)
    let nearly every cell pass the floors, so the beam would grow with the
    database; two caps bound it (:data:`vpr.evidence.BEAM_DEFAULTS`: at most
    8,192 cells carried, 256 minicolumns entering by feed-forward per frame).
    What remains linear in the database per frame is counting the overlaps
    through the inverted index (as in learning). With the caps the best match
    is the dense one for 99.2 % (Nordland 358) and 99.0 % (rendered
    two_seasons, 300 frames) of the queries, where the caps do not bind; where
    they do (two_seasons 64 x 48, 1,000 frames) only 72 %, with R@1 0.54
    instead of the dense 0.41 (docs/benchmarks.md, "Large inputs").
    """

    name = "rshosm-seq"
    default_conf = {**SequenceMemory.default_params(), "threshold": 0.75, "decay": 0.9, "stay": 0.05,
                    "skip": 0.05, "direction": "both", "normalise": "query", "top_k": 50}
    # loops only: a closure is accepted when its z-score is at least z_min at the frame and at the confirm
    # frames before it (vpr.evidence.accept_loops; chosen in studies/loops_acceptance.py)
    default_conf["z_min"] = 6.0
    default_conf["confirm"] = 8
    # loops only: a closure onto a place the camera never left is a stop (vpr.evidence.stationary_closures; 0: off)
    default_conf["stop_ratio"] = 0.35
    nullable_conf = frozenset({"seed", "stay", "skip"})

    def inputs(self) -> set[str]:
        return {"sdr"}

    def warm_up(self) -> None:
        warm_up_memory(evidence=True)
        # the sparse beam's kernels too: compiling them would otherwise count as matching time
        tiny = sdr.from_indices([[0, 1, 2, 3]] * 2, 64)
        mem = SequenceMemory(n_inputs=64, cells_per_column=2, new_columns=1)
        sparse_evidence(mem, tiny, mem.run(tiny), top_k=1)

    def _match(self, db: EncodedTraverse, query: EncodedTraverse, progress: bool):
        c = self.conf
        db_sdr, q_sdr = need(db, "sdr", self.name, "database"), need(query, "sdr", self.name, "query")
        mem = SequenceMemory(**{k: c[k] for k in SequenceMemory.default_params()})
        db_codes = mem.run(db_sdr, progress=progress)
        mem.reset()
        top_k = top_k_or_dense(len(db), len(query), c["top_k"])
        if top_k is not None:
            r = sparse_evidence(mem, q_sdr, db_codes, decay=c["decay"], stay=c["stay"], skip=c["skip"],
                                direction=c["direction"], top_k=top_k, normalise=c["normalise"], progress=progress)
            return r.similarity, r.best_db, r.score, None
        S = mem.evidence(q_sdr, db_codes, decay=c["decay"], stay=c["stay"], skip=c["skip"],
                         direction=c["direction"], progress=progress)
        S = normalise_columns(S, c["normalise"])
        best, score = best_matches(S)
        return S, best, score, None

    def _loops(self, seq: EncodedTraverse, exclude: int, progress: bool):
        """Loop closures within one stream, learned online, scored by forward sequence evidence.

        :func:`vpr.evidence.loop_evidence`: the stream is learned frame by frame
        with Algorithm 1; at frame ``j`` the frames ``i <= j - exclude`` are
        scored with causal (forward) evidence over what the memory had learned
        by ``j - exclude`` (only the past counts; the backward pass of
        :meth:`match` would see the future). T x T over pairs i < j, dense up
        to 20,000 frames, top-50 sparse beyond. A closure is accepted when its
        z-score is at least ``z_min`` over ``confirm`` + 1 frames and the
        camera left the place in between (:func:`vpr.evidence.accept_loops`).
        """
        c = self.conf
        x = need(seq, "sdr", self.name, "loop")
        S, _ = loop_evidence(x, exclude=int(exclude), decay=c["decay"], stay=c["stay"], skip=c["skip"],
                             normalise=c["normalise"], memory={k: c[k] for k in SequenceMemory.default_params()},
                             progress=progress)
        _, _, ok = accept_loops(S, z_min=c["z_min"], confirm=c["confirm"], sdr=x, stop_ratio=c["stop_ratio"])
        return S, ok
