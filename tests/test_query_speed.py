"""A query driven at another speed than the database is matched again at the sampling that makes them agree
(vpr.methods.match_at_speed)."""
import dataclasses
import warnings

import numpy as np
import pytest
import scipy.sparse as sp

from vpr import methods, shosm, simulate
from vpr.shosm import Localizer, LoopConf, SpeedFollower, confirm_closures
from vpr.types import Decision, EncodedTraverse


def _traverses(speed, seed=3):
    db, q, _, q_place = simulate.aliased_traverses(300, 100, speed=speed, seed=seed)
    name = lambda x: [str(i) for i in range(x.shape[0])]  # noqa: E731
    return EncodedTraverse(name(db), sdr=db), EncodedTraverse(name(q), sdr=q), q_place


def _match(fitted, query):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = methods.match_at_speed(fitted, query)
    return res, [str(w.message) for w in caught]


def _lengths(best, back=4, ahead=6):
    """The oracle of a consistent path's length: each frame's best within ``back`` behind and ``ahead`` beyond the
    previous frame's, counted from where it last was not."""
    out, n = [], 0
    for j, b in enumerate(best):
        n = n + 1 if b >= 0 and n and -back <= b - best[j - 1] <= ahead else int(b >= 0)
        out.append(n)
    return np.array(out)


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
    assert p1 >= p0 and r1 > r0 + 0.05, (p0, r0, p1, r1)
    # each database frame scores in the map of its phase: row i of the result is row i // 2 of that map
    odd = methods.get("rshosm-seq").fit(db.take(np.arange(1, len(db), 2))).match(q)
    np.testing.assert_array_equal(res.similarity[1::2], odd.similarity)
    # and each query frame takes the phase that accepts it on the longer consistent path (ties: the first phase)
    even = methods.get("rshosm-seq").fit(db.take(np.arange(0, len(db), 2))).match(q)
    n_even, n_odd = _lengths(even.best), _lengths(odd.best)
    take_odd = (odd.accepted > even.accepted) | ((odd.accepted == even.accepted) & (n_odd > n_even))
    picked = np.where(take_odd, 2 * odd.best + 1, 2 * even.best)
    # accepted unless both accept it more than 3 database frames apart; where both accept it nearer, between them
    apart = even.accepted & odd.accepted & (np.abs(2 * odd.best + 1 - 2 * even.best) > 3)
    both = even.accepted & odd.accepted & ~apart
    np.testing.assert_array_equal(res.best, [_between([2 * e, 2 * o + 1], p) if b else p for e, o, p, b in
                                             zip(even.best, odd.best, picked, both, strict=True)])
    assert (res.best != picked).any()
    np.testing.assert_array_equal(res.accepted, np.where(take_odd, odd.accepted, even.accepted) & ~apart)
    assert res.sampling["db_apart"] == apart.sum()


def _between(answers, picked):
    """The oracle of between_maps for one frame that several maps accept and agree on: the mean of their answers,
    rounded toward the picked map's answer."""
    mean = sum(answers) / len(answers)
    return int(np.ceil(mean)) if picked >= mean else int(np.floor(mean))


def test_maps_of_one_frame_in_k_that_agree_answer_between_them():
    best = np.array([[10, 10, 10, 10, 10, -1, 7], [11, 13, 14, 6, 30, 50, 7]])
    accepted = np.array([[1, 1, 1, 1, 0, 1, 1], [1, 1, 1, 1, 1, 1, 1]], bool)
    chosen = np.array([10, 13, 10, 10, 30, 50, 7])
    # 10 / 11: 10.5 toward 10; 10 / 13: 11.5 toward 13; 10 / 14 and 10 / 6 apart; one map accepts; the same answer
    np.testing.assert_array_equal(shosm.between_maps(best, accepted, chosen, 2), [10, 12, 10, 10, 30, 50, 7])
    three = np.array([[10, 10, -1], [12, 12, 20], [13, 14, 21]])
    np.testing.assert_array_equal(shosm.between_maps(three, three >= 0, [13, 10, 20], 3), [12, 12, 20])
    rng = np.random.default_rng(1)
    for _ in range(200):
        b = rng.integers(-1, 12, (3, 1))
        a = rng.random((3, 1)) < 0.7
        took = a[:, 0] & (b[:, 0] >= 0)
        pick = int(b[took, 0][0]) if took.any() else int(b[0, 0])
        agree = took.sum() >= 2 and np.ptp(b[took, 0]) <= 4
        want = _between(list(b[took, 0]), pick) if agree else pick
        assert shosm.between_maps(b, a, [pick], 3)[0] == want


