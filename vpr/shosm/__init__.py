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

:mod:`vpr.shosm.conf` holds rSHOSM-seq's parameters once (:class:`RshosmSeqConf`, the one
frozen conf every entry point takes, of :class:`EvidenceConf`, :class:`BeamConf`,
:class:`LoopConf` / :class:`PathConf`, :data:`LEARN_THRESHOLD`); :mod:`vpr.shosm.state` the one
file format of saved memories, detectors and maps; :mod:`vpr.shosm.kernels` the
compiled loops. Nothing outside this package reads the memory's private
state: kernels read :meth:`SequenceMemory.view`, users :attr:`SequenceMemory.connections`.
"""
from .conf import (
    DECISION_KEYS,
    DENSE_EVIDENCE_PAIRS,
    LEARN_THRESHOLD,
    LOOP_EXCLUDE,
    BeamConf,
    EvidenceConf,
    LoopConf,
    PathConf,
    RshosmSeqConf,
    memory_params,
)
from .connections import Connections, MemoryView
from .decide import LoopDecider, LoopDecisions, PathDecider, accept_loops, accept_path, stationary_closures
from .detector import LoopDetector, LoopResult
from .evidence import EvidenceResult, dense_evidence, query_evidence, sparse_evidence, zscore_columns
from .localizer import Localizer, LocalizerResult
from .loops import LOOP_DENSE_MAX, LOOP_UNCAPPED_MAX, FrameLoop, LoopEvidence, LoopStream, loop_evidence
from .memory import SequenceMemory, pad_codes
from .state import MemoryFileError
from .streaming import ForwardEvidence, FrameEvidence

__all__ = ["SequenceMemory", "MemoryView", "Connections", "MemoryFileError", "pad_codes",
           "LEARN_THRESHOLD", "LOOP_EXCLUDE", "DENSE_EVIDENCE_PAIRS", "EvidenceConf",
           "BeamConf", "LoopConf", "PathConf", "RshosmSeqConf", "DECISION_KEYS", "memory_params",
           "query_evidence", "dense_evidence", "sparse_evidence", "zscore_columns", "EvidenceResult",
           "ForwardEvidence", "FrameEvidence", "Localizer", "LocalizerResult",
           "loop_evidence", "LoopEvidence", "LoopStream", "FrameLoop", "accept_loops", "accept_path", "LoopDecider",
           "LoopDecisions",
           "PathDecider", "stationary_closures", "LOOP_UNCAPPED_MAX", "LOOP_DENSE_MAX", "LoopDetector", "LoopResult"]
