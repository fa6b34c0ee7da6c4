"""Online localisation answered a few frames late (vpr.shosm.Lagged, ``rshosm-seq.lag``)."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import vpr
from vpr import methods, simulate
from vpr import shosm as ev
from vpr.shosm import Lagged, PathConf, PathDecider
from vpr.types import Column


@pytest.fixture(scope="module")
def traverses():
    return simulate.aliased_traverses(120, 30, seed=5)


def _names(n):
    return [f"db{i:04d}.png" for i in range(n)]


def _answers(lagged, q, upto=None):
    out = []
    for j in range(q.shape[0] if upto is None else upto):
        out.extend(lagged.update(q[j]))
    return out


def _zscore(D):
    mu, sd = D.mean(axis=0), D.std(axis=0)
    return (D - mu) / np.where(sd > 0, sd, 1.0)


def test_late_by_the_whole_query_is_the_evidence_of_both_directions(traverses):
    db, q, _, _ = traverses
    base = vpr.Localizer.from_database(db, _names(db.shape[0]), exact=True)
    lagged = Lagged(base, lag=q.shape[0])
    got = _answers(lagged, q)
    assert got == []  # every frame waits for the frames after it
    got = lagged.flush()
    assert [d.frame for d in got] == list(range(q.shape[0]))
    both = _zscore(ev.dense_evidence(base.memory, q, base.db_codes, base.seq.evidence.split()[0], "both"))
    for d in got:
        assert np.allclose(d.column.dense(), both[:, d.frame], atol=1e-4)
    # and the path rule of the map on those columns, as vpr compare decides them
    batch = ev.accept_path(both.astype(np.float32), base.seq.path())
    assert np.array_equal([d.best for d in got], batch.best)


def test_a_lag_waits_that_many_frames_and_answers_each_frame_once_in_order(traverses):
    db, q, dp, qp = traverses
    loc = vpr.Localizer.from_database(db, _names(db.shape[0]))
    lagged = Lagged(loc, lag=5)
    seen = []
    for j in range(q.shape[0]):
        ds = lagged.update(q[j])
        assert [d.frame for d in ds] == ([j - 5] if j >= 5 else [])
        seen.extend(ds)
    seen.extend(lagged.flush())
    assert [d.frame for d in seen] == list(range(q.shape[0])) and not lagged.waiting
    best = np.array([d.best for d in seen])
    acc = np.array([d.accepted for d in seen])
    assert acc.sum() > 0.5 * acc.size and np.mean(np.abs(dp[best[acc]] - qp[acc]) <= 1) >= 0.95


def test_lag_zero_answers_at_once_as_the_localizer(traverses):
    db, q, _, _ = traverses
    a = vpr.Localizer.from_database(db, _names(db.shape[0]))
    b = vpr.Localizer.from_database(db, _names(db.shape[0]))
    lagged = Lagged(b, lag=0)
    for j in range(40):
        (d,) = lagged.update(q[j])
        e = a.update(q[j])
        assert (d.best, d.score, d.accepted, d.frame) == (e.best, e.score, e.accepted, e.frame)


def test_a_new_traverse_answers_the_frames_waiting_first(traverses):
    db, q, _, _ = traverses
    lagged = Lagged(vpr.Localizer.from_database(db, _names(db.shape[0])), lag=4)
    _answers(lagged, q, 10)
    assert [d.frame for d in lagged.reset()] == [6, 7, 8, 9]
    assert not lagged.waiting and lagged.base.frames == 0


def test_a_restart_from_the_saved_state_changes_no_answer(traverses, tmp_path):
    db, q, _, _ = traverses
    names = _names(db.shape[0])
    whole = Lagged(vpr.Localizer.from_database(db, names), lag=6)
    want = _answers(whole, q) + whole.flush()
    loc = vpr.Localizer.from_database(db, names)
    first = Lagged(loc, lag=6)
    got = _answers(first, q, 50)
    the_map = vpr.Map("rshosm-seq", loc, {"name": "pixel", "conf": {"k": 200}})
    the_map.save(tmp_path / "m.npz")
    header, arrays = first.state()
    again = methods.load_map(tmp_path / "m.npz").localizer
    second = Lagged(again, lag=6).load_state(header, arrays)
    assert len(second.waiting) == 6
    got += [d for j in range(50, q.shape[0]) for d in second.update(q[j])] + second.flush()
    assert [(d.frame, d.best, d.accepted) for d in got] == [(d.frame, d.best, d.accepted) for d in want]
    assert np.allclose([d.score for d in got], [d.score for d in want])
    with pytest.raises(ValueError, match="frames late"):
        Lagged(vpr.Localizer.from_database(db, names), lag=3).load_state(header, arrays)


def test_lag_is_a_setting_of_online_localisation_only():
    m = methods.get("rshosm-seq", lag=10)
    m.check_matching(online=True)
    with pytest.raises(ValueError, match="lag applies to online localisation"):
        m.check_matching()
    with pytest.raises(ValueError, match="lag applies to online localisation"):
        m.seq.loop()
    with pytest.raises(ValueError, match="lag must be an integer >= 0"):
        methods.get("rshosm-seq", lag=-1)
    assert methods.get("rshosm-seq", lag="12").seq.localize_lag == 12
    assert methods.get("rshosm-seq").seq.localize_lag == ev.LOCALIZE_LAG


def test_exact_is_read_from_its_spelling_or_left_to_the_map():
    # as --method-conf spells it: a string
    assert [methods.get("rshosm-seq", exact=v).seq.exact for v in ("false", "true", "none", "0")] == \
        [False, True, None, False]
    seq = methods.get("rshosm-seq").seq
    assert seq.localize_exact(ev.DENSE_LOCALIZE_FRAMES) and not seq.localize_exact(ev.DENSE_LOCALIZE_FRAMES + 1)
    assert not methods.get("rshosm-seq", exact="false").seq.localize_exact(10)
    with pytest.raises(ValueError, match="exact"):
        methods.get("rshosm-seq", exact="maybe")


def _col(best, frame, n=50, z=3.0):
    v = np.zeros(n, np.float32)
    v[best] = z
    return Column(np.arange(n, dtype=np.int64), v, 0.0, n, frame)


def test_a_path_accepted_on_the_frames_after_it_and_only_before_it_breaks():
    dec = PathDecider(PathConf(drift=0.25, min_score=12.0))
    for t in range(3):  # a path of 3 frames: score 3 * 2.75, below the bar
        assert not dec.decide(_col(t, t)).accepted
    before = dec.st.copy()
    assert dec.accepted_ahead([_col(3, 3), _col(4, 4)])  # 11.0, then 13.75
    assert not dec.accepted_ahead([_col(3, 3)])  # the bar not reached within the frames given
    assert not dec.accepted_ahead([_col(40, 3), _col(41, 4), _col(42, 5)])  # another place: the path broke
    assert np.array_equal(dec.st, before)  # the path's state is left as it was
    dec.new_session()
    assert not dec.accepted_ahead([_col(t, t) for t in range(10)])  # no path to accept


def test_late_frames_are_accepted_on_their_path_ahead_but_not_just_after_a_query_stand(traverses):
    db, q, dp, qp = traverses
    names = _names(db.shape[0])
    lag = Lagged(vpr.Localizer.from_database(db, names), lag=8)
    got = _answers(lag, q) + lag.flush()
    acc = np.array([d.accepted for d in got])
    own = np.array([d.score >= lag.decider.accept_score for d in got])
    assert (acc & ~own).any()  # accepted before its own score reached the bar
    assert np.mean(np.abs(dp[np.array([d.best for d in got])[acc]] - qp[acc]) <= 1) >= 0.95
    # the query stands at its frame 5 for 20 frames (the frame repeated) before any path is accepted: the evidence
    # ran on alone during the stand, so within the evidence's memory after it frames are accepted on their own score
    stood = sp.vstack([q[:5], *[q[5]] * 20, q[5:]]).tocsr()
    lag = Lagged(vpr.Localizer.from_database(db, names), lag=8)
    got = _answers(lag, stood) + lag.flush()
    after = [d for d in got if 26 <= d.frame < 26 + lag.memory_frames]
    assert lag.memory_frames == 10 and sum(d.accepted for d in after) >= 5
    assert all(d.score >= lag.decider.accept_score for d in after if d.accepted)