def test_path_lengths_count_each_frames_consistent_path():
    best = np.random.default_rng(0).integers(-1, 30, 300).cumsum() % 500 - 1
    best[::17] = -1
    np.testing.assert_array_equal(shosm.path_lengths(best, 4, 6), _lengths(best))


def test_maps_of_one_frame_in_k_that_place_a_frame_apart_leave_it_undecided():
    best = np.array([[10, 10, 10, 10, 10, -1], [11, 13, 15, 6, 30, 50]])
    accepted = np.array([[1, 1, 1, 1, 0, 1], [1, 1, 1, 1, 1, 1]], bool)
    np.testing.assert_array_equal(shosm.disagree(best, accepted, 2), [False, False, True, True, False, False])
    three = np.array([[10, 10], [12, 12], [14, 13]])  # step 3: more than 4 apart among those that accept
    np.testing.assert_array_equal(shosm.disagree(three, np.ones((3, 2), bool), 3), [False, False])
    np.testing.assert_array_equal(shosm.disagree(three + [[0, 0], [0, 0], [1, 9]], np.ones((3, 2), bool), 3),
                                  [True, True])


def test_a_slower_query_is_matched_as_queries_of_one_frame_in_two():
    db, q, q_place = _traverses((0.45, 0.55))
    fitted = methods.get("rshosm-seq").fit(db)
    res, said = _match(fitted, q)
    assert res.sampling["query_step"] == 2 and res.sampling["speed"] < 0.6
    assert len(said) == 1 and "as 2 queries of one frame in 2" in said[0]
    best, score, accepted = np.zeros(len(q), np.int64), np.zeros(len(q)), np.zeros(len(q), bool)
    for a in (0, 1):  # each query frame has the answer of its own phase's query
        part = fitted.match(q.take(np.arange(a, len(q), 2)))
        best[a::2], score[a::2], accepted[a::2] = part.best, part.score, part.accepted
        np.testing.assert_array_equal(res.similarity[:, a::2], part.similarity)
    # ... or, not accepted there, the one between its neighbours' accepted answers (the fill's oracle below)
    filled = _filled(best, accepted, 2)
    np.testing.assert_array_equal(res.accepted, accepted | (filled >= 0))
    np.testing.assert_array_equal(res.best, np.where(filled >= 0, filled, best))
    assert res.sampling["query_filled"] == int((filled >= 0).sum())
    assert _decisions(res, q_place)[0] >= 0.99


def _filled(best, accepted, step):
    """The oracle of fill_between: per frame, the interpolated answer (-1: not filled)."""
    out = np.full(len(best), -1)
    for q in range(len(best)):
        if accepted[q] and best[q] >= 0:
            continue
        before = [i for i in range(q) if accepted[i] and best[i] >= 0]
        after = [i for i in range(q + 1, len(best)) if accepted[i] and best[i] >= 0]
        if not before or not after:
            continue
        q0, q1 = before[-1], after[0]
        if q1 - q0 <= step and 0 <= best[q1] - best[q0] <= 2:
            out[q] = best[q0] + round((best[q1] - best[q0]) * (q - q0) / (q1 - q0))
    return out


def _odd_frames_noise(x, seed=0):
    """``x`` with every 2nd row replaced by random bits (as many as its first row's)."""
    rng = np.random.default_rng(seed)
    x = x.tolil(copy=True)
    k = int(x[0].nnz)
    for j in range(1, x.shape[0], 2):
        x[j] = np.isin(np.arange(x.shape[1]), rng.choice(x.shape[1], k, replace=False))
    return sp.csr_matrix(x, dtype=bool)


def test_a_slower_querys_frames_that_match_nothing_are_placed_between_their_neighbours():
    """Every 2nd frame of a query at 0.5x shares nothing with the map (as a frame halfway between two sparse map
    frames can): its own query of one frame in 2 accepts none of them; placed between their neighbours' answers."""
    db, q, q_place = _traverses((0.45, 0.55))
    q = EncodedTraverse(q.names, sdr=_odd_frames_noise(q.sdr))
    fitted = methods.get("rshosm-seq").fit(db)
    odd = fitted.match(q.take(np.arange(1, len(q), 2)))
    assert odd.accepted.mean() < 0.05
    res, _ = _match(fitted, q)
    right = res.accepted & (np.abs(res.best - q_place) <= 1)
    assert res.sampling["query_filled"] > 0.4 * len(q)
    assert right[res.accepted].mean() >= 0.99 and right[1::2].mean() > 0.9


