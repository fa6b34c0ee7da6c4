"""``rshosm``: the paper's sequence memory; winner codes compared by overlap."""
from __future__ import annotations

import scipy.sparse as sp

from vpr import sdr, similarity
from vpr.shosm import SequenceMemory, pad_codes
from vpr.similarity import TOP_K, top_k_or_dense
from vpr.types import EncodedTraverse

from .base import Method

__all__ = ["Rshosm", "warm_up_memory"]


def warm_up_memory() -> SequenceMemory:
    """Compile (or load from numba's cache) the memory's kernels on a tiny input; returns the tiny memory."""
    tiny = sdr.from_indices([[0, 1, 2, 3]] * 2, 64)
    mem = SequenceMemory(n_inputs=64, cells_per_column=2, new_columns=1)
    mem.run(tiny)
    return mem


class Rshosm(Method):
    """rSHOSM (Neubert et al. 2018): learn the database, run the query without learning, compare winner codes.

    Conf: the :class:`~vpr.shosm.SequenceMemory` parameters, and ``top_k`` (entries kept per query when the similarity
    matrix is too large to be dense). In :meth:`loops` the memory learns while it runs, as in the paper.
    """

    name = "rshosm"
    sdr_width_key = "n_inputs"
    score_label = "winner-cell overlap"
    default_conf = {**SequenceMemory.default_params(), "top_k": TOP_K}
    nullable_conf = frozenset({"seed"})
    required_inputs = ("sdr",)
    follows_sequences = True

    def __init__(self, **conf):
        super().__init__(**conf)
        try:  # checked here, where the conf is built, not when the first memory is
            SequenceMemory.check_params(**{k: self.conf[k] for k in SequenceMemory.default_params()})
        except ValueError as e:
            raise ValueError(f"{self.name}: {e}") from None

    def memory(self) -> SequenceMemory:
        """A new, empty memory with this method's parameters."""
        return SequenceMemory(**{k: self.conf[k] for k in SequenceMemory.default_params()})

    def warm_up(self) -> None:
        warm_up_memory()

    def decisions(self, S, best, score):
        d = super().decisions(S, best, score)
        d.accepted &= d.score > 0  # an overlap of zero is no evidence
        return d

    def _fit(self, db: EncodedTraverse, progress: bool):
        mem = self.memory()
        db_codes = mem.run(self.need(db, "sdr", "database"), progress=progress)
        mem.reset()
        return mem, db_codes

    def _match_fitted(self, state, db: EncodedTraverse, query: EncodedTraverse, progress: bool):
        mem, db_codes = state
        mem.reset()  # every query starts from the learned memory's fresh context (learning off changes nothing else)
        q_codes = mem.run(self.need(query, "sdr", "query"), learn=False, progress=progress)
        db_codes, q_codes = pad_codes(db_codes, q_codes)
        top_k = top_k_or_dense(len(db), len(query), self.conf["top_k"])
        return similarity.overlap_similarity(db_codes, q_codes, top_k=top_k), None

    def _loops(self, seq: EncodedTraverse, exclude: int, progress: bool, sessions=(0,)):
        n = len(seq)
        x, mem = self.need(seq, "sdr", "sequence"), self.memory()
        bounds = [*sessions, n]
        parts = []
        for a, b in zip(bounds[:-1], bounds[1:], strict=True):  # each session from a fresh context, learning kept
            mem.reset()
            parts.append(mem.run(x[a:b], progress=progress))
        codes = sp.vstack(pad_codes(*parts)).tocsr()
        return similarity.overlap_similarity(codes, top_k=top_k_or_dense(n, n, self.conf["top_k"])), None
