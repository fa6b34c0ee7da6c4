"""The base class of the place-recognition methods."""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from vpr.checks import check_exclude, check_top_k
from vpr.config import merge_conf
from vpr.similarity import best_matches, mask_recent
from vpr.types import (
    ENCODER_INPUTS,
    Decision,
    EncodedTraverse,
    FollowingLocalizer,
    ImageInput,
    LateLocalizer,
    MapLocalizer,
    MatchResult,
    StreamDetector,
)

__all__ = ["Method", "Fitted"]


class Method:
    """A place-recognition method, configured once (``**conf`` over ``default_conf``), run on encoded traverses.

    Subclasses set ``name``, ``default_conf``, ``nullable_conf``, ``no_loops_reason`` and ``required_inputs``, and
    implement :meth:`_match` and, for loop closure, :meth:`_loops`. :meth:`check_size` refuses inputs too large before
    any work; :meth:`warm_up` compiles outside the timed region.
    """

    name: str = "base"
    default_conf: dict = {}
    nullable_conf: frozenset = frozenset()
    #: why :meth:`loops` is refused, for methods that do not override :meth:`_loops`
    no_loops_reason: str = ""
    #: what the similarity matrix holds (the colour bar of its heatmap)
    score_label: str = "similarity"
    #: the :class:`~vpr.types.EncodedTraverse` inputs read: ``"sdr"``, ``"desc"`` (from the encoder) or the
    #: name of one of :attr:`image_inputs`
    required_inputs: tuple = ()
    #: inputs this method computes from the images itself, by name (the extraction stage provides them)
    image_inputs: dict = {}

    #: the conf key that is the width of the SDRs the method reads (None: it reads any width), which follows the
    #: encoder's (:meth:`conf_for_sdrs`)
    sdr_width_key: str | None = None

    def __init__(self, **conf):
        self.conf = merge_conf(self.default_conf, conf, self.name, nullable=self.nullable_conf)
        if "top_k" in self.conf:
            check_top_k(self.conf["top_k"], f"{self.name}: top_k", nullable="top_k" in self.nullable_conf)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({', '.join(f'{k}={v!r}' for k, v in self.conf.items())})"

    def need(self, traverse: EncodedTraverse, key: str, role: str):
        """``traverse.inputs[key]``, or a ValueError saying that this method needs it for the ``role`` traverse."""
        value = traverse.inputs.get(key)
        if value is None:
            what = ENCODER_INPUTS.get(key)
            if what is None:
                spec: ImageInput | None = self.image_inputs.get(key)
                what = spec.description if spec is not None else f"input {key!r}"
                raise ValueError(f"{self.name} needs {what} of the {role} traverse, but none were extracted")
            raise ValueError(f"{self.name} needs {what} of the {role} traverse, but the encoder produced none")
        return value

    @classmethod
    def conf_for_sdrs(cls, conf: dict, n_bits: int | None, encoder: str = "the encoder") -> dict:
        """``conf`` with the width of the SDRs read (:attr:`sdr_width_key`) set to the encoder's ``n_bits``; a width
        given otherwise is refused before any frame is encoded (ValueError naming both settings and the fix)."""
        key = cls.sdr_width_key
        if key is None or n_bits is None:
            return dict(conf)
        given = conf.get(key)
        if given is not None:
            try:
                differs = int(str(given)) != int(n_bits)
            except ValueError:
                return dict(conf)  # refused by the conf's own check, naming the value
            if differs:
                raise ValueError(f"--method-conf {cls.name}.{key}={given}: {encoder} makes SDRs of {int(n_bits)} "
                                 f"bits, which {cls.name} reads at their width by itself: leave {key} out, or give "
                                 f"the encoder {given} bits (--encoder-conf n_bits={given})")
        return {**conf, key: int(n_bits)}

    # ----------------------------------------------------------- to override
    def check_size(self, n_db: int, n_q: int) -> None:
        """Raise ValueError if ``n_db x n_q`` is too large for this method (default: any size)."""

    def check_matching(self, online: bool = False) -> None:
        """Raise ValueError if a setting given applies to loop closure within one stream only (database x query
        matching and localisation refuse it before a frame is read), or to online localisation only where not
        ``online``; default: every setting applies."""

    def check_loops(self) -> None:
        """Raise ValueError if a setting given does not apply to loop closure within one stream (refused before a
        frame is read; default: every setting applies)."""

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) the method's kernels.

        The first run after an install otherwise spends seconds compiling, which would be reported as the method's
        matching time.
        """

    #: whether loop closure is decided frame by frame (a second opinion can wrap the decider)
    decides_frames: bool = False
    #: whether the method's sequences follow a query that moves one database frame a frame (a query driven at
    #: another speed is matched again at the sampling that makes the two agree: :func:`vpr.methods.match_at_speed`)
    follows_sequences: bool = False
    #: whether the method reads the frames as a sequence, in their order (a source that keeps none is refused)
    reads_order: bool = True
    #: whether the method runs online, one frame at a time as it comes: the online face below (``vpr loops -``,
    #: ``vpr learn`` / ``vpr localize``)
    runs_online: bool = False

    # ----------------------------------------------------------- the online face (runs_online)
    def loop_detector(self, encoder=None, exclude: int = 1, opinion=None) -> StreamDetector:
        """Loop closure one frame at a time with this conf: ``encoder`` (a :class:`~vpr.types.FrameEncoder`, None:
        SDR rows), ``exclude`` (frames closer are not candidates), ``opinion`` (a second opinion around its
        decision, where :attr:`decides_frames`). Its :attr:`~vpr.types.StreamDetector.meta` names this method."""
        raise ValueError(f"{self.name} does not run online (one frame at a time as it comes)")

    @classmethod
    def resume_loop_detector(cls, path, encoder=None, opinion=None) -> StreamDetector:
        """The detector its :meth:`~vpr.types.StreamDetector.save` wrote to ``path``, continuing where it was saved
        (``encoder``: a fresh one of the kind its meta names, its state restored)."""
        raise ValueError(f"{cls.name} does not run online (one frame at a time as it comes)")

    @classmethod
    def saved_loop_meta(cls, path) -> dict:
        """The meta of a detector state written by this method (and ``opinion``: whether it decided with one)."""
        raise ValueError(f"{cls.name} does not run online (one frame at a time as it comes)")

    def localizer(self, db_sdr, names, progress: bool = False, sessions=None) -> MapLocalizer:
        """Learn the database ``db_sdr`` (frames x bits, named ``names``; ``sessions``: the first frame of each run of
        a multi-session map) into what a map holds."""
        raise ValueError(f"{self.name} does not run online (one frame at a time as it comes)")

    @classmethod
    def restore_localizer(cls, header: dict, parts: dict, names) -> MapLocalizer:
        """The localizer a map file holds (:meth:`~vpr.types.MapLocalizer.map_state`), continuing its state."""
        raise ValueError(f"{cls.name} does not run online (one frame at a time as it comes)")

    def follower(self, localizer: MapLocalizer, sdr=None) -> FollowingLocalizer | None:
        """What answers a query driven at another speed than the map over ``localizer`` (``sdr``: the map's SDRs, to
        learn it again at another sampling); None (the default): the query's frames as they come."""
        return None

    def late(self, localizer: MapLocalizer, answering=None) -> LateLocalizer | None:
        """What answers each query frame a few frames late, with the evidence of the frames after it, over
        ``answering`` (``localizer`` or its :meth:`follower`); None (the default, or a lag of 0): every frame at
        once."""
        return None

    def loop_conf(self):
        """The conf its loop closures within one stream are decided by, frame by frame (a
        :class:`vpr.shosm.RshosmSeqConf`: its loop rule and confirmation), or None (default: a method without one)."""
        return None

    @property
    def supports_loops(self) -> bool:
        """Whether :meth:`loops` (loop closure within one traverse) is implemented."""
        return type(self)._loops is not Method._loops

    @property
    def block_margin(self) -> int | None:
        """Query frames of context a block of queries needs on each side to get the answers of the whole traverse
        (:meth:`Fitted.match_block`), None when the method cannot be split. A method that can also takes
        ``shape=(n_db, n_q)`` in :meth:`_match_fitted`: the size of the whole match (dense or top-K is chosen by
        it, not by the block's)."""
        return None

    def decisions(self, S, best: np.ndarray, score: np.ndarray) -> Decision:
        """The decision over a traverse's similarity ``S`` whose best matches are ``best`` (scoring ``score``).

        The one decision hook: by default a best match with a finite score is accepted; methods override it with their
        own rule (which may run over every query in order). A run that decides itself returns its
        :class:`~vpr.types.Decision` instead (SeqSLAM's uniqueness ratio).
        """
        score = np.asarray(score, np.float64)
        best = np.where(np.isfinite(score), np.asarray(best, np.int64), -1)
        return Decision(best, score, best >= 0)

    def decision_inputs(self, state, db: EncodedTraverse, query: EncodedTraverse, evidence=None) -> dict:
        """What :meth:`decisions` reads besides the similarity, as its keyword arguments (``state``: :meth:`_fit`'s;
        ``evidence``: what the method's own match computed that it reads again, where the match passes it); none by
        default."""
        return {}

    def _match(self, db: EncodedTraverse, query: EncodedTraverse, progress: bool):
        """(similarity, Decision or None: :meth:`decisions` on the best matches).

        Methods that learn the database implement :meth:`_fit` and
        :meth:`_match_fitted` instead (:meth:`match` is ``fit``, then the fitted match).
        """
        raise NotImplementedError

    def _fit(self, db: EncodedTraverse, progress: bool):
        """What the method learns from the database alone (None: nothing; methods that learn override it)."""
        return None

    def _match_fitted(self, state, db: EncodedTraverse, query: EncodedTraverse, progress: bool):
        """:meth:`_match` given ``state = _fit(db)`` (must not change ``state``: it serves many queries)."""
        return self._match(db, query, progress)

    def _loops(self, seq: EncodedTraverse, exclude: int, progress: bool, sessions=(0,)):
        """(similarity before masking, Decision or None): loop closure within one traverse; ``sessions``: the first
        frame of each session of the stream. Not overridden: unsupported."""
        raise NotImplementedError

    def _result(self, S, d: Decision | None, seconds: float) -> MatchResult:
        if d is None:
            d = self.decisions(S, *best_matches(S))
        best = np.asarray(d.best, np.int64)
        score = np.where(best >= 0, np.asarray(d.score, np.float64), -np.inf)
        return MatchResult(self.name, S, best, score, np.asarray(d.accepted, bool) & (best >= 0), seconds,
                           dict(self.conf), reversed=int(np.count_nonzero(d.reversed)))

    # ---------------------------------------------------------------- public
    def match(self, db: EncodedTraverse, query: EncodedTraverse, progress: bool = False) -> MatchResult:
        """Match every query frame against the database traverse (:meth:`fit`, then :meth:`Fitted.match`)."""
        self.check_size(len(db), len(query))
        return self.fit(db, progress).match(query, progress)

    def fit(self, db: EncodedTraverse, progress: bool = False, once: bool = False) -> Fitted:
        """Learn the database once; the :class:`Fitted` result matches any number of query traverses.

        A fleet of query traverses against one map learns the map once (and ships it to workers once); each query's
        answers are those of
        :meth:`match` on that query alone. ``once``: for one query, learned
        when it is matched and not kept after (a run of several methods then holds one method's learned database at a
        time, not all of them).
        """
        if once:
            return Fitted(self, db, None, 0.0, once=True)
        self.warm_up()
        t = time.perf_counter()
        state = self._fit(db, progress)
        return Fitted(self, db, state, time.perf_counter() - t)

    def loops(self, seq: EncodedTraverse, exclude: int = 1, progress: bool = False, sessions=None,
              opinion=None) -> MatchResult:
        """Loop closures within one traverse: for each frame, the best earlier frame and the decision.

        Candidates are pairs ``i <= j - exclude`` (others ``-inf`` or absent); ``score`` is what the decision
        thresholds. ``sessions``: each session's first frame (``exclude`` within a session; a memory forgets its
        context at each start). ``opinion(decider)``: a second decider around the method's own. Methods without loop
        closure raise ValueError.
        """
        exclude = check_exclude(exclude)
        sessions = tuple(sorted({0, *(int(s) for s in (sessions or ()))}))
        if sessions[-1] >= max(len(seq), 1) or sessions[0] < 0:
            raise ValueError(f"sessions must start at frames 0 .. {len(seq) - 1}, got {list(sessions)}")
        if not self.supports_loops:
            raise ValueError(self.no_loops_reason or f"{self.name} does not support loop closure within one traverse")
        self.check_size(len(seq), len(seq))
        self.warm_up()
        t = time.perf_counter()
        if opinion is not None and not self.decides_frames:
            raise ValueError(f"a second opinion wraps a decision taken frame by frame (rshosm-seq's), not "
                             f"{self.name}'s")
        S, d = self._loops(seq, int(exclude), progress, sessions, **({"opinion": opinion} if opinion else {}))
        S = mask_recent(S, exclude, sessions)
        return self._result(S, d, time.perf_counter() - t)


