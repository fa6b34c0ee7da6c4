"""rSHOSM-seq's parameters, written once: the learning threshold, the evidence and the beam."""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from types import MappingProxyType

import numpy as np

from vpr.checks import check_top_k
from vpr.config import coerce_value, merge_conf
from vpr.similarity import TOP_K

from .kernels.decide import LoopRule as LoopRuleArgs
from .kernels.decide import PathRule
from .memory import SequenceMemory

__all__ = ["RETIRED", "without_retired",
           "LEARN_THRESHOLD", "LOOP_EXCLUDE", "DENSE_EVIDENCE_PAIRS", "SPEEDS", "EvidenceConf", "BeamConf", "LoopConf",
           "PathConf", "memory_params", "RshosmSeqConf", "DECISION_KEYS", "LOCALIZE_LAG",
           "DENSE_LOCALIZE_FRAMES"]

#: Minicolumn threshold of the memory that rSHOSM-seq learns (the paper's is 0.25).
LEARN_THRESHOLD = 0.75

#: Frames closer than this are not loop-closure candidates (``vpr loops --exclude``).
LOOP_EXCLUDE = 30

#: Above this many database x query pairs ``rshosm-seq`` runs the sparse evidence (top-K), below it the dense one.
DENSE_EVIDENCE_PAIRS = 7_000 * 7_000

_NORMALISE = ("query", "none")
#: The evidence's speed models: the map's speed, faster (a skipped map frame free), slower (a repeated one free).
SPEEDS = ("same", "faster", "slower")


def memory_params(conf: Mapping | None = None) -> dict:
    """:class:`SequenceMemory` parameters of rSHOSM-seq (threshold :data:`LEARN_THRESHOLD`), ``conf`` over them.

    Keys of ``conf`` that are not memory parameters are ignored (a method's conf holds both).
    """
    params = {**SequenceMemory.default_params(), "threshold": LEARN_THRESHOLD}
    params.update({k: v for k, v in (conf or {}).items() if k in params})
    return params


