"""``seqslam`` and ``seqslam-desc``: SeqSLAM (Milford and Wyeth 2012) on pixel or encoder descriptors."""
from __future__ import annotations

import numpy as np

from vpr import similarity
from vpr.checks import check_choice, check_int
from vpr.seqslam import SeqSlamConf, difference_matrix, pixel_descriptors, seqslam, seqslam_topk
from vpr.similarity import TOP_K, best_matches, check_dense, mask_recent, top_k_or_dense
from vpr.types import Decision, EncodedTraverse, ImageInput

from .base import Method

__all__ = ["SeqSlam", "SeqSlamDesc", "PIXELS"]

_DESCRIPTORS = {"pixel": "pixels", "encoder": "desc", "desc": "desc"}
_LARGE = ("pairwise", "exact")

#: SeqSLAM's own image descriptor, computed from the images by the extraction stage (not by the encoder).
PIXELS = ImageInput("pixels", "SeqSLAM pixel descriptors (64 x 32 grey, patch-normalised)", pixel_descriptors)


class SeqSlam(Method):
    """SeqSLAM: difference matrix, local contrast enhancement, best constant-velocity trajectory.

    Conf: :func:`vpr.seqslam.seqslam`'s arguments, ``metric`` (``"sad"`` or ``"cosine"``) and ``descriptor``
    (``"pixel"`` thumbnails or ``"encoder"``/``"desc"``). Above :func:`~vpr.similarity.dense_pairs` pairs
    :func:`vpr.seqslam.seqslam_topk` keeps the ``top_k`` best per query, searching around each block's
    ``n_candidates`` best single-frame matches (``large="pairwise"``) or every cell (``"exact"``); loop closure is
    refused there.
    """

    name = "seqslam"
    score_label = "-difference along the best trajectory (darkest rows: no full trajectory fits, ranked last)"
    default_conf = {"ds": 10, "v_min": 0.8, "v_max": 1.2, "v_step": 0.1, "R": 10, "rwindow": 10,
                    "ratio_threshold": 0.9, "causal": False, "metric": "sad", "descriptor": "pixel",
                    "large": "pairwise", "top_k": TOP_K, "n_candidates": TOP_K}

    image_inputs = {"pixels": PIXELS}
    follows_sequences = True

    def __init__(self, **conf):
        super().__init__(**conf)
        check_choice(self.conf.get("descriptor", "encoder"), f"{self.name}: descriptor", _DESCRIPTORS)
        check_choice(self.conf["metric"], f"{self.name}: metric", ("sad", "cosine"))
        check_choice(self.conf["large"], f"{self.name}: large", _LARGE)
        try:  # every value checked here, where the conf is built, not where it is first used
            if self.conf["ds"] == 0:
                raise ValueError("ds: must be an integer >= 1, got 0 (sequences of one frame: that is the pairwise "
                                 "method)")
            #: the trajectory and enhancement parameters, checked once here
            self.params = SeqSlamConf.from_conf(self.conf)
            for key in ("top_k", "n_candidates"):
                check_int(self.conf[key], key, 1)
        except ValueError as e:
            raise ValueError(f"{self.name}: {e}") from None
        self._large = False

    @property
    def _attr(self) -> str:
        return _DESCRIPTORS[self.conf.get("descriptor", "encoder")]

    @property
    def required_inputs(self) -> tuple:
        return (self._attr,)

    def check_size(self, n_db: int, n_q: int) -> None:
        ds = self.conf["ds"]
        for n, role in ((n_q, "query"), (n_db, "database")):
            if ds >= n:
                raise ValueError(f"{self.name}: ds={ds} is a sequence of {ds + 1} frames, but the {role} has {n}: "
                                 "no frame has a whole sequence (a smaller ds, or more frames)")
        # remembered for warm_up: the blocked kernels are compiled only when they will run
        self._large = top_k_or_dense(n_db, n_q, 1) is not None

    def warm_up(self) -> None:
        # the difference matrix and pairwise SAD share one compiled kernel
        similarity.mean_abs_diff(np.zeros((2, 2), np.float32))
        if self._large:
            x = np.zeros((4, 2), np.float32)
            seqslam_topk(x, x, top_k=1, ds=2, R=2, candidates=None if self.conf["large"] == "exact" else "pairwise")

    def descriptors(self, feat: EncodedTraverse, role: str):
        """The descriptors ``conf["descriptor"]`` selects."""
        return self.need(feat, self._attr, role)

    def _run(self, D):
        return self._decided(seqslam(D, **self.params.as_dict()))

    @staticmethod
    def _decided(res):
        """SeqSLAM decides in its run: the uniqueness ratio needs every score, not the kept ones."""
        return res.similarity, Decision(res.best_db.astype(np.int64), -res.best_score.astype(np.float64),
                                        res.accepted)

    def _match(self, db: EncodedTraverse, query: EncodedTraverse, progress: bool):
        a, b = self.descriptors(db, "database"), self.descriptors(query, "query")
        if self._large:
            res = seqslam_topk(a, b, top_k=self.conf["top_k"], metric=self.conf["metric"],
                               candidates=None if self.conf["large"] == "exact" else "pairwise",
                               n_candidates=self.conf["n_candidates"],
                               **self.params.as_dict())
            # a query whose block had no candidate: best_db -1, best_score inf -> score -inf (never matched)
            return self._decided(res)
        return self._run(difference_matrix(a, b, metric=self.conf["metric"]))

    def _loops(self, seq: EncodedTraverse, exclude: int, progress: bool, sessions=(0,)):
        check_dense(f"{self.name} loop closure", len(seq), len(seq))
        x = self.descriptors(seq, "sequence")
        D = difference_matrix(x, x, metric=self.conf["metric"])
        # recent frames must not win the sequence search: give them the worst difference
        i, j = np.indices(D.shape)
        D[np.abs(i - j) < exclude] = D.max()
        S, d = self._run(D)
        # the best earlier frame of the masked matrix, accepted by SeqSLAM's ratio test of its column
        best, score = best_matches(mask_recent(S, exclude, sessions))
        return S, Decision(np.where(np.isfinite(score), best, -1), score, d.accepted & np.isfinite(score))


class SeqSlamDesc(SeqSlam):
    """SeqSLAM on the encoder's own dense descriptors, cosine distance ("SeqSLAM on NetVLAD").

    The same enhancement, trajectory search and large-input handling as
    :class:`SeqSlam` (conf: the same keys but ``descriptor``, which is always
    the encoder's; ``metric`` defaults to ``"cosine"``, the usual distance for CNN and HOG descriptors). Needs an
    encoder with a dense descriptor (``describe``): the error names the encoder otherwise.
    """

    name = "seqslam-desc"
    default_conf = {k: v for k, v in SeqSlam.default_conf.items() if k != "descriptor"} | {"metric": "cosine"}
