"""The one evaluation harness: every method on the same inputs, evaluated against the same ground truth."""
from __future__ import annotations

import resource
import time
from collections.abc import Callable

import numpy as np
import scipy.sparse as sp

from .decisions import accepted_precision, best_in_soft_band, decision_curve, path_speed
from .ranking import RECALL_AT, evaluate, recall_at_n

__all__ = ["method_metrics", "speed_metric", "run_methods", "peak_rss_mb"]


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far, MB (Linux reports kB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _count(g, mask=None) -> int:
    """True pairs of a dense or sparse ground truth inside ``mask``."""
    if mask is not None:
        g = g.multiply(mask) if sp.issparse(g) else mask.multiply(g) if sp.issparse(mask) else np.asarray(g) & mask
    return int(g.count_nonzero() if sp.issparse(g) else np.count_nonzero(g))


def speed_metric(best, accepted) -> float | None:
    """metrics.json's ``path_speed``: :func:`path_speed`, rounded (None without a path)."""
    speed = path_speed(best, accepted)[0]
    return None if speed is None else round(float(speed), 3)


def method_metrics(res, gt_hard, gt_soft, mask=None, loops: bool = False, recall_at=RECALL_AT):
    """(metrics dict, (precision, recall) or None without ground truth) of a :class:`~vpr.types.MatchResult`.

    Always the seconds, the number of accepted matches and ``path_speed`` (:func:`path_speed`: database frames per
    query frame along the accepted paths, None without a path) and, for a result matched again at the query's speed,
    its ``sampling`` (:attr:`~vpr.types.MatchResult.sampling`), ``reversed_frames`` where the query ran the map
    backwards (:attr:`~vpr.types.MatchResult.reversed`); with ground truth the metrics of :func:`evaluate` over
    the evaluated pairs and the precision and recall of the accepted matches. ``loops``: one stream's loop closures,
    where the curve is that of the per-frame decisions (:func:`decision_curve`: ``frame_ap``,
    ``frame_recall_at_100p``), what loop-closure detectors report; a stream without a true loop (a drive without
    revisits) has no ranking or recall to measure: ``revisits`` 0 and the accepted closures, all false
    (``false_per_1000``). With a true match to find, ``recall_at_n``: Recall@N for each of ``recall_at`` over every
    query and over the queries with a true match (:func:`recall_at_n`; loops: each frame is the query, its earlier
    frames outside ``mask``'s exclusion the candidates).
    """
    m = {"seconds": round(res.seconds, 4), "n_accepted": int(np.count_nonzero(res.accepted & (res.best >= 0))),
         "path_speed": speed_metric(res.best, res.accepted)}
    if res.sampling:
        m["sampling"] = dict(res.sampling)
    if res.reversed:
        m["reversed_frames"] = int(res.reversed)
    if gt_hard is None:
        return m, None
    if loops and not _count(gt_hard, mask):
        # a drive without revisits: no ranking or recall to measure, every accepted closure is false
        m.update(accepted_precision(res.best, res.accepted, gt_hard, gt_soft, mask=mask), revisits=0)
        return m, None
    ev, (prec, rec, _) = evaluate(res.similarity, gt_hard, gt_soft, mask=mask, return_curve=True)
    m.update({k: float(v) for k, v in ev.items()})
    m.update(accepted_precision(res.best, res.accepted, gt_hard, gt_soft, mask=mask))
    m["recall_at_n"] = recall_at_n(res.similarity, gt_hard, gt_soft, recall_at, mask=mask)
    if gt_soft is not None:
        m["best_in_soft"] = best_in_soft_band(res.best, gt_hard, gt_soft, mask=mask)
    if loops:
        dm, (prec, rec, _) = decision_curve(res.best, res.score, gt_hard, gt_soft, mask=mask)
        m.update(frame_ap=dm["ap"], frame_recall_at_100p=dm["recall_at_100p"], frames_with_loop=dm["n_with_match"])
    return m, (prec, rec)


def run_methods(runners: dict, call: Callable, gt_hard=None, gt_soft=None, mask=None,
                on_result: Callable | None = None, resources: bool = False, loops: bool = False,
                recall_at=RECALL_AT) -> dict:
    """Run and evaluate every method, one at a time (one similarity matrix alive at once).

    ``runners``: label -> :class:`vpr.methods.Method`; ``call(runner) -> MatchResult``; ground truth None: seconds
    only; ``on_result(label, result, (metrics, curve))`` may return further ``{label: (metrics, curve)}``;
    ``resources``: also ``cpu_seconds`` and ``peak_rss_mb``; ``loops``: one stream, ``recall_at``: the N of Recall@N
    (:func:`method_metrics`). Returns label -> (metrics, curve or None), in the order run.
    """
    out = {}
    for label, runner in runners.items():
        c0 = time.process_time()
        res = call(runner)
        cpu = time.process_time() - c0
        metrics, curve = method_metrics(res, gt_hard, gt_soft, mask=mask, loops=loops, recall_at=recall_at)
        if resources:
            metrics.update(cpu_seconds=round(cpu, 4), peak_rss_mb=round(peak_rss_mb(), 1))
        out[label] = (metrics, curve)
        if on_result is not None:
            out.update(on_result(label, res, (metrics, curve)) or {})
        del res
    return out