@pytest.mark.parametrize("step", [2, 3])
def test_a_slower_querys_frame_between_two_accepted_takes_the_place_between_them(step):
    rng = np.random.default_rng(step)
    best = np.cumsum(rng.integers(-1, 3, 400)) + rng.integers(-1, 2, 400) * (rng.random(400) < 0.1)
    best[rng.random(400) < 0.05] = -1
    accepted = rng.random(400) < 0.6
    score = rng.random(400) * 30
    new_best, new_score, filled = shosm.fill_between(best, score, accepted, step)
    oracle = _filled(best, accepted, step)
    np.testing.assert_array_equal(filled, oracle >= 0)
    np.testing.assert_array_equal(new_best, np.where(oracle >= 0, oracle, best))
    assert 10 < filled.sum() < 400 - accepted.sum()  # some filled, not every frame not accepted
    for q in np.flatnonzero(filled):  # the smaller score of the two accepted frames around it
        q0 = np.flatnonzero(accepted[:q] & (best[:q] >= 0))[-1]
        q1 = q + 1 + np.flatnonzero(accepted[q + 1:] & (best[q + 1:] >= 0))[0]
        assert new_score[q] == min(score[q0], score[q1])
    np.testing.assert_array_equal(new_score[~filled], score[~filled])


@pytest.mark.parametrize("method, speed", [("rshosm-seq", (0.9, 1.1)), ("pairwise", (1.8, 2.2))])
def test_nothing_is_matched_again_at_the_same_speed_or_without_sequences(method, speed):
    db, q, _ = _traverses(speed)
    fitted = methods.get(method).fit(db)
    res, said = _match(fitted, q)
    first = fitted.match(q)
    assert res.sampling is None and said == []
    np.testing.assert_array_equal(res.best, first.best)
    np.testing.assert_array_equal(res.accepted, first.accepted)


def _online(loc, q):
    return [loc.update(q[j]) for j in range(q.shape[0])]


def _scores(ds, q_place):
    best = np.array([d.best for d in ds])
    acc = np.array([d.accepted for d in ds], bool)
    right = acc & (np.abs(best - q_place) <= 1)
    return right.sum() / max(acc.sum(), 1), right.mean()


def _follower(db, step=2):
    names = [str(i) for i in range(db.shape[0])]
    return Localizer.from_database(db, names), SpeedFollower(Localizer.from_database(db, names), db, step)


def test_online_a_faster_query_is_answered_by_the_maps_of_one_frame_in_two():
    db, q, _, q_place = simulate.aliased_traverses(300, 100, speed=(1.8, 2.2), seed=3)
    plain, follower = _follower(db)
    a, b = _online(plain, q), _online(follower, q)
    (p0, r0), (p1, r1) = _scores(a, q_place), _scores(b, q_place)
    assert p1 > p0 + 0.2 and r1 > r0 + 0.2, (p0, r0, p1, r1)
    s = follower.sampling()
    assert s["db_step"] == 2 and s["db_step_frames"] > q.shape[0] // 2 and "query_step" not in s
    assert [d.frame for d in b] == list(range(q.shape[0]))
    for d in b:  # the answers and their evidence index the whole map
        assert d.column.n == db.shape[0] and (d.best < 0 or d.column.rows.max() < db.shape[0])


def test_online_maps_of_one_frame_in_two_that_place_a_frame_apart_leave_it_undecided_and_near_answer_between(
        monkeypatch):
    db, q, _, q_place = simulate.aliased_traverses(300, 100, speed=(1.8, 2.2), seed=1)
    _, follower = _follower(db)
    fed, feed = {}, follower._feed

    def spy(mode, j, bits):
        out = feed(mode, j, bits)
        if j == follower.frame - 1:  # the frame answered now, not one replayed when a speed starts
            fed[j] = (mode, out)
        return out

    monkeypatch.setattr(follower, "_feed", spy)
    ds = [follower.update(q[j]) for j in range(q.shape[0])]
    apart = between = 0
    for j, d in enumerate(ds):
        mode, answers = fed.get(j, (0, []))
        if mode <= 0 or not answers:
            continue
        on_map = [keep[a.best] for a, keep in zip(answers, follower.keeps, strict=True) if a.accepted and a.best >= 0]
        far = len(on_map) == 2 and abs(on_map[0] - on_map[1]) > 3
        apart += far
        assert d.accepted == (any(a.accepted for a in answers) and not far), j
        if len(on_map) == 2 and not far:  # both accept it near each other: between their answers
            between += on_map[0] != on_map[1] and d.best not in on_map
            assert d.best in (np.floor(np.mean(on_map)), np.ceil(np.mean(on_map))), j
    assert apart == follower.sampling()["db_apart"] > 10
    assert between > 0


