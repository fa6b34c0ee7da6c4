"""rSHOSM-seq's parameters, written once: the learning threshold, the evidence and the beam.

Every user of the graded evidence (the ``rshosm-seq`` method, the streaming
evidence, loop closure, the localizer) reads its defaults from here:

* :data:`LEARN_THRESHOLD`: the minicolumn threshold rSHOSM-seq learns with
  (the paper's memory uses 0.25; 0.75 keeps a database frame from reusing
  minicolumns sampled from other frames, see ``docs/experiments.md``).
* :class:`EvidenceConf`: how evidence is carried from one frame to the next
  (``decay``, ``stay``, ``skip``) and how a frame's scores are standardised
  (``normalise``).
* :class:`BeamConf`: the floors and caps of the sparse evidence (the beam), and
  :data:`DENSE_EVIDENCE_PAIRS`, the size above which the sparse evidence is used.
* :class:`LoopConf`: when a loop closure is accepted (:func:`vpr.shosm.accept_loops`).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields

import numpy as np

from .memory import SequenceMemory

__all__ = ["LEARN_THRESHOLD", "LOOP_EXCLUDE", "DENSE_EVIDENCE_PAIRS", "EvidenceConf", "BeamConf", "LoopConf",
           "PathConf", "memory_params"]

#: Minicolumn threshold of the memory that rSHOSM-seq learns (the paper's is 0.25).
LEARN_THRESHOLD = 0.75

#: Frames closer than this are not loop-closure candidates, unless told otherwise (``vpr loops --exclude``):
#: the frames just before are the same place seen again a moment later, not a revisit.
LOOP_EXCLUDE = 30

#: Above this many database x query pairs ``rshosm-seq`` runs the sparse evidence (top-K), below it the
#: dense one (every pair ranked): where the sparse path becomes the faster one, measured on image and
#: random SDRs (``benchmarks/bench_scale_images.py``, ``bench_scale.py --agree``; ``docs/benchmarks.md``).
DENSE_EVIDENCE_PAIRS = 7_000 * 7_000

_NORMALISE = ("query", "none")


def memory_params(conf: Mapping | None = None) -> dict:
    """:class:`SequenceMemory` parameters of rSHOSM-seq (threshold :data:`LEARN_THRESHOLD`), ``conf`` over them.

    Keys of ``conf`` that are not memory parameters are ignored (a method's
    conf holds both).
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
        Weight of the predicted evidence: a cell's evidence is its feed-forward
        overlap plus ``decay`` times the best evidence that predicts it
        (``1 / (1 - decay)`` frames of memory).
    stay, skip : float >= 0 or None
        Cost of a repeated (``stay``) or a skipped (``skip``) database frame
        between two query frames (velocity tolerance, as SeqSLAM's velocity
        search); ``None`` disables that transition.
    normalise : {"query", "none"}
        ``"query"``: each query frame's scores are z-scores over all database
        frames, so that one threshold means the same for every frame.
    """

    decay: float = 0.9
    stay: float | None = 0.05
    skip: float | None = 0.05
    normalise: str = "query"

    def __post_init__(self):
        if not 0.0 <= float(self.decay) < 1.0:
            raise ValueError(f"decay must be in [0, 1), got {self.decay}")
        for name in ("stay", "skip"):
            v = getattr(self, name)
            if v is not None and not float(v) >= 0.0:
                raise ValueError(f"{name} must be >= 0 or None, got {v}")
        if self.normalise not in _NORMALISE:
            raise ValueError(f"normalise must be 'query' or 'none', got {self.normalise!r}")

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
        A cell stays in the beam while its evidence is above
        ``max(floor, rel_floor * largest)`` (``0 <= rel_floor < 1``).
    z_floor : float
        A minicolumn's cells enter by feed-forward only when its overlap
        fraction with the query SDR is above this.
    max_beam, max_enter : int or None
        Caps that bound the cost per frame whatever the SDRs share: at most
        ``max_beam`` cells carried (those of largest evidence) and at most
        ``max_enter`` minicolumns entering by feed-forward (those of largest
        overlap); None: no cap.
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

    The rule of :class:`LoopConf` (which extends it) against a map: the best map frame's margin
    over the strongest other place (``z_best - z_other``, outside the best's
    *island*), minus ``drift``, accumulated while the best map frame moves on
    consistently; accepted when the score reaches ``min_score``. A margin, not
    a z-score against every map frame, because a z-score grows and shrinks with
    the size and frame rate of the map. The defaults and how they were chosen:
    ``docs/localize.md``.

    Attributes
    ----------
    drift, min_score, back, ahead, island
        As :class:`LoopConf`. Against a map the margins are smaller than within
        one stream (a query frame competes with every map frame, not only with
        the frames far enough back), so the defaults differ: a small drift, and
        a path is accepted on the sum of its margins.
    """

    drift: float = 0.25
    min_score: float = 12.0
    back: int = 4
    ahead: int = 6
    island: float = 1.0

    def __post_init__(self):
        _check_path(self)


@dataclass(frozen=True)
class LoopConf(PathConf):
    """When a loop closure is accepted, frame by frame (:func:`vpr.shosm.accept_loops`).

    A frame's best earlier frame stands out from every other place by
    ``z_best - z_other`` (its z-score minus the best z-score outside the
    *island* of neighbouring candidates around it whose z is at least
    ``island``). Along a path of consistent best matches this margin minus
    ``drift`` is accumulated (a CUSUM: never below 0); the path's score is the
    decision statistic, and a closure is accepted when it reaches
    ``min_score``. The defaults and how they were chosen: ``docs/loops.md``.

    Attributes
    ----------
    drift : float > 0
        Margin a frame must exceed on average for the score to grow (the "new
        place" hypothesis wins below it).
    min_score : float > 0
        Score at which a closure is accepted.
    back, ahead : int >= 0
        A frame continues the path when its best earlier frame is at most
        ``back`` frames behind and ``ahead`` frames beyond the path's furthest
        best so far (tied neighbours, slower or faster revisits).
    island : float
        z-score down to which neighbouring candidates belong to the best place.
    stop_ratio : float in [0, 1)
        A closure onto a place the camera never left is a stop, not a loop
        (:func:`vpr.shosm.stationary_closures`; 0: not checked).
    """

    drift: float = 1.5
    min_score: float = 24.0
    stop_ratio: float = 0.35

    def __post_init__(self):
        super().__post_init__()
        if not 0.0 <= float(self.stop_ratio) < 1.0:
            raise ValueError(f"stop_ratio must be in [0, 1) (0: stops are not checked), got {self.stop_ratio}")
