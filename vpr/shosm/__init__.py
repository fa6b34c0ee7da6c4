"""rSHOSM: the sequence memory of Neubert, Ahmad and Protzel (KI 2018), and rSHOSM-seq, our graded evidence over it."""
from vpr.statefile import MemoryFileError

from .backfill import Backfill, backfill_closures
from .conf import (
    DECISION_KEYS,
    DENSE_EVIDENCE_PAIRS,
    DENSE_LOCALIZE_FRAMES,
    LEARN_THRESHOLD,
    LOCALIZE_LAG,
    LOOP_EXCLUDE,
    LOOP_ONLY_KEYS,
    SPEEDS,
    BeamConf,
    EvidenceConf,
    LoopConf,
    PathConf,
    RshosmSeqConf,
    memory_params,
)
from .confirm import Confirmation, confirm_closures
from .connections import Connections, MemoryView
from .decide import (
    LOOP_RULES,
    STAND_FRAMES,
    UNMOVED_SHARE,
    LoopDecider,
    LoopRule,
    PathDecider,
    accept_loops,
    accept_path,
    decide_all,
    loop_rule,
    map_places,
    refuse_stands,
    standing,
    stationary_closures,
)
from .detector import LoopDetector
from .direction import Direction, reversed_frames
from .evidence import (
    Engine,
    Evidence,
    EvidenceEngine,
    LoopEvidence,
    SpeedEngine,
    dense_evidence,
    directions_evidence,
    make_engine,
    query_evidence,
    sparse_evidence,
)
from .follow import (
    PICKS,
    SpeedFollower,
    apart_from_neighbours,
    between_maps,
    check_pick,
    disagree,
    fill_between,
    path_lengths,
    pick_maps,
)
from .graph import Graph
from .lagged import Lagged
from .localizer import Localizer, LocalizerStep
from .loops import LoopStream, loop_evidence
from .memory import SequenceMemory, pad_codes
from .stream_graph import StreamEngine, StreamGraph

__all__ = ["SequenceMemory", "MemoryView", "Connections", "MemoryFileError", "pad_codes",
           "LEARN_THRESHOLD", "LOCALIZE_LAG", "LOOP_EXCLUDE", "LOOP_ONLY_KEYS", "DENSE_EVIDENCE_PAIRS",
           "DENSE_LOCALIZE_FRAMES", "EvidenceConf", "BeamConf",
           "LoopConf", "PathConf", "RshosmSeqConf", "DECISION_KEYS", "SPEEDS", "memory_params", "Graph", "Engine",
           "EvidenceEngine", "SpeedEngine", "make_engine", "Evidence",
           "query_evidence", "directions_evidence", "dense_evidence", "sparse_evidence", "LoopEvidence", "LoopDecider",
           "PathDecider",
           "decide_all",
           "LoopRule", "LOOP_RULES", "loop_rule",
           "accept_loops", "accept_path", "stationary_closures", "STAND_FRAMES", "UNMOVED_SHARE", "map_places",
           "standing", "refuse_stands",
           "Localizer", "LocalizerStep", "Lagged", "LoopStream", "loop_evidence", "Direction", "reversed_frames",
           "StreamGraph", "StreamEngine", "LoopDetector", "Confirmation", "confirm_closures",
           "Backfill", "backfill_closures", "SpeedFollower", "PICKS", "check_pick",
           "pick_maps", "disagree", "apart_from_neighbours", "between_maps", "fill_between", "path_lengths"]
