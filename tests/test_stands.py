"""Stands: a query frame that did not move is not accepted, and online it steps no evidence (``vpr.sdr.unmoved``);
the map's stands number one place (``vpr.shosm.map_places``), on which a query's speed is read."""
from __future__ import annotations

import numpy as np

import vpr
from vpr import methods, sdr
from vpr.shosm import SequenceMemory, map_places, memory_params
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


def test_map_places_are_the_memory_learning_one_place_under_several_frames():
    x, _ = _stand(sdr.random_sdrs(40, 2048, 40, seed=1), 10, 4)
    mem = SequenceMemory(**memory_params())
    codes = mem.run(x)
    assert map_places(codes, mem.cells_per_column).tolist() == [*range(11), 10, 10, 10, *range(11, 40)]
    # a session that starts on the stand's last frame follows no frame of the map
    assert map_places(codes, mem.cells_per_column, sessions=(0, 13)).tolist() == \
        [*range(11), 10, 10, 11, *range(12, 41)]


def _traverses(seed=3):
    """A map that stands 10 frames at place 30 and a query of the same route (noisy) that stands 10 frames at place
    70, with each frame's place."""
    db = sdr.random_sdrs(120, 2048, 40, seed=seed)
    q = sdr.add_noise(db, 0.3, seed=seed + 1)
    return (*_stand(db, 30, 10), *_stand(q, 70, 10))


def _encoded(x):
    return EncodedTraverse(names=[f"{i:04d}" for i in range(x.shape[0])], sdr=x)


def test_match_accepts_no_frame_of_a_query_that_did_not_move():
    db, dp, q, qp = _traverses()
    m = methods.get("rshosm-seq")
    r = m.match(_encoded(db), _encoded(q))
    assert not r.accepted[71:80].any()
    assert r.accepted.sum() > 80 and np.all(np.abs(dp[r.best[r.accepted]] - qp[r.accepted]) <= 1)
    # the rule is what refuses them: the path score alone accepts answers on the query's stand
    plain = m.decisions(r.similarity, r.best, r.score)
    assert plain.accepted[71:80].sum() > 0


def test_localizer_steps_no_evidence_where_the_query_did_not_move(tmp_path):
    db, dp, q, qp = _traverses()
    names = [str(i) for i in range(db.shape[0])]
    loc = vpr.Localizer.from_database(db, names)
    whole = vpr.Localizer.from_database(db, names)
    out = []
    for j in range(q.shape[0]):
        if j == 72:  # stopped on the query's stand: the restarted run knows the frame before
            vpr.Map("rshosm-seq", loc, {"name": "pixel", "conf": {}}).save(tmp_path / "m.npz")
            loc = methods.load_map(tmp_path / "m.npz").localizer
            assert loc.frames == 72
        a, b = loc.update(q[j]), whole.update(q[j])
        assert (a.best, a.accepted, a.frame) == (b.best, b.accepted, j)
        out.append(a)
    best = np.array([d.best for d in out])
    acc = np.array([d.accepted for d in out])
    # the stand's frames: the answer of the frame before it, not accepted; after it, the evidence has not run ahead
    assert not acc[71:80].any() and (best[71:80] == best[70]).all()
    assert acc[80:].mean() > 0.9
    assert acc.sum() > 80 and np.all(np.abs(dp[best[acc]] - qp[acc]) <= 1)
