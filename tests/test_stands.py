"""Stands: where the map shows one place under several frame numbers, or the query did not move, no frame number is
accepted (``vpr.shosm.standing``, ``vpr.sdr.unmoved``, ``vpr.shosm.refuse_stands``)."""
from __future__ import annotations

import numpy as np

import vpr
from vpr import methods, sdr
from vpr.shosm import SequenceMemory, map_places, memory_params, refuse_stands, standing
from vpr.types import EncodedTraverse


def _stand(x, place: int, length: int):
    """``x`` (one row per place) with place ``place`` seen ``length`` times (the camera stood there), and each frame's
    place."""
    places = np.r_[np.arange(place + 1), np.full(length - 1, place), np.arange(place + 1, x.shape[0])]
    return x[places], places


def test_unmoved_reads_the_share_of_bits_kept():
    x = sdr.from_indices([[0, 1, 2, 3], [0, 1, 2, 3], [0, 1, 8, 9], [], [5]], 16)
    assert sdr.unmoved(x, 0.75).tolist() == [False, True, False, False, False]
    assert sdr.unmoved(x, 0.5).tolist() == [False, True, True, False, False]
    assert sdr.kept_share(np.array([0, 1, 8, 9]), np.array([0, 1, 2, 3])) == 0.5
    assert sdr.unmoved(x[:1], 0.5).tolist() == [False]


def test_standing_is_the_memory_learning_one_place_under_several_frames():
    x, _ = _stand(sdr.random_sdrs(40, 2048, 40, seed=1), 10, 4)
    mem = SequenceMemory(**memory_params())
    codes = mem.run(x)
    places = map_places(codes, mem.cells_per_column)
    assert places.tolist() == [*range(11), 10, 10, 10, *range(11, 40)]
    assert np.flatnonzero(standing(places)).tolist() == [10, 11, 12, 13]
    # a session that starts on the stand's last frame follows no frame of the map
    places = map_places(codes, mem.cells_per_column, sessions=(0, 13))
    assert np.flatnonzero(standing(places)).tolist() == [10, 11, 12]
    # two frames of one place: an answer onto either is within a frame of the query's own
    assert not standing([0, 1, 1, 2]).any() and standing([0, 1, 1, 1, 2]).tolist() == [False, True, True, True, False]


def test_refuse_stands_on_arrays_and_one_frame():
    map_still = np.array([False, True, True, False])
    best, acc = np.array([0, 1, 3, -1]), np.array([True, True, True, True])
    assert refuse_stands(best, acc, map_still, np.array([False, False, True, False])).tolist() == \
        [True, False, False, True]
    assert refuse_stands(2, True, map_still, False) is False
    assert refuse_stands(3, True, map_still, False) is True


def _traverses(seed=3):
    """A map that stands 10 frames at place 30 and a query of the same route (noisy) that stands 10 frames at place
    70, with each frame's place."""
    db = sdr.random_sdrs(120, 2048, 40, seed=seed)
    q = sdr.add_noise(db, 0.3, seed=seed + 1)
    return (*_stand(db, 30, 10), *_stand(q, 70, 10))


def _encoded(x):
    return EncodedTraverse(names=[f"{i:04d}" for i in range(x.shape[0])], sdr=x)


def test_match_accepts_no_frame_number_on_a_stand():
    db, dp, q, qp = _traverses()
    m = methods.get("rshosm-seq")
    r = m.match(_encoded(db), _encoded(q))
    on_map_stand = (r.best >= 30) & (r.best <= 39)
    assert not (r.accepted & on_map_stand).any() and not r.accepted[71:80].any()
    assert r.accepted.sum() > 80 and np.all(np.abs(dp[r.best[r.accepted]] - qp[r.accepted]) <= 1)
    # the rule is what refuses them: the path score alone accepts answers on both stands
    plain = m.decisions(r.similarity, r.best, r.score)
    assert (plain.accepted & on_map_stand).sum() > 0 and plain.accepted[71:80].sum() > 0


def test_localizer_refuses_stands_and_a_restart_keeps_the_frame_before(tmp_path):
    db, dp, q, qp = _traverses()
    names = [str(i) for i in range(db.shape[0])]
    loc = vpr.Localizer.from_database(db, names)
    whole = vpr.Localizer.from_database(db, names)
    out = []
    for j in range(q.shape[0]):
        if j == 72:  # stopped on the query's stand: the restarted run knows the frame before
            vpr.Map("rshosm-seq", loc, {"name": "pixel", "conf": {}}).save(tmp_path / "m.npz")
            loc = methods.load_map(tmp_path / "m.npz").localizer
        a, b = loc.update(q[j]), whole.update(q[j])
        assert (a.best, a.accepted) == (b.best, b.accepted)
        out.append(a)
    best = np.array([d.best for d in out])
    acc = np.array([d.accepted for d in out])
    assert not acc[71:80].any() and not (acc & (best >= 30) & (best <= 39)).any()
    assert acc.sum() > 80 and np.all(np.abs(dp[best[acc]] - qp[acc]) <= 1)
