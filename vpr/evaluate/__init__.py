"""Place-recognition metrics: plain functions over ``S``, ``gt_hard`` and ``gt_soft``.

Rankings in :mod:`vpr.evaluate.ranking` (AP, curves, recall@K), decisions in
:mod:`vpr.evaluate.decisions` (accepted precision and recall, per-frame
curves, session pairs), the harness that runs and evaluates methods in
:mod:`vpr.evaluate.harness`; every name is here too.

The metrics follow the conventions of the VPR tutorial of Schubert, Neubert,
Garg, Milford and Fischer (IEEE RAM 2023; ``createPR``, ``recallAt100precision``,
``recallAtK``), but evaluate *every* distinct threshold instead of a fixed grid.

Conventions
-----------
``S``
    Similarity matrix, database x query (``n_db x n_q``), higher means more
    similar; for single-stream loop closure it is ``T x T``. It may be a dense
    array or a :mod:`scipy.sparse` matrix holding, e.g., only the top-K entries
    per query. Entries that are not stored, and dense entries equal to
    ``-inf``, mean "never matched": they lie below every threshold, are never
    predicted as matches and never appear in a top-k list. Explicitly stored
    zeros are ordinary similarities. ``S`` must not contain NaN or ``+inf``.
    The one exception is :func:`average_precision`, which ranks *every*
    evaluated pair: never-matched pairs come last, all tied, so a top-K ``S``
    scores exactly as the dense matrix with its missing entries set below
    every stored value.
``gt_hard``
    Boolean matrix (dense or sparse) of the same shape: the true matches.
``gt_soft``
    Optional boolean matrix of the same shape that should contain ``gt_hard``.
    Only its extra pairs ``gt_soft & ~gt_hard`` are used: they are ignored
    entirely, i.e. they are neither true nor false positives, are not counted
    in recall and are removed from rankings.
``mask``
    Optional boolean matrix of the same shape; only pairs where it is True are
    evaluated, both as decisions and as ground-truth positives (loop closure:
    :func:`vpr.groundtruth.loop_closure_mask`).

Matching
--------
``"multi"``
    Every evaluated ``(db, query)`` pair with ``S >= t`` is a predicted match.
    Recall is relative to the number of ``gt_hard`` pairs.
``"single"``
    Each query makes at most one decision: its best database entry (highest
    similarity; on ties the lowest database index). Queries without any true
    match still make that decision, so they can produce false positives.
    Recall is relative to the number of queries with at least one ``gt_hard``
    match.

All sizes in the denominators are counted inside ``mask``. When ``S`` is
sparse, only its stored entries and the nonzeros of ``gt_hard`` are touched,
so ``n_db * n_q`` may be far larger than memory (pass ``gt_hard`` and
``gt_soft`` sparse as well in that case, e.g. from the ``sparse=True`` option
of the builders in :mod:`vpr.groundtruth`).
"""
from .decisions import accepted_precision, best_in_soft_band, decision_curve, outcomes, session_pairs
from .harness import method_metrics, peak_rss_mb, run_methods
from .ranking import auc_from_pr, auc_pr, average_precision, evaluate, pr_curve, recall_at_100p, recall_at_k

__all__ = ["average_precision", "pr_curve", "auc_pr", "auc_from_pr", "recall_at_100p", "recall_at_k", "evaluate",
           "accepted_precision", "best_in_soft_band", "decision_curve", "session_pairs", "outcomes", "method_metrics",
           "run_methods", "peak_rss_mb"]
