"""``seqslam``: SeqSLAM (Milford and Wyeth 2012) on pixel or encoder descriptors."""
from __future__ import annotations

import numpy as np

from vpr import similarity
from vpr.baselines.seqslam import difference_matrix, seqslam

from .base import EncodedTraverse, Method, check_dense, need

__all__ = ["SeqSlam"]

_SEQSLAM_ARGS = ("ds", "v_min", "v_max", "v_step", "R", "rwindow", "ratio_threshold", "causal")


class SeqSlam(Method):
    """SeqSLAM: difference matrix, local contrast enhancement, best constant-velocity trajectory.

    Conf: the arguments of :func:`vpr.baselines.seqslam.seqslam`, ``metric``
    of the difference matrix and ``descriptor``: ``"pixel"`` (the SeqSLAM
    thumbnails) or ``"encoder"`` (the encoder's dense descriptors).
    """

    name = "seqslam"
    default_conf = {"ds": 10, "v_min": 0.8, "v_max": 1.2, "v_step": 0.1, "R": 10, "rwindow": 10,
                    "ratio_threshold": 0.9, "causal": False, "metric": "sad", "descriptor": "pixel"}

    def check_size(self, n_db: int, n_q: int) -> None:
        # the contrast enhancement and trajectory search need the whole difference matrix
        check_dense("seqslam", n_db, n_q)

    def inputs(self) -> set[str]:
        return {"pixels" if self.conf["descriptor"] == "pixel" else "desc"}

    def warm_up(self) -> None:
        # the difference matrix and pairwise SAD share one compiled kernel
        similarity.mean_abs_diff(np.zeros((2, 2), np.float32))

    def descriptors(self, feat: EncodedTraverse, role: str):
        """The descriptors ``conf["descriptor"]`` selects."""
        return need(feat, "pixels" if self.conf["descriptor"] == "pixel" else "desc", self.name, role)

    def _run(self, D):
        res = seqslam(D, **{k: self.conf[k] for k in _SEQSLAM_ARGS})
        return res.similarity, res.best_db.astype(np.int64), -res.best_score.astype(np.float64), res.accepted

    def _match(self, db: EncodedTraverse, query: EncodedTraverse, progress: bool):
        D = difference_matrix(self.descriptors(db, "database"), self.descriptors(query, "query"),
                              metric=self.conf["metric"])
        return self._run(D)

    def _loops(self, seq: EncodedTraverse, exclude: int, progress: bool):
        x = self.descriptors(seq, "sequence")
        D = difference_matrix(x, x, metric=self.conf["metric"])
        # recent frames must not win the sequence search: give them the worst difference
        i, j = np.indices(D.shape)
        D[np.abs(i - j) < exclude] = D.max()
        S, _, _, accepted = self._run(D)
        return S, accepted
