"""A query driven at another speed than the database is matched again at the sampling that makes them agree
(vpr.methods.match_at_speed)."""
import warnings

import numpy as np
import pytest

from vpr import methods, simulate
from vpr.types import EncodedTraverse


def _traverses(speed, seed=3):
    db, q, _, q_place = simulate.aliased_traverses(300, 100, speed=speed, seed=seed)
    name = lambda x: [str(i) for i in range(x.shape[0])]  # noqa: E731
    return EncodedTraverse(name(db), sdr=db), EncodedTraverse(name(q), sdr=q), q_place


def _match(fitted, query):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = methods.match_at_speed(fitted, query)
    return res, [str(w.message) for w in caught]


def _decisions(res, q_place):
    right = res.accepted & (np.abs(res.best - q_place) <= 1)
    return right.sum() / max(res.accepted.sum(), 1), right.mean()


def test_a_faster_query_is_matched_against_maps_of_one_frame_in_two():
    db, q, q_place = _traverses((1.8, 2.2))
    fitted = methods.get("rshosm-seq").fit(db)
    first = fitted.match(q)
    res, said = _match(fitted, q)
    assert res.sampling["db_step"] == 2 and 1.8 <= res.sampling["speed"] <= 2.2
    assert res.similarity.shape == first.similarity.shape == (len(db), len(q))
    assert len(said) == 1 and "learned again as 2 maps of one frame in 2" in said[0]
    (p0, r0), (p1, r1) = _decisions(first, q_place), _decisions(res, q_place)
    assert p1 > p0 + 0.03 and r1 > r0 + 0.1, (p0, r0, p1, r1)
    # each database frame scores in the map of its phase: row i of the result is row i // 2 of that map
    odd = methods.get("rshosm-seq").fit(db.take(np.arange(1, len(db), 2))).match(q)
    np.testing.assert_array_equal(res.similarity[1::2], odd.similarity)
    # and each query frame takes the phase that scores it highest
    even = methods.get("rshosm-seq").fit(db.take(np.arange(0, len(db), 2))).match(q)
    pick = np.where(odd.score > even.score, 2 * odd.best + 1, 2 * even.best)
    np.testing.assert_array_equal(res.best, pick)


def test_a_slower_query_is_matched_as_queries_of_one_frame_in_two():
    db, q, q_place = _traverses((0.45, 0.55))
    fitted = methods.get("rshosm-seq").fit(db)
    res, said = _match(fitted, q)
    assert res.sampling["query_step"] == 2 and res.sampling["speed"] < 0.6
    assert len(said) == 1 and "as 2 queries of one frame in 2" in said[0]
    for a in (0, 1):  # each query frame has the answer of its own phase's query
        part = fitted.match(q.take(np.arange(a, len(q), 2)))
        np.testing.assert_array_equal(res.best[a::2], part.best)
        np.testing.assert_array_equal(res.accepted[a::2], part.accepted)
        np.testing.assert_array_equal(res.similarity[:, a::2], part.similarity)
    assert _decisions(res, q_place)[0] >= 0.99


@pytest.mark.parametrize("method, speed", [("rshosm-seq", (0.9, 1.1)), ("pairwise", (1.8, 2.2))])
def test_nothing_is_matched_again_at_the_same_speed_or_without_sequences(method, speed):
    db, q, _ = _traverses(speed)
    fitted = methods.get(method).fit(db)
    res, said = _match(fitted, q)
    first = fitted.match(q)
    assert res.sampling is None and said == []
    np.testing.assert_array_equal(res.best, first.best)
    np.testing.assert_array_equal(res.accepted, first.accepted)
