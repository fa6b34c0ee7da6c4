"""``rshosm-seq``: rSHOSM's learned memory, queried for graded sequence evidence (our extension)."""
from __future__ import annotations

import numpy as np

from vpr import sdr
from vpr.shosm import (
    DENSE_EVIDENCE_PAIRS,
    LOOP_EXCLUDE,
    UNMOVED_SHARE,
    Lagged,
    Localizer,
    LoopDetector,
    RshosmSeqConf,
    SequenceMemory,
    SpeedFollower,
    accept_path,
    directions_evidence,
    loop_evidence,
    loop_rule,
    map_places,
    query_evidence,
    refuse_stands,
    reversed_frames,
    standing,
)
from vpr.shosm.conf import without_retired
from vpr.shosm.confirm import warm_up as warm_up_confirmation
from vpr.similarity import top_k_or_dense
from vpr.types import Decision, EncodedTraverse

from .base import Method
from .rshosm import warm_up_memory

__all__ = ["RshosmSeq"]


class RshosmSeq(Method):
    """Learn the database with rSHOSM, then score the query by graded sequence evidence.

    Conf: the flat keys of :class:`vpr.shosm.RshosmSeqConf`, built and checked once (``self.seq``). Dense evidence up
    to
    :data:`~vpr.shosm.DENSE_EVIDENCE_PAIRS` pairs (and the memory budget), the beam's top-``top_k`` beyond. Online
    forms with the same conf: :meth:`loop_detector`, :meth:`localizer`.
    """

    name = "rshosm-seq"
    sdr_width_key = "n_inputs"
    score_label = "z-score of the sequence evidence"
    default_conf = RshosmSeqConf.defaults()
    nullable_conf = RshosmSeqConf.NULLABLE
    required_inputs = ("sdr",)
    follows_sequences = True
    decides_frames = True
    runs_online = True

    def __init__(self, **conf):
        super().__init__(**without_retired(conf, self.name))
        #: the conf, built and checked once: every value is refused here, before any work
        self.seq = RshosmSeqConf.build(self.conf, self.name)
        loop_rule(self.seq.loop_rule)  # a rule not registered is refused now

    def loop_detector(self, encoder=None, exclude: int = LOOP_EXCLUDE, opinion=None) -> LoopDetector:
        """A :class:`vpr.shosm.LoopDetector` with this conf: the answers of :meth:`loops` (with the same ``opinion``
        around the loop rule)."""
        det = LoopDetector(encoder, self.seq, exclude=exclude, opinion=opinion)
        det.meta["method"] = self.name
        return det

    @classmethod
    def resume_loop_detector(cls, path, encoder=None, opinion=None) -> LoopDetector:
        return LoopDetector.load(path, encoder=encoder, opinion=opinion)

    @classmethod
    def saved_loop_meta(cls, path) -> dict:
        return LoopDetector.saved_meta(path)

    def localizer(self, db_sdr, names, progress: bool = False, sessions=None) -> Localizer:
        """A :class:`vpr.shosm.Localizer` with this conf."""
        return Localizer.from_database(db_sdr, names, progress=progress, conf=self.seq, sessions=sessions)

    @classmethod
    def restore_localizer(cls, header: dict, parts: dict, names) -> Localizer:
        return Localizer.restore(header, parts, names)

    def follower(self, localizer: Localizer, sdr=None) -> SpeedFollower:
        """A :class:`vpr.shosm.SpeedFollower`: the maps of one frame in k (learned again from ``sdr``) or the queries
        of one frame in k while the query's speed reads so."""
        return SpeedFollower(localizer, sdr)

    def late(self, localizer: Localizer, answering=None) -> Lagged | None:
        """A :class:`vpr.shosm.Lagged` of the map's ``lag`` (``rshosm-seq.lag``; None where it is 0)."""
        lag = localizer.seq.localize_lag
        return Lagged(localizer, answering, lag) if lag else None

    def loop_conf(self) -> RshosmSeqConf:
        return self.seq

    def check_matching(self, online: bool = False) -> None:
        self.seq.path()  # refuses the keys of loop closure only
        if not online:
            self.seq.refuse_lag("a batch match (it scores each frame with the whole query)")

    def check_loops(self) -> None:
        self.seq.loop()  # refuses the keys of online localisation only

    def warm_up(self) -> None:
        mem = warm_up_memory()
        tiny = sdr.from_indices([[0, 1, 2, 3]] * 2, 64)
        codes = mem.run(tiny)
        # the dense and the sparse kernels: compiling them would otherwise count as matching time
        query_evidence(mem, tiny, codes)
        query_evidence(mem, tiny, codes, top_k=1)
        warm_up_confirmation()  # loop closure's

    def _fit(self, db: EncodedTraverse, progress: bool):
        mem = SequenceMemory(**self.seq.memory_params)
        db_codes = mem.run(self.need(db, "sdr", "database"), progress=progress)
        mem.reset()
        return mem, db_codes

    #: Evidence forgotten by this much is negligible: the relative weight the frames before a block keep after
    #: :attr:`block_margin` frames (``decay ** margin``), in both directions.
    BLOCK_TOLERANCE = 1e-6

    @property
    def block_margin(self) -> int:
        """Frames of warm-up a block of queries needs on each side: the evidence a frame carries forward (and
        backward) is weighted ``decay ** k`` after ``k`` frames, so after ``log(tol) / log(decay)`` frames what came
        before the block weighs less than :attr:`BLOCK_TOLERANCE` of it (0.9: 132 frames). Exact for the dense
        evidence; the sparse beam's floors keep a longer history where they bind (``pipelines.split``)."""
        decay = self.seq.evidence.decay
        return 1 if decay <= 0 else int(np.ceil(np.log(self.BLOCK_TOLERANCE) / np.log(decay)))

    def _match_fitted(self, state, db: EncodedTraverse, query: EncodedTraverse, progress: bool, shape=None):
        seq = self.seq
        mem, db_codes = state  # read, never changed, by the evidence
        q_sdr = self.need(query, "sdr", "query")
        n_db, n_q = shape or (len(db), len(query))  # a block of a larger match takes the path of the whole
        top_k = self._top_k(n_db, n_q)
        if shape is not None:  # a block of a larger match: decided over the whole (Fitted.combine)
            r = query_evidence(mem, q_sdr, db_codes, seq.evidence, direction=seq.direction, top_k=top_k,
                               beam=seq.beam, progress=progress)
            return r.similarity, None
        ev = self._directions(state, q_sdr, top_k, progress)
        r = ev[seq.direction]
        return r.similarity, self.decisions(r.similarity, r.best, r.z,
                                            **self.decision_inputs(state, db, query, evidence=ev))

    def _directions(self, state, q_sdr, top_k, progress: bool = False) -> dict:
        """The evidence of the query in the directions its match and its direction check read (the match's own,
        ``"forward"`` and ``"reversed"``), computed together (:func:`vpr.shosm.directions_evidence`)."""
        mem, db_codes = state
        seq = self.seq
        if seq.direction == "both":
            return directions_evidence(mem, q_sdr, db_codes, seq.evidence, top_k, seq.beam, progress)
        return {d: query_evidence(mem, q_sdr, db_codes, seq.evidence, direction=d, top_k=top_k, beam=seq.beam,
                                  progress=progress) for d in ("forward", "reversed")}

    def _top_k(self, n_db: int, n_q: int) -> int | None:
        """The beam's top-K of a match of ``n_db`` x ``n_q`` frames (None: the dense evidence)."""
        return top_k_or_dense(n_db, n_q, self.seq.top_k, DENSE_EVIDENCE_PAIRS) if self.seq.top_k else None

    def decision_inputs(self, state, db: EncodedTraverse, query: EncodedTraverse, evidence=None) -> dict:
        """The stands of the map (:func:`vpr.shosm.standing`, from the memory's codes) and of the query
        (:func:`vpr.sdr.unmoved` at :data:`vpr.shosm.UNMOVED_SHARE`); each query frame's best z of the causal
        evidence of the query moving along the map and of it running the map backwards (``direction="forward"``
        and ``"reversed"``, :func:`vpr.shosm.reversed_frames`: what :class:`vpr.shosm.Localizer` compares
        online), and which frames the path rule accepts on the reversed evidence (the map's frames in reverse
        order: a confident localisation of the query running the map backwards)."""
        mem, db_codes = state
        q = self.need(query, "sdr", "query")
        ev = evidence or self._directions(state, q, self._top_k(len(db), len(query)))
        ahead, back = ev["forward"], ev["reversed"]
        mirrored = back.similarity[np.arange(len(db))[::-1]]
        return {"stands": (standing(map_places(db_codes, mem.cells_per_column)), sdr.unmoved(q, UNMOVED_SHARE)),
                "direction": (ahead.z, back.z, accept_path(mirrored, self.seq.path()).accepted)}

    def decisions(self, S, best, score, stands=None, direction=None):
        """The decision of a robot localising against the map (vpr localize): a path score, query by query; not
        accepted on a stand of the map or of the query (``stands``: (map, query), :func:`vpr.shosm.refuse_stands`),
        nor where the query runs the map backwards (``direction``: each frame's best z of the evidence along the map
        and of the evidence reversed, :func:`vpr.shosm.reversed_frames`; the first ``MIN_RUN`` frames as they
        read together)."""
        d = accept_path(S, self.seq.path())
        best = np.asarray(best, np.int64)
        accepted = d.accepted & (best >= 0)
        if stands is not None:
            accepted = refuse_stands(best, accepted, *stands)
        back = confident = np.zeros(best.size, bool)
        if direction is not None:
            back = reversed_frames(*direction[:2], causal=False,
                                   moved=None if stands is None else ~np.asarray(stands[1], bool))
            confident = back & np.asarray(direction[2], bool)
        return Decision(best, np.where(best >= 0, d.score, -np.inf), accepted & ~back, d.margin, reversed=confident)

    def _loops(self, seq: EncodedTraverse, exclude: int, progress: bool, sessions=(0,), opinion=None):
        """Loop closures within one stream (:func:`vpr.shosm.loop_evidence`): learned online, scored by causal
        evidence, decided by :func:`vpr.shosm.accept_loops`.
        """
        x = self.need(seq, "sdr", "loop")
        ev = loop_evidence(x, exclude=int(exclude), conf=self.seq, progress=progress, sessions=sessions,
                           opinion=opinion)
        return ev.similarity, ev.decision
