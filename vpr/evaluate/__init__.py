"""Place-recognition metrics: plain functions over ``S``, ``gt_hard`` and ``gt_soft``."""
from .decisions import (
    MIN_RUN,
    SpeedReader,
    accepted_precision,
    best_in_soft_band,
    decision_curve,
    outcomes,
    path_run_speeds,
    path_runs,
    path_speed,
    session_pairs,
    session_speeds,
)
from .harness import method_metrics, peak_rss_mb, run_methods, speed_metric
from .ranking import (
    RECALL_AT,
    auc_from_pr,
    auc_pr,
    average_precision,
    evaluate,
    pr_curve,
    recall_at_100p,
    recall_at_k,
    recall_at_n,
    thin_pr,
)

__all__ = ["recall_at_n", "RECALL_AT", "average_precision", "pr_curve", "thin_pr", "auc_pr", "auc_from_pr",
           "recall_at_100p", "recall_at_k", "evaluate", "accepted_precision", "best_in_soft_band", "decision_curve",
           "session_pairs", "outcomes", "path_speed", "path_runs", "path_run_speeds", "SpeedReader", "session_speeds",
           "MIN_RUN", "speed_metric", "method_metrics", "run_methods", "peak_rss_mb"]
