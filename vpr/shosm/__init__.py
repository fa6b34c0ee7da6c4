"""rSHOSM: the sequence memory of Neubert, Ahmad and Protzel (KI 2018), and rSHOSM-seq, our graded evidence over it.

One entry point per use:

- :class:`SequenceMemory`: Algorithm 1 of the paper (SHOSM; rSHOSM with
  ``p_extra > 0``): ``step`` / ``run`` learn a stream and return winner cells
  (:mod:`vpr.shosm.memory`).
- :func:`query_evidence`: a query traverse against a learned database, the
  graded evidence of rSHOSM-seq, dense or top-K sparse (:mod:`vpr.shosm.evidence`).
- :class:`ForwardEvidence`: the same, causal, one query frame at a time
  (:mod:`vpr.shosm.streaming`); :class:`Localizer` wraps it with a database
  and a decision for a robot (:mod:`vpr.shosm.localizer`).
- :func:`loop_evidence` and :func:`accept_loops`: loop closure within one
  stream learned online (:mod:`vpr.shosm.loops`); :class:`LoopDetector`: the
  same, one frame at a time, for a robot (:mod:`vpr.shosm.detector`).

:mod:`vpr.shosm.conf` holds rSHOSM-seq's parameters once (:class:`EvidenceConf`,
:class:`BeamConf`, :class:`LoopConf`, :data:`LEARN_THRESHOLD`); :mod:`vpr.shosm.kernels` the
compiled loops. Nothing outside this package reads the memory's private
state: kernels read :meth:`SequenceMemory.view`, users :attr:`SequenceMemory.connections`.
"""
from .conf import (
    DENSE_EVIDENCE_PAIRS,
    LEARN_THRESHOLD,
    LOOP_EXCLUDE,
    BeamConf,
    EvidenceConf,
    LoopConf,
    PathConf,
    memory_params,
)
from .connections import Connections, MemoryView
from .decide import LoopDecider, LoopDecisions, PathDecider, accept_loops, stationary_closures
from .detector import LOOP_DETECTOR_DEFAULTS, LoopDetector, LoopResult
from .evidence import EvidenceResult, dense_evidence, query_evidence, sparse_evidence, zscore_columns
from .localizer import LOCALIZER_DEFAULTS, Localizer, LocalizerResult
from .loops import LOOP_DENSE_MAX, LOOP_UNCAPPED_MAX, FrameLoop, LoopEvidence, LoopStream, loop_evidence
from .memory import MemoryFileError, SequenceMemory, pad_codes
from .streaming import ForwardEvidence, FrameEvidence

__all__ = ["SequenceMemory", "MemoryView", "Connections", "MemoryFileError", "pad_codes",
           "LEARN_THRESHOLD", "LOOP_EXCLUDE", "DENSE_EVIDENCE_PAIRS", "EvidenceConf",
           "BeamConf", "LoopConf", "PathConf", "memory_params",
           "query_evidence", "dense_evidence", "sparse_evidence", "zscore_columns", "EvidenceResult",
           "ForwardEvidence", "FrameEvidence", "Localizer", "LocalizerResult", "LOCALIZER_DEFAULTS",
           "loop_evidence", "LoopEvidence", "LoopStream", "FrameLoop", "accept_loops", "LoopDecider", "LoopDecisions",
           "PathDecider", "stationary_closures", "LOOP_UNCAPPED_MAX", "LOOP_DENSE_MAX", "LoopDetector", "LoopResult",
           "LOOP_DETECTOR_DEFAULTS"]