class _Conf:
    """Shared helpers of the conf dataclasses."""

    @classmethod
    def keys(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    @classmethod
    def from_conf(cls, conf: Mapping):
        """The fields found in ``conf`` (e.g. a method's whole conf) over the defaults."""
        return cls(**{k: conf[k] for k in cls.keys() if k in conf})

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class EvidenceConf(_Conf):
    """How rSHOSM-seq's graded evidence is carried and standardised.

    Attributes
    ----------
    decay : float in [0, 1)
        Weight of the predicted evidence: a cell's evidence is its feed-forward overlap plus ``decay`` times the best
        evidence that predicts it (``1 / (1 - decay)`` frames of memory).
    stay, skip : float >= 0 or None
        Cost of a repeated (``stay``) or a skipped (``skip``) database frame between two query frames (velocity
        tolerance, as SeqSLAM's velocity search); ``None`` disables that transition.
    normalise : {"query", "none"}
        ``"query"``: each query frame's scores are z-scores over all database frames, so that one threshold means the
        same for every frame.
    speeds : str
        The speed models, ``+``-joined names of :data:`SPEEDS` (e.g. ``"same+faster"``): each an evidence of its own,
        merged by the largest score per pair (:meth:`split`; ``research/docs/localize.md``, "A query driven faster or
        slower").
    """

    decay: float = 0.9
    stay: float | None = 0.05
    skip: float | None = 0.05
    normalise: str = "query"
    speeds: str = "same"

    def __post_init__(self):
        if not 0.0 <= float(self.decay) < 1.0:
            raise ValueError(f"decay must be in [0, 1), got {self.decay}")
        for name in ("stay", "skip"):
            v = getattr(self, name)
            if v is not None and not float(v) >= 0.0:
                raise ValueError(f"{name} must be >= 0 or None, got {v}")
        if self.normalise not in _NORMALISE:
            raise ValueError(f"normalise must be 'query' or 'none', got {self.normalise!r}")
        models = str(self.speeds).split("+")
        if not all(m in SPEEDS for m in models) or len(set(models)) < len(models):
            raise ValueError(f"speeds must join distinct names of {', '.join(SPEEDS)} with '+', got {self.speeds!r}")

    def split(self) -> tuple[EvidenceConf, ...]:
        """One conf per speed model (``speeds`` ``"same"``): ``faster`` with ``skip`` 0, ``slower`` with ``stay`` 0."""
        costs = {"same": {}, "faster": {"skip": 0.0}, "slower": {"stay": 0.0}}
        return tuple(EvidenceConf(**{**self.as_dict(), "speeds": "same", **costs[m]}) for m in self.speeds.split("+"))

    @property
    def costs(self) -> tuple[float, float]:
        """(stay, skip) as the kernels read them: a negative cost disables the transition."""
        return (-1.0 if self.stay is None else float(self.stay)), (-1.0 if self.skip is None else float(self.skip))


@dataclass(frozen=True)
class BeamConf(_Conf):
    """Floors and caps of the sparse evidence (the beam, :func:`vpr.shosm.sparse_evidence`).

    Attributes
    ----------
    floor, rel_floor : float
        A cell stays in the beam while its evidence is above ``max(floor, rel_floor * largest)`` (``0 <= rel_floor <
        1``).
    z_floor : float
        A minicolumn's cells enter by feed-forward only when its overlap fraction with the query SDR is above this.
    max_beam, max_enter : int or None
        Caps that bound the cost per frame whatever the SDRs share: at most ``max_beam`` cells carried (those of
        largest evidence) and at most ``max_enter`` minicolumns entering by feed-forward (those of largest overlap);
        None: no cap.
    """

    floor: float = 0.0
    rel_floor: float = 0.1
    z_floor: float = 0.15
    max_beam: int | None = 8192
    max_enter: int | None = 256

    def __post_init__(self):
        for name in ("floor", "rel_floor", "z_floor"):
            if not float(getattr(self, name)) >= 0.0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if float(self.rel_floor) >= 1.0:
            raise ValueError(f"rel_floor must be < 1, got {self.rel_floor}")
        for name in ("max_beam", "max_enter"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or int(v) != v or int(v) < 1):
                raise ValueError(f"{name} must be an int >= 1 or None (no cap), got {v}")

    def uncapped(self) -> BeamConf:
        """The same floors without caps."""
        return BeamConf(self.floor, self.rel_floor, self.z_floor, None, None)

    @property
    def caps(self) -> tuple[int, int]:
        """(max_beam, max_enter) as the kernels read them: 0 is no cap."""
        return (0 if self.max_beam is None else int(self.max_beam)), (0 if self.max_enter is None else
                                                                       int(self.max_enter))


def _check_path(c) -> None:
    for name in ("drift", "min_score"):
        if not float(getattr(c, name)) > 0.0:
            raise ValueError(f"{name} must be > 0, got {getattr(c, name)}")
    for name in ("back", "ahead"):
        v = getattr(c, name)
        if isinstance(v, bool) or int(v) != v or int(v) < 0:
            raise ValueError(f"{name} must be an integer >= 0, got {v}")
    if not np.isfinite(float(c.island)):
        raise ValueError(f"island must be a finite z-score, got {c.island}")


@dataclass(frozen=True)
class PathConf(_Conf):
    """When a localisation is accepted, query frame by query frame (:class:`vpr.shosm.Localizer`).

    The rule of :class:`LoopConf` (which extends it, same attributes) against a map, with its own defaults
    (``research/docs/localize.md``).
    """

    drift: float = 0.25
    min_score: float = 12.0
    back: int = 4
    ahead: int = 6
    island: float = 1.0

    def __post_init__(self):
        _check_path(self)

    @property
    def rule(self) -> PathRule:
        """The rule as the decision kernel reads it (a named record)."""
        return PathRule(float(self.drift), float(self.min_score), int(self.back), int(self.ahead), float(self.island))


@dataclass(frozen=True)
class LoopConf(PathConf):
    """When a loop closure is accepted, frame by frame (:func:`vpr.shosm.accept_loops`).

    A frame's best earlier frame stands out from every other place by ``z_best - z_other`` (its z-score minus the best
    z-score outside the *island* of neighbouring candidates around it whose z is at least ``island``). Along a path of
    consistent best matches this margin minus ``drift`` is accumulated (never below 0); a closure is accepted when the
    score reaches ``min_score``. Defaults: ``research/docs/loops.md``.

    Attributes
    ----------
    drift : float > 0
        Margin a frame must exceed on average for the score to grow (the "new place" hypothesis wins below it).
    min_score : float > 0
        Score at which a closure is accepted.
    back, ahead : int >= 0
        A frame continues the path when its best earlier frame is at most ``back`` frames behind and ``ahead`` frames
        beyond the path's furthest best so far (tied neighbours, slower or faster revisits).
    island : float
        z-score down to which neighbouring candidates belong to the best place.
    stop_ratio : float in [0, 1)
        A closure onto a place the camera never left is a stop, not a loop (:func:`vpr.shosm.stationary_closures`; 0:
        not checked).
    confirm_frames : int >= 0
        A closure waits for this many frames (its own and the ones after it) and is kept only where they single out its
        place on their own (:class:`vpr.shosm.Confirmation`); 0: decided at once, nothing confirmed.
    confirm_z : float
        How many standard deviations over the other candidates those frames must put the closure's place.
    backfill_frames : int >= 0
        When a closure is accepted (and confirmed), the frames up to this many before it that led up to it on its path
        are accepted with it (:class:`vpr.shosm.Backfill`); they wait meanwhile. 0: nothing accepted back.
    """

    drift: float = 1.25
    min_score: float = 28.0
    stop_ratio: float = 0.35
    confirm_frames: int = 20
    confirm_z: float = 2.5
    backfill_frames: int = 40

    def __post_init__(self):
        super().__post_init__()
        if not 0.0 <= float(self.stop_ratio) < 1.0:
            raise ValueError(f"stop_ratio must be in [0, 1) (0: stops are not checked), got {self.stop_ratio}")
        v = self.confirm_frames
        if isinstance(v, bool) or int(v) != v or int(v) < 0:
            raise ValueError(f"confirm_frames must be an integer >= 0 (0: closures are not confirmed), got {v}")
        if not np.isfinite(float(self.confirm_z)):
            raise ValueError(f"confirm_z must be a finite z-score, got {self.confirm_z}")
        v = self.backfill_frames
        if isinstance(v, bool) or int(v) != v or int(v) < 0:
            raise ValueError(f"backfill_frames must be an integer >= 0 (0: nothing accepted back), got {v}")

    @property
    def rule(self) -> LoopRuleArgs:
        """The rule as the decision kernel reads it (a named record: the path's and the stop check's ratio)."""
        return LoopRuleArgs(*super().rule, float(self.stop_ratio))


#: The decision's keys of loop closure within one stream only.
LOOP_ONLY_KEYS = ("stop_ratio", "confirm_frames", "confirm_z", "backfill_frames")

#: Keys of decision mechanisms that were taken out (``research/docs/decisions.md``, "Each mechanism taken out"): unset
#: in a saved map or detector state (None) they are dropped; set, refused naming why.
RETIRED = {"place_frames": "closures are no longer placed by the frames up to them: the placement changed no answer "
                           "on a stream it was not chosen on (research/docs/decisions.md)"}

#: The decision's keys; left None in :class:`RshosmSeqConf`, a key takes the default of :class:`LoopConf` in one
#: stream, of :class:`PathConf` against a map.
DECISION_KEYS = LoopConf.keys()


def without_retired(conf: Mapping | None, what: str = "rshosm-seq") -> dict:
    """``conf`` without the :data:`RETIRED` keys left unset (None, as a saved map or state holds them); one set
    raises ValueError naming why it was taken out."""
    conf = dict(conf or {})
    for key, why in RETIRED.items():
        if key in conf and conf.pop(key) is not None:
            raise ValueError(f"{what}: {key} was taken out: {why}")
    return conf


#: Online localisation against a map of at most this many frames steps the dense column (``exact``), beyond it the
#: beam, whose cost does not grow with the map (``docs/internals.md``, ``vpr/shosm/localizer.py``).
DENSE_LOCALIZE_FRAMES = 7_000

#: Query frames after a frame whose evidence ``vpr localize`` waits for before it answers the frame, by default
#: (:class:`vpr.shosm.Lagged`; ``research/docs/decisions.md``, "Answers a few frames late").
LOCALIZE_LAG = 10

#: rSHOSM-seq's own keys: ``direction`` of the batch evidence (``"both"`` or the causal ``"forward"``), ``top_k``
#: (frames kept per query; None: all), ``exact`` (the localizer's dense column instead of the beam; None: dense on a
#: map of at most :data:`DENSE_LOCALIZE_FRAMES` frames), ``loop_rule``
#: (a name in :data:`vpr.shosm.LOOP_RULES`), ``lag`` (online localisation's: each frame answered that many frames
#: late, with the evidence of the frames after it; None: :data:`LOCALIZE_LAG`).
_OWN = MappingProxyType({"direction": "both", "top_k": TOP_K, "exact": None, "loop_rule": "path", "lag": None})
_DIRECTIONS = ("both", "forward")


@dataclass(frozen=True)
class RshosmSeqConf:
    """rSHOSM-seq's whole conf, one frozen object: the memory, the evidence, the beam, the decision.

    Built and checked once, by :meth:`build`; the batch method, loop closure and the :class:`Localizer` take it whole.
    :meth:`flat` gives the flat keys of ``--method-conf rshosm-seq.KEY=VALUE``.

    Attributes
    ----------
    memory : mapping
        :class:`SequenceMemory` parameters (threshold :data:`LEARN_THRESHOLD`).
    evidence : EvidenceConf
    beam : BeamConf
    decision : mapping
        The decision keys (:data:`DECISION_KEYS`) given; None: the setting's default.
    direction, top_k, exact, loop_rule
        See :data:`_OWN`.
    """

    memory: Mapping
    evidence: EvidenceConf
    beam: BeamConf
    decision: Mapping
    direction: str
    top_k: int | None
    exact: bool | None
    loop_rule: str = "path"
    lag: int | None = None

    #: Keys that also take None ("none" on the command line).
    NULLABLE = frozenset({"seed", "stay", "skip", "top_k", "max_beam", "max_enter", "lag", "exact", *DECISION_KEYS})

    def __reduce__(self):  # pickled as its flat keys (a map shipped to a Dask cluster holds one)
        return RshosmSeqConf.build, (self.flat(),)

    @staticmethod
    def defaults() -> dict:
        """Every flat key with its default (decision keys None: the setting's own)."""
        return {**memory_params(), **EvidenceConf().as_dict(), **BeamConf().as_dict(), **_OWN,
                **dict.fromkeys(DECISION_KEYS)}

    @classmethod
    def build(cls, conf: Mapping | None = None, what: str = "rshosm-seq") -> RshosmSeqConf:
        """The conf of the flat keys ``conf`` over the defaults, every value checked.

        Strings are read as the default's type; unknown keys and bad values raise ValueError naming ``what`` and the
        key.
        """
        flat = merge_conf(cls.defaults(), without_retired(conf, what), what, nullable=cls.NULLABLE)
        try:
            memory = SequenceMemory.check_params(**{k: flat[k] for k in memory_params()})
            evidence = EvidenceConf.from_conf(flat)
            beam = BeamConf.from_conf(flat)
            loop = LoopConf()
            decision = {k: None if flat[k] is None else coerce_value(k, flat[k], getattr(loop, k))
                        for k in DECISION_KEYS}
            LoopConf(**{k: v for k, v in decision.items() if v is not None})  # refuses bad values now
            PathConf(**{k: v for k, v in decision.items() if v is not None and k in PathConf.keys()})
            if flat["direction"] not in _DIRECTIONS:
                raise ValueError(f"direction must be one of {_DIRECTIONS}, got {flat['direction']!r}")
            top_k = check_top_k(flat["top_k"])
            if not (isinstance(flat["loop_rule"], str) and flat["loop_rule"]):
                raise ValueError(f"loop_rule must name a loop rule, got {flat['loop_rule']!r}")
            lag = flat["lag"]
            if lag is not None:
                lag = coerce_value("lag", lag, 0)
                if isinstance(lag, bool) or int(lag) != lag or int(lag) < 0:
                    raise ValueError(f"lag must be an integer >= 0 (frames; 0: each frame answered at once), got {lag}")
            exact = flat["exact"]
            if exact is not None:  # true, false, or none: the map's size decides (localize_exact)
                exact = coerce_value("exact", exact, False)
        except ValueError as e:
            raise ValueError(f"{what}: {e}") from None
        return cls(MappingProxyType(memory), evidence, beam, MappingProxyType(decision), flat["direction"],
                   None if top_k is None else int(top_k), exact, flat["loop_rule"], None if lag is None else int(lag))

    @classmethod
    def of(cls, *confs, **flat) -> RshosmSeqConf:
        """One checked conf of ``confs`` (each an :class:`RshosmSeqConf`, one of its parts, a mapping of flat keys, or
        None), later ones and the flat keys ``flat`` over earlier."""
        if len(confs) == 1 and isinstance(confs[0], RshosmSeqConf) and not flat:
            return confs[0]
        merged: dict = {}
        for c in confs:
            if c is None:
                continue
            if isinstance(c, RshosmSeqConf):
                merged.update(c.flat())
            elif isinstance(c, _Conf):
                merged.update(c.as_dict())
            elif isinstance(c, Mapping):
                merged.update(c)
            else:
                raise TypeError(f"an rshosm-seq conf is a RshosmSeqConf, one of its parts or a mapping, got "
                                f"{type(c).__name__}")
        return cls.build({**merged, **flat})

    def flat(self) -> dict:
        """The flat keys and values (``--method-conf rshosm-seq.KEY=VALUE``; saved in map and detector files)."""
        return {**self.memory, **self.evidence.as_dict(), **self.beam.as_dict(), "direction": self.direction,
                "top_k": self.top_k, "exact": self.exact, "loop_rule": self.loop_rule, "lag": self.lag,
                **self.decision}

    def replace(self, **flat) -> RshosmSeqConf:
        """This conf with some flat keys changed (checked as :meth:`build`)."""
        return RshosmSeqConf.build({**self.flat(), **flat})

    @property
    def memory_params(self) -> dict:
        """The :class:`SequenceMemory` parameters, as a dict."""
        return dict(self.memory)

    def loop(self) -> LoopConf:
        """The decision within one stream: the keys given over :class:`LoopConf`'s defaults (``lag``, of online
        localisation, refused)."""
        self.refuse_lag("loop closure within one stream")
        return LoopConf(**{k: v for k, v in self.decision.items() if v is not None})

    def path(self, between_sessions: bool = False) -> PathConf:
        """The decision against a map: the keys given over :class:`PathConf`'s defaults.

        The keys of one stream only (:data:`LOOP_ONLY_KEYS`) are refused unless the map is a stream's earlier sessions
        (``between_sessions``).
        """
        own = [k for k in LOOP_ONLY_KEYS if self.decision.get(k) is not None]
        if own and not between_sessions:
            raise ValueError(f"rshosm-seq: {', '.join(own)} applies to loop closure within one stream, not to "
                             "localisation against a map")
        return PathConf(**{k: v for k, v in self.decision.items() if v is not None and k in PathConf.keys()})

    def refuse_lag(self, where: str) -> None:
        """ValueError if ``lag`` is given: it applies to online localisation against a map only."""
        if self.lag is not None:
            raise ValueError(f"rshosm-seq: lag applies to online localisation against a map (vpr localize), not to "
                             f"{where}")

    def localize_exact(self, n_db: int) -> bool:
        """Whether online localisation against a map of ``n_db`` frames steps the dense column (``exact``, default:
        at most :data:`DENSE_LOCALIZE_FRAMES` frames)."""
        return n_db <= DENSE_LOCALIZE_FRAMES if self.exact is None else self.exact

    @property
    def localize_lag(self) -> int:
        """The frames online localisation answers late (``lag``, default :data:`LOCALIZE_LAG`)."""
        return LOCALIZE_LAG if self.lag is None else self.lag

    def resolved(self, setting: str) -> dict:
        """The flat keys with the decision of ``setting`` (``"loops"`` or ``"map"``) filled in (for metrics.json)."""
        if setting == "loops":
            return {**self.flat(), **self.loop().as_dict()}
        return {**self.flat(), **self.path().as_dict(), "lag": self.localize_lag}
