"""``delta``: Delta Descriptors over the encoder's (or the given) dense descriptors, compared by cosine."""
from __future__ import annotations

from vpr.delta import delta_similarity
from vpr.similarity import check_dense
from vpr.types import EncodedTraverse

from .base import Method

__all__ = ["Delta"]


class Delta(Method):
    """Delta Descriptors (:mod:`vpr.delta`) of the dense descriptors, window ``L`` frames; every best match accepted.

    Dense only: a database x query larger than the memory budget is refused.
    """

    name = "delta"
    score_label = "cosine of the two frames' delta descriptors"
    default_conf = {"L": 16}
    required_inputs = ("desc",)
    no_loops_reason = "delta compares two traverses; within one stream its window sees the revisit's own frames"

    def check_size(self, n_db: int, n_q: int) -> None:
        check_dense("Delta Descriptors' cosine similarity", n_db, n_q)

    def _match(self, db: EncodedTraverse, query: EncodedTraverse, progress: bool):
        S = delta_similarity(self.need(db, "desc", "database"), self.need(query, "desc", "query"), self.conf["L"])
        return S, None
