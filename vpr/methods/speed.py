"""A query driven at another speed than the database, matched again at the sampling that makes the two agree."""
from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np
import scipy.sparse as sp

from vpr.evaluate import path_speed
from vpr.groundtruth import speed_step
from vpr.types import EncodedTraverse, MatchResult

from .base import Fitted

__all__ = ["match_at_speed"]


def match_at_speed(fitted: Fitted, query: EncodedTraverse, progress: bool = False,
                   match: Callable[[Fitted, EncodedTraverse], MatchResult] | None = None) -> MatchResult:
    """Match ``query`` against the learned database; match again where the query was driven at another speed.

    A method whose sequences follow one database frame a frame (:attr:`Method.follows_sequences`) and whose accepted
    paths move ``k`` >= :data:`~vpr.groundtruth.RATE_RATIO` database frames a query frame (:func:`vpr.evaluate.
    path_speed`, no ground truth; :func:`~vpr.groundtruth.speed_step`) is matched again against one database frame in
    ``k`` (the ``k`` maps of frames ``a, a + k, ...``, learned again; each query frame answered by the map that scores
    it highest) and, moving ``1 / k``, as ``k`` queries of one frame in ``k`` (each frame answered by its own); each
    is said (a warning). The result keeps the traverses' frames and their similarity;
    :attr:`MatchResult.sampling` records the first pass's speed and the step, ``seconds`` both passes.
    ``match(fitted, query)``: how a match runs (default :meth:`Fitted.match`). Returns the first result where nothing
    is to be done or the sampled traverse is too short for the method.
    """
    match = match or (lambda f, q: f.match(q, progress))
    res = match(fitted, query)
    speed = path_speed(res.best, res.accepted)[0]
    k = speed_step(speed) if fitted.method.follows_sequences else 0
    n_db, n_q, method = len(fitted.db), len(query), fitted.method
    if not k or (n_db if k > 0 else n_q) < 2 * abs(k):
        return res
    n, step = (n_db, k) if k > 0 else (n_q, -k)
    phases = [np.arange(a, n, step) for a in range(step)]
    try:
        if k > 0:
            parts = [match(method.fit(fitted.db.take(f), progress, once=fitted.once), query) for f in phases]
        else:
            parts = [match(fitted, query.take(f)) for f in phases]
    except ValueError as e:  # the sampled traverse is too short for the method (SeqSLAM's ``ds``)
        warnings.warn(f"{method.name}: the query moves {speed:.2g} database frames a frame, and one "
                      f"{'database' if k > 0 else 'query'} frame in {step} cannot be matched: {e}", UserWarning,
                      stacklevel=2)
        return res
    order = np.argsort(np.concatenate(phases), kind="stable")  # the phases' frames back in the traverse's order
    sparse = sp.issparse(parts[0].similarity)
    if k > 0:  # each database frame is in one phase's map; a query frame takes the phase that scores it highest
        S = (sp.vstack if sparse else np.vstack)([r.similarity for r in parts])[order]
        best = np.stack([np.where(r.best >= 0, f[np.maximum(r.best, 0)], -1) for r, f in zip(parts, phases,
                                                                                          strict=True)])
        score, accepted = np.stack([r.score for r in parts]), np.stack([r.accepted for r in parts])
        pick = np.argmax(score, axis=0), np.arange(n_q)
        best, score, accepted = best[pick], score[pick], accepted[pick]
        said = f"the database was learned again as {step} maps of one frame in {step}"
    else:  # each query frame is in one phase's query
        S = (sp.hstack if sparse else np.hstack)([r.similarity for r in parts])[:, order]
        best, score, accepted = (np.concatenate([getattr(r, f) for r in parts])[order]
                                 for f in ("best", "score", "accepted"))
        said = f"its frames were matched as {step} queries of one frame in {step}"
    S = S.tocsr() if sparse else S
    warnings.warn(f"{method.name}: along its accepted paths the query moved {speed:.2g} database frames a frame, "
                  f"driven {'faster' if k > 0 else 'slower'} than the database at the same frame rate: {said}, so "
                  "that its sequences follow the query's (docs/localize.md)", UserWarning, stacklevel=2)
    return MatchResult(res.method, S, best, score, accepted, res.seconds + sum(r.seconds for r in parts), res.conf,
                       {"speed": round(float(speed), 3), "db_step" if k > 0 else "query_step": abs(k)})