@pytest.mark.parametrize("speed", [(1.8, 2.2), (0.45, 0.55)])
def test_online_the_speed_is_read_on_the_answers_given(speed):
    """The path of the map's own answers reads the speed; while a faster query is followed, the path of the answers
    the follower gives (on the whole map)."""
    db, q, _, _ = simulate.aliased_traverses(300, 100, speed=speed, seed=3)
    plain, follower = _follower(db)
    followed = 0
    for j in range(q.shape[0]):
        mode = follower.mode
        own, d = plain.update(q[j]), follower.update(q[j])
        read = d.best if mode > 0 else own.best
        if read >= 0:  # on the map's places (two frames of one appearance in a row are one)
            assert follower.path.last == follower.base.places[read] and follower.path.start <= j, (j, mode)
        followed += bool(mode)
    assert followed > q.shape[0] // 2


def test_online_a_slower_query_is_answered_as_queries_of_one_frame_in_two():
    db, q, _, q_place = simulate.aliased_traverses(300, 100, speed=(0.45, 0.55), seed=3)
    _, follower = _follower(db)
    b = _online(follower, q)
    assert follower.sampling()["query_step_frames"] > 0.9 * q.shape[0]
    assert _scores(b, q_place)[0] >= 0.99


def test_online_a_slower_querys_frame_its_own_does_not_accept_takes_the_answer_just_before():
    db, q, _, q_place = simulate.aliased_traverses(300, 100, speed=(0.45, 0.55), seed=3)
    q = _odd_frames_noise(q)
    _, follower = _follower(db)
    b = _online(follower, q)
    s = follower.sampling()
    assert s["query_filled"] > 0.3 * q.shape[0]
    right = np.array([d.accepted and abs(d.best - p) <= 1 for d, p in zip(b, q_place, strict=True)])
    assert _scores(b, q_place)[0] >= 0.99 and right[1::2].mean() > 0.6
    acc = np.array([d.accepted for d in b])
    for j in range(1, q.shape[0]):  # a filled frame: the answer of the frame before, which its own query accepted
        if acc[j] and acc[j - 1] and b[j].best == b[j - 1].best and j % 2:
            assert b[j].score == b[j - 1].score


def test_online_a_slower_speed_is_left_only_at_a_frame_its_queries_do_not_answer(monkeypatch):
    db, q, _, _ = simulate.aliased_traverses(300, 100, speed=(0.45, 0.55), seed=3)
    q = _odd_frames_noise(q)
    plain, follower = _follower(db)
    _, first = _follower(db)
    acc = np.array([first.update(q[j]).accepted for j in range(q.shape[0])])
    # from a frame on which its queries answer the next 20 frames (a stand of the map's in between refuses some)
    start = next(j for j in range(100, q.shape[0] - 21) if acc[j - 1:j + 21].all())
    for j in range(start):
        plain.update(q[j]), follower.update(q[j])
    j = start
    assert follower.mode < 0
    monkeypatch.setattr(follower.path, "speed", lambda: 1.0)  # from here on the map's answers read its speed
    ds, own = [], []
    while follower.mode < 0 and j < q.shape[0]:
        own.append(plain.update(q[j]))
        ds.append(follower.update(q[j]))
        j += 1
    assert all(d.accepted for d in ds[:-1]) and len(ds) > 20  # held while its queries answered
    assert follower.mode == 0 and follower.last is None  # then left, the frame answered by the map's localizer
    assert (ds[-1].best, ds[-1].score, ds[-1].accepted) == (own[-1].best, own[-1].score, own[-1].accepted)


def test_online_at_the_maps_speed_the_follower_answers_as_the_localizer():
    db, q, _, _ = simulate.aliased_traverses(300, 100, speed=(0.9, 1.1), seed=3)
    plain, follower = _follower(db)
    a, b = _online(plain, q), _online(follower, q)
    assert [(d.best, d.score, d.accepted) for d in a] == [(d.best, d.score, d.accepted) for d in b]
    assert follower.sampling() is None


