"""rSHOSM-seq's causal (forward) evidence of a query stream against a learned database, one frame at a time.

**Our extension, not the paper's.** What :class:`vpr.shosm.Localizer` runs
for every new camera frame: the same evidence as the batch
``query_evidence(..., direction="forward")``, but frame by frame, with a state
that can be saved and restored.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vpr import sdr as _sdr
from vpr.checks import check_top_k
from vpr.similarity import TOP_K

from .beam import BIG, NO_PASS, Beam, beam_params, check_codes, db_graph, finish
from .conf import BeamConf, EvidenceConf
from .evidence import dense_graph
from .kernels import evidence as KE
from .memory import SequenceMemory

__all__ = ["ForwardEvidence", "FrameEvidence"]


@dataclass
class FrameEvidence:
    """Evidence of one query frame: the best database frame, its score, and the kept database frames.

    ``db_idx`` are the top-K database frames by score (all frames, in index
    order, when ``top_k`` is None) and ``scores`` their z-scores. ``best_db`` is
    -1 (score -inf) when no database frame has any evidence. ``rows`` /
    ``vals``: every database frame with evidence (sorted) and its z-score;
    ``fill``: the z-score of a database frame without evidence (what a
    decision over the whole column reads, :class:`vpr.shosm.PathDecider`).
    """

    best_db: int
    score: float
    db_idx: np.ndarray
    scores: np.ndarray
    rows: np.ndarray
    vals: np.ndarray
    fill: float


class ForwardEvidence:
    """Causal (forward) rSHOSM-seq evidence of a query stream, one frame at a time.

    Cost per frame does not grow with the number of query frames seen: the
    state is the evidence of the last frame (the beam, or with ``exact=True``
    every relevant cell). Answers equal the batch ``direction="forward"`` run
    on the same frames: :func:`vpr.shosm.sparse_evidence` (default) or, with
    ``exact=True``, :func:`vpr.shosm.dense_evidence` standardised per query.
    The memory is read, never changed.

    Parameters
    ----------
    mem : SequenceMemory
        The memory that learned the database.
    db_codes : csr matrix (n_db x cells)
        Winner codes of the database traverse from ``mem.run``.
    conf : EvidenceConf
        Decay, transition costs, standardisation.
    top_k : int or None
        Database frames reported per query frame (None: all).
    exact : bool
        Dense evidence (cost per frame linear in the number of connections)
        instead of the beam.
    beam : BeamConf
        The beam's floors and caps (not with ``exact``).
    """

    def __init__(self, mem: SequenceMemory, db_codes, conf: EvidenceConf | None = None, top_k: int | None = TOP_K,
                 exact: bool = False, beam: BeamConf | None = None):
        top_k = check_top_k(top_k)
        self.mem = mem
        self.conf = conf or EvidenceConf()
        self.beam_conf = beam or BeamConf()
        self.top_k = None if top_k is None else int(top_k)
        self.exact = bool(exact)
        self.db = check_codes(mem, db_codes)
        self.n_db = self.db.shape[0]
        self.frames = 0
        if self.exact:
            self._rel, self._dense = dense_graph(mem, self.db)
            self._e = np.zeros(self._rel.size, np.float64)
            self._out = np.zeros((self.n_db, 1), np.float32)
        else:
            self._g = db_graph(mem, self.db, backward=False)  # causal: forward only
            self._beam = Beam(self._g["n_cells"], self._g["n_cols"], self.n_db)
            self._params = beam_params(self.conf, self.beam_conf, 0.0)

    def update(self, sdr_row) -> FrameEvidence:
        """Score one query frame (SDR row: 1-row batch, bool vector or bit indices; :func:`vpr.sdr.row_bits`)."""
        bits = _sdr.row_bits(sdr_row, self.mem.n_inputs, name="query SDR")
        q_ptr = np.array([0, bits.size], np.int64)
        order = np.zeros(1, np.int64)
        if self.exact:
            self._out[:] = 0.0
            stay, skip = self.conf.costs
            KE.evidence_frames(q_ptr, bits, order, *self._dense, float(self.conf.decay), stay, skip, 0.0, self._out,
                               self._e, self.frames == 0)
            col = self._out[:, 0]
            nz = np.flatnonzero(col)
            a = (np.array([0, nz.size], np.int64), nz.astype(np.int64), col[nz].astype(np.float64))
        else:
            a = self._beam.run(self._g, self._g["fwd"], q_ptr, bits, order, np.full(1, BIG, np.int64), self._params)
        self.frames += 1
        return self._frame(a)

    def _frame(self, a) -> FrameEvidence:
        S, best, score, mean, sd = finish(a, NO_PASS, np.full(1, self.n_db, np.int64), self.n_db, None,
                                          self.conf.normalise == "query")
        C = S.tocoo()
        idx, val = C.row.astype(np.int64), C.data.astype(np.float64)
        fill = float(np.float32(-mean[0] / sd[0])) if self.conf.normalise == "query" else 0.0
        rows = np.argsort(idx, kind="stable")
        column = (idx[rows], val[rows], fill)
        if self.top_k is None:
            scores = np.full(self.n_db, -mean[0] / sd[0], np.float64)
            scores[idx] = val
            if best[0] < 0 and self.n_db:  # no evidence anywhere: all equal, argmax's answer
                best[0], score[0] = 0, scores[0]
            return FrameEvidence(int(best[0]), float(score[0]), np.arange(self.n_db), scores, *column)
        # the top-K as the kernel keeps them (it ranks the float64 z-scores), in order of score
        K = finish(a, NO_PASS, np.full(1, self.n_db, np.int64), self.n_db, self.top_k,
                   self.conf.normalise == "query")[0].tocoo()
        k_idx, k_val = K.row.astype(np.int64), K.data.astype(np.float64)
        order = np.lexsort((k_idx, -k_val))
        return FrameEvidence(int(best[0]), float(score[0]), k_idx[order], k_val[order], *column)

    # ------------------------------------------------------------- state
    def state_dict(self) -> dict:
        """The state after the frames seen so far, as arrays (save with ``np.savez``)."""
        out = {"frames": np.array(self.frames, np.int64)}
        if self.exact:
            out["rel"] = self._rel.copy()
            out["e"] = self._e.copy()
        else:
            out["beam_cells"], out["beam_e"] = self._beam.cells()
        return out

    def load_state(self, state: dict) -> ForwardEvidence:
        """Continue from a :meth:`state_dict` of an object built on the same memory and database."""
        self.frames = int(state["frames"])
        if self.exact:
            if "e" not in state or not np.array_equal(state["rel"], self._rel):
                raise ValueError("state is not from an exact ForwardEvidence on this memory and database")
            self._e[:] = state["e"]
        else:
            if "beam_cells" not in state:
                raise ValueError("state is not from a beam ForwardEvidence (exact=False)")
            cells = np.asarray(state["beam_cells"], np.int64)
            if cells.size and (cells.min() < 0 or cells.max() >= self._g["n_cells"]):
                raise ValueError("state has beam cells outside this memory: another memory's state?")
            self._beam.set_beam(cells, np.asarray(state["beam_e"], np.float64))
        return self