class Fitted:
    """A method with its database learned (:meth:`Method.fit`): ``match(query)`` for any number of queries.

    Picklable, so that a cluster receives it once and matches many query traverses with it. ``seconds``: the learning
    time, counted in every query's :attr:`MatchResult.seconds` (as :meth:`Method.match` counts it). ``once``: learned
    at :meth:`match` and not kept (``Method.fit(once=True)``).
    """

    def __init__(self, method: Method, db: EncodedTraverse, state, seconds: float, once: bool = False):
        self.method, self.db, self.state, self.seconds, self.once = method, db, state, float(seconds), once

    @property
    def name(self) -> str:
        return self.method.name

    def match(self, query: EncodedTraverse, progress: bool = False) -> MatchResult:
        """Match every frame of ``query`` against the learned database."""
        m = self.method
        m.check_size(len(self.db), len(query))
        m.warm_up()
        t = time.perf_counter()
        state = m._fit(self.db, progress) if self.once else self.state
        S, d = m._match_fitted(state, self.db, query, progress)
        del state  # a state learned for this query alone goes before the result is evaluated and written
        return m._result(S, d, self.seconds + time.perf_counter() - t)

    def match_block(self, query: EncodedTraverse, start: int, stop: int):
        """(similarity columns, best, score) of queries ``start:stop``, computed on them and
        :attr:`Method.block_margin` frames on each side: a part of :meth:`match` that a worker can run alone.

        Raises ValueError for a method that cannot be split.
        """
        a, b = self.block_bounds(start, stop, len(query))
        return self.match_part(query.slice(a, b), start - a, stop - a, len(query))

    def block_bounds(self, start: int, stop: int, n_q: int) -> tuple[int, int]:
        """The query frames a block ``start:stop`` is computed on: :attr:`Method.block_margin` more on each side."""
        w = self.method.block_margin
        if w is None:
            raise ValueError(f"{self.method.name} cannot match a query traverse in blocks")
        return max(start - w, 0), min(stop + w, n_q)

    def match_part(self, part: EncodedTraverse, lo: int, hi: int, n_q: int):
        """(similarity columns, best, z) of frames ``lo:hi`` of ``part`` (a block with its margins) of a query
        traverse of ``n_q`` frames: what a worker computes (:meth:`match_block`)."""
        if self.once:
            raise ValueError(f"{self.method.name}: learned for one match (fit(once=True)), not for blocks")
        S = self.method._match_fitted(self.state, self.db, part, False, shape=(len(self.db), n_q))[0]
        S = S[:, lo:hi] if not sp.issparse(S) else sp.csc_matrix(S)[:, lo:hi].tocsr()
        best, z = best_matches(S)
        return S, best, z

    def combine(self, blocks, seconds: float, query: EncodedTraverse) -> MatchResult:
        """The :class:`MatchResult` of the whole ``query`` traverse from its blocks (in order), decided over all."""
        m = self.method
        parts = [b[0] for b in blocks]
        S = sp.hstack([sp.csr_matrix(p) for p in parts]).tocsr() if sp.issparse(parts[0]) else np.hstack(parts)
        best = np.concatenate([b[1] for b in blocks]).astype(np.int64)
        z = np.concatenate([b[2] for b in blocks]).astype(np.float64)
        return m._result(S, m.decisions(S, best, z, **m.decision_inputs(self.state, self.db, query)),
                         self.seconds + seconds)

    def __repr__(self) -> str:
        return f"Fitted({self.method!r}, db={len(self.db)} frames)"