@pytest.mark.parametrize("speed", [(1.8, 2.2), (0.45, 0.55)])
def test_a_follower_continues_from_its_state(speed):
    db, q, _, _ = simulate.aliased_traverses(300, 100, speed=speed, seed=1)
    q = q if speed[0] > 1 else _odd_frames_noise(q)  # a slower query's fill carried across the stop
    _, whole = _follower(db)
    expected = _online(whole, q)
    _, first = _follower(db)
    half = q.shape[0] // 2 | 1  # stopped just after a frame of real bits
    got = [first.update(q[j]) for j in range(half)]
    assert speed[0] > 1 or first.last is not None  # the next frame's fill comes from the state
    loc_state, state = first.base.state(), first.state()
    _, second = _follower(db)
    second.base.load_state(*loc_state)
    second.load_state(*state)
    got += [second.update(q[j]) for j in range(half, q.shape[0])]
    assert [(d.best, d.score, d.accepted, d.frame) for d in got] == \
        [(d.best, d.score, d.accepted, d.frame) for d in expected]
    with pytest.raises(ValueError, match="step 2"):
        _follower(db, step=3)[1].load_state(*state)


@pytest.mark.parametrize("speed, key", [((1.8, 2.2), "db_step"), ((0.45, 0.55), "query_step")])
def test_a_top_k_similarity_is_matched_again_in_the_same_form(speed, key):
    from vpr.similarity import dense_budget

    db, q, _ = _traverses(speed)
    with dense_budget(1000):  # every similarity top-K sparse
        fitted = methods.get("rshosm-seq", top_k=5).fit(db)
        res, _ = _match(fitted, q)
    assert sp.issparse(res.similarity) and res.similarity.shape == (len(db), len(q)) and res.sampling[key] == 2
    assert res.similarity.format == "csr"
    # every column keeps at most top_k entries of each phase it was matched in
    assert np.diff(res.similarity.tocsc().indptr).max() <= 5 * 2


def test_a_method_whose_answers_read_no_speed_takes_the_speed_another_read():
    db, q, q_place = _traverses((1.8, 2.2))
    dense = lambda t: EncodedTraverse(t.names, sdr=t.sdr, desc=t.sdr.toarray().astype(np.float32))  # noqa: E731
    fitted = methods.get("seqslam-desc").fit(dense(db))
    first = fitted.match(dense(q))
    assert methods.match_at_speed(fitted, dense(q), first=first) is first  # its own answers form no path
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = methods.match_at_speed(fitted, dense(q), first=first, speed=2.0)
    assert {k: res.sampling[k] for k in ("speed", "db_step")} == {"speed": 2.0, "db_step": 2}
    assert 0 <= res.sampling["db_apart"] < len(q) // 4
    (p0, r0), (p1, r1) = _decisions(first, q_place), _decisions(res, q_place)
    assert p1 > p0 + 0.5 and r1 > r0 + 0.3, (p0, r0, p1, r1)


def test_the_map_of_the_largest_score_and_a_pick_refused():
    db, q, _ = _traverses((1.8, 2.2))
    fitted = methods.get("rshosm-seq").fit(db)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = methods.match_at_speed(fitted, q, pick="score")
    even, odd = (methods.get("rshosm-seq").fit(db.take(np.arange(a, len(db), 2))).match(q) for a in (0, 1))
    picked = np.where(odd.score > even.score, 2 * odd.best + 1, 2 * even.best)
    both = even.accepted & odd.accepted & (np.abs(2 * odd.best + 1 - 2 * even.best) <= 3)
    np.testing.assert_array_equal(res.best, [_between([2 * e, 2 * o + 1], p) if b else p for e, o, p, b in
                                             zip(even.best, odd.best, picked, both, strict=True)])
    with pytest.raises(ValueError, match="pick must be one of path, score"):
        methods.match_at_speed(fitted, q, pick="nope")
    with pytest.raises(ValueError, match="pick must be one of"):
        SpeedFollower(Localizer.from_database(db.sdr, db.names), db.sdr, pick="longest")


def _stream(speed, seed=3):
    """Two sessions of one stream: the database traverse, then the query traverse driven at ``speed``."""
    db, q, q_place = _traverses(speed, seed)
    stream = EncodedTraverse.from_parts([db, q], ["a", "b"])
    method = methods.get("rshosm-seq")
    return method, stream, db, q, q_place, method.loops(stream, exclude=5, sessions=[len(db)])


