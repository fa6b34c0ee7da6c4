"""``pairwise``: every query frame against every database frame, no sequence information."""
from __future__ import annotations

import numpy as np

from vpr import similarity
from vpr.checks import check_choice
from vpr.frame_pairs import METRICS, pairwise
from vpr.similarity import TOP_K, check_dense, top_k_or_dense
from vpr.types import EncodedTraverse

from .base import Method

__all__ = ["Pairwise"]


class Pairwise(Method):
    """Pairwise comparison of SDRs (``on="sdr"``, overlap) or dense descriptors (``on="descriptor"``).

    Conf: ``on``, ``metric`` (see :func:`vpr.frame_pairs.pairwise`) and ``top_k`` (entries kept per query when the SDR
    similarity is too large to be dense; dense descriptors have no sparse form and are refused then).
    """

    name = "pairwise"
    reads_order = False
    score_label = "similarity of the two frames (SDR overlap or descriptor)"
    default_conf = {"on": "sdr", "metric": "auto", "top_k": TOP_K}

    def __init__(self, **conf):
        super().__init__(**conf)
        check_choice(self.conf["on"], f"{self.name}: on", ("sdr", "descriptor"))
        check_choice(self.conf["metric"], f"{self.name}: metric", METRICS)

    @property
    def _attr(self) -> str:
        return "sdr" if self.conf["on"] == "sdr" else "desc"

    @property
    def required_inputs(self) -> tuple:
        return (self._attr,)

    def check_size(self, n_db: int, n_q: int) -> None:
        if self._attr != "sdr":
            check_dense("pairwise comparison of dense descriptors", n_db, n_q)

    def warm_up(self) -> None:
        similarity.mean_abs_diff(np.zeros((2, 2), np.float32))

    def decisions(self, S, best, score):
        d = super().decisions(S, best, score)
        if self._attr == "sdr":
            d.accepted &= d.score > 0  # an SDR overlap of zero is no evidence
        return d

    def _similarity(self, db: EncodedTraverse, query: EncodedTraverse | None):
        a = self.need(db, self._attr, "database" if query is not None else "sequence")
        b = None if query is None else self.need(query, self._attr, "query")
        n_q = len(db) if query is None else len(query)
        top_k = top_k_or_dense(len(db), n_q, self.conf["top_k"]) if self._attr == "sdr" else None
        return pairwise(a, b, metric=self.conf["metric"], top_k=top_k)

    def _match(self, db: EncodedTraverse, query: EncodedTraverse, progress: bool):
        return self._similarity(db, query), None

    def _loops(self, seq: EncodedTraverse, exclude: int, progress: bool, sessions=(0,)):
        return self._similarity(seq, None), None