def _loops(method, stream, res, *later):
    """``loops_at_speed`` with the sessions starting at 0 and ``later``: (result, the warnings said)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = methods.loops_at_speed(method, stream, res, [0, *later])
    return out, [str(w.message) for w in caught]


@pytest.mark.slow
@pytest.mark.parametrize("speed, key, said, gain", [
    ((1.8, 2.2), "db_step", "learned again as 2 maps of one frame in 2", 0.05),
    ((0.45, 0.55), "query_step", "as 2 queries of one frame in 2", 0.0)])
def test_a_later_session_at_another_speed_is_decided_again_onto_the_earlier_ones(speed, key, said, gain):
    method, stream, db, q, q_place, res = _stream(speed)
    a = len(db)
    out, lines = _loops(method, stream, res, a)
    (f,) = out.sampling["sessions"]
    assert f["session"] == 2 and f[key] == 2 and len(lines) == 1 and said in lines[0] and "session 2" in lines[0]
    # the oracle: the session's frames take the match against the earlier session at that sampling, except where
    # the loop's best lies in its own session and the match does not accept
    with warnings.catch_warnings(action="ignore"):
        m = methods.match_at_speed(method.fit(db), q)
    assert m.sampling[key] == 2
    own = res.best[a:] >= a
    take = m.accepted | ~own
    np.testing.assert_array_equal(out.best[a:], np.where(take, m.best, res.best[a:]))
    np.testing.assert_array_equal(out.accepted[a:], np.where(take, m.accepted, res.accepted[a:]))
    np.testing.assert_array_equal(out.similarity[:a, a:], m.similarity)
    np.testing.assert_array_equal(out.similarity[:, :a], res.similarity[:, :a])  # the first session as it was
    np.testing.assert_array_equal(out.similarity[a:], res.similarity[a:])
    right = lambda r: r.accepted[a:] & (np.abs(r.best[a:] - q_place) <= 1)  # noqa: E731
    # against the loop's own answers
    as_is = methods.get("rshosm-seq").loops(stream, exclude=5, sessions=[a])
    p0, p1 = (right(r).sum() / max(r.accepted[a:].sum(), 1) for r in (as_is, out))
    assert p1 >= p0 and right(out).mean() >= right(as_is).mean() + gain, (p0, p1)
    # decided again: more closures onto the earlier session where the query is than the loop's own
    assert right(out).sum() > right(res).sum()
    # the speed is read on the match against the earlier session, also where the loop's own paths read none
    blind = dataclasses.replace(res, best=np.where(np.arange(len(res.best)) >= a, -1, res.best))
    again = _loops(method, stream, blind, a)[0]
    assert again.sampling["sessions"][0][key] == 2
    np.testing.assert_array_equal(again.best[a:], m.best)


def test_loops_at_the_same_speed_are_read_and_left_as_they_are_and_without_sequences_not_read():
    method, stream, db, *_, res = _stream((0.9, 1.1))
    out, lines = _loops(method, stream, res, len(db))
    (f,) = out.sampling["sessions"]
    assert f.keys() == {"session", "speed"} and 0.9 <= f["speed"] <= 1.1 and lines == []
    for key in ("best", "score", "accepted", "similarity"):
        np.testing.assert_array_equal(getattr(out, key), getattr(res, key))
    assert methods.loops_at_speed(method, stream, res, [0]) is res  # one session: nothing to read
    pairwise = methods.get("pairwise")
    fast = _stream((1.8, 2.2))[1]
    res = pairwise.loops(fast, exclude=5, sessions=[len(db)])
    assert _loops(pairwise, fast, res, len(db))[0] is res


def test_a_top_k_loop_similarity_keeps_its_form_when_a_session_is_decided_again():
    method, stream, db, q, _, res = _stream((1.8, 2.2))
    a, k = len(db), 7
    S = res.similarity.copy()
    S[~np.isfinite(S)] = -np.inf
    top = np.argsort(-S, axis=0, kind="stable")[:k]
    cols = np.broadcast_to(np.arange(S.shape[1]), top.shape)
    keep = np.isfinite(S[top, cols])
    sparse = sp.csr_matrix((S[top, cols][keep], (top[keep], cols[keep])), shape=S.shape)
    out = _loops(method, stream, dataclasses.replace(res, similarity=sparse), a)[0]
    dense = _loops(method, stream, res, a)[0]
    assert sp.issparse(out.similarity) and np.diff(out.similarity.tocsc().indptr).max() <= k
    np.testing.assert_array_equal(out.best, dense.best)
    # each column of the session keeps the k largest of the match's values and its own session's
    full = np.where(np.isfinite(dense.similarity), dense.similarity, np.nan)
    full[a:, a:] = np.where(sparse[a:, a:].toarray() != 0, sparse[a:, a:].toarray(), np.nan)
    got = out.similarity.toarray()
    for j in range(a, a + len(q)):
        x = full[:, j][np.isfinite(full[:, j])]
        np.testing.assert_array_equal(np.sort(got[:, j][got[:, j] != 0]), np.sort(x)[-k:])
    np.testing.assert_array_equal(out.similarity[:, :a].toarray(), sparse[:, :a].toarray())


def test_each_later_session_is_read_against_all_earlier_ones_and_only_the_one_off_speed_is_followed():
    db, fast, _ = _traverses((1.8, 2.2))
    same = _traverses((0.9, 1.1))[1]
    stream = EncodedTraverse.from_parts([db, fast, same], ["a", "b", "c"])
    method = methods.get("rshosm-seq")
    a, b = len(db), len(db) + len(fast)
    res = method.loops(stream, exclude=5, sessions=[a, b])
    out = _loops(method, stream, res, a, b)[0]
    second, third = out.sampling["sessions"]
    assert second["session"] == 2 and second["db_step"] == 2
    assert third["session"] == 3 and third.keys() == {"session", "speed"} and 0.9 <= third["speed"] <= 1.1
    for key in ("best", "accepted"):  # the first and the third session as the loops decided them
        np.testing.assert_array_equal(getattr(out, key)[:a], getattr(res, key)[:a])
        np.testing.assert_array_equal(getattr(out, key)[b:], getattr(res, key)[b:])
    assert not np.array_equal(out.best[a:b], res.best[a:b])


def _one_run(speed, seed=3):
    """One run (one session) that drives the database's route, then again at ``speed``: (method, stream, where the
    revisit starts, its places, the loops of the stream)."""
    db, q, q_place = _traverses(speed, seed)
    stream = EncodedTraverse.from_parts([db, q], ["a", "b"])
    method = methods.get("rshosm-seq")
    return method, stream, len(db), q_place, method.loops(stream, exclude=30)


@pytest.mark.slow
def test_a_revisit_within_one_run_driven_faster_is_matched_again_by_the_loop_rule_and_confirmed():
    key = "db_step"
    method, stream, a, q_place, res = _one_run((1.8, 2.2))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = methods.loops_in_run_at_speed(method, stream, res, 30)
    (run,) = out.sampling["runs"]
    lo, hi = run["frames"][0], run["frames"][1] + 1
    assert run[key] == 2 and a - 30 < lo < a + 50 and hi == len(stream)
    said = [str(w.message) for w in caught]
    assert len(said) == 1 and f"frames {lo}-{hi - 1} of one run" in said[0]
    # the oracle: the stretch matched against the frames 30 before it at that sampling, decided by the loop rule's
    # path, confirmed by the frames after each closure; taken where the loops did not accept
    strict = methods.get("rshosm-seq", drift=LoopConf.drift, min_score=LoopConf.min_score)
    with warnings.catch_warnings(action="ignore"):
        m = methods.match_at_speed(strict.fit(stream.slice(0, lo - 30)), stream.slice(lo, hi), speed=run["speed"])
    best, score, acc = np.full(len(stream), -1), np.zeros(len(stream)), np.zeros(len(stream), bool)
    best[lo:hi], score[lo:hi], acc[lo:hi] = m.best, m.score, m.accepted
    kept = confirm_closures(Decision(best, score, acc, np.zeros(len(stream))), stream.sdr, 30, method.seq).accepted
    take = kept & ~res.accepted
    # ... where it lies on a run of 10 or more closures (with the loops' own) that moves 1.5 or more frames a frame
    joined, closed = np.where(take, best, res.best), res.accepted | take
    j = 0
    while j < len(stream):
        k = j
        while k + 1 < len(stream) and closed[k] and closed[k + 1] and 0 <= joined[k + 1] - joined[k] <= 4:
            k += 1
        if k - j + 1 < 10 or (joined[k] - joined[j]) / (k - j) < 1.5:
            take[j:k + 1] = False
        j = k + 1
    assert run["closures"] == take.sum() > 5
    np.testing.assert_array_equal(out.accepted, res.accepted | take)
    np.testing.assert_array_equal(out.best, np.where(take, best, res.best))
    np.testing.assert_array_equal(out.similarity[:lo - 30, lo:hi], m.similarity)
    np.testing.assert_array_equal(out.similarity[:, :lo], res.similarity[:, :lo])
    # what it takes is the place, near enough (the query's own places; no closure on the first drive)
    assert not out.accepted[:a].any() and (np.abs(out.best[a:] - q_place)[take[a:]] <= 3).all()


@pytest.mark.parametrize("speed", [(0.9, 1.1), (0.45, 0.55)])
def test_one_run_at_one_speed_or_slower_forward_or_without_sequences_is_left_as_it_is(speed):
    """Only a faster reading is matched again: a slower revisit the evidence follows as it comes."""
    method, stream, a, q_place, res = _one_run(speed)
    assert methods.loops_in_run_at_speed(method, stream, res, 30) is res
    right = res.accepted[a:] & (np.abs(res.best[a:] - q_place) <= 1)
    assert right.mean() > 0.6 and right.sum() == res.accepted[a:].sum()
    forward = stream.slice(0, a)
    assert methods.loops_in_run_at_speed(method, forward, method.loops(forward, exclude=30), 30).sampling is None
    pairwise = methods.get("pairwise")
    fast = _one_run((1.8, 2.2))[1]
    res = pairwise.loops(fast, exclude=30)
    assert methods.loops_in_run_at_speed(pairwise, fast, res, 30) is res


def test_a_later_session_is_followed_also_with_settings_of_one_stream():
    """A setting of loop closure within one stream (backfill_frames) does not keep a later session from being matched
    again against the earlier ones (its match is a map's, where such a setting is refused)."""
    db, q, _ = _traverses((1.8, 2.2))
    stream = EncodedTraverse.from_parts([db, q], ["a", "b"])
    method = methods.get("rshosm-seq", backfill_frames=10)
    res = method.loops(stream, exclude=5, sessions=[len(db)])
    out, said = _loops(method, stream, res, len(db))
    assert out.sampling["sessions"][0]["db_step"] == 2 and not any("cannot be matched" in s for s in said)


def test_a_slower_querys_frame_its_neighbours_bracket_elsewhere_is_not_decided():
    """Answered as queries of one frame in 2, a frame lies between the frames just before and after it (other
    queries): an accepted answer more than 3 map frames from their mean contradicts them and is not decided."""
    best = np.array([10, 11, 7, 12, 13, 20, 14])
    acc = np.array([True, True, True, True, True, True, False])
    apart = shosm.apart_from_neighbours(best, acc, 2)
    assert apart.tolist() == [False, False, True, False, False, False, False]  # 20: a neighbour is not accepted
    assert not shosm.apart_from_neighbours(best, np.zeros(7, bool), 2).any()
    assert shosm.apart_from_neighbours(np.array([10, 14, 11]), np.ones(3, bool), 3).tolist() == [False] * 3


def test_the_online_speed_is_read_where_both_halves_of_the_path_read_it():
    from vpr.paths import MIN_RUN
    from vpr.shosm.follow import BestPath

    def read(bests):
        p = BestPath(4, 8)
        for t, b in enumerate(bests):
            p.step(t, b)
        return p.speed()

    assert read(range(0, MIN_RUN - 1)) is None  # too short to read
    assert read([t // 2 for t in range(20)]) == pytest.approx(0.5, abs=0.03)  # a query at half the speed
    assert read([2 * t for t in range(20)]) == pytest.approx(2.0)
    # at the map's speed, then the answers stay on one frame: the slope of all of them reads slower (0.61), the
    # halves do not agree (1.0 and 0.0)
    assert read([*range(12), *[11] * 8]) is None
    # one answer six frames behind, then the map's speed: its two ends read faster (14 frames in 9), the slope of all
    # of them not (1.27), its first half faster (2.0): no speed; 6 frames later the map's
    assert read([0, *range(6, 15)]) is None
    assert 0.9 < read([0, *range(6, 21)]) < 1.5
    assert read([*range(10), *range(10, 30, 2)]) is None  # 1x for 10 frames, then 2x for 10: neither yet
    assert read(range(20)) == pytest.approx(1.0)
