"""A closure of a revisit driven faster than the evidence follows is placed by the frames up to it
(vpr.shosm.Placement)."""
import numpy as np
import pytest
import scipy.sparse as sp

from vpr import sdr
from vpr.shosm import LoopDetector, RshosmSeqConf, loop_evidence, place_closures

N_BITS, K, ROUTE = 2048, 80, 300


def _route_driven_again(speed: float, seed: int = 0):
    """A first pass of ROUTE frames whose view changes a fifth of its bits a frame, then the same route again at
    ``speed`` frames a frame, a third of every frame's bits moved; returns (SDR batch, each frame's place or -1)."""
    rng = np.random.default_rng(seed)
    route = [rng.choice(N_BITS, K, replace=False)]
    for _ in range(ROUTE - 1):
        row = route[-1].copy()
        row[rng.choice(K, K // 5, replace=False)] = rng.choice(np.setdiff1d(np.arange(N_BITS), row), K // 5,
                                                              replace=False)
        route.append(row)
    first = sp.csr_matrix((np.ones(ROUTE * K, bool), np.concatenate(route), np.arange(ROUTE + 1) * K),
                          shape=(ROUTE, N_BITS))
    places = np.arange(0, ROUTE, speed).astype(int)
    again = sdr.add_noise(first[places], 0.35, seed=seed + 1)
    return sp.vstack([first, again]).tocsr(), np.r_[np.full(ROUTE, -1), places]


def _off(d, place) -> np.ndarray:
    acc = np.flatnonzero(d.accepted)
    return np.abs(d.best[acc] - place[acc])


def test_a_revisit_driven_faster_is_answered_at_its_place():
    x, place = _route_driven_again(2.5)
    lagging = loop_evidence(x, exclude=30, place_frames=0).decision
    placed = loop_evidence(x, exclude=30).decision
    np.testing.assert_array_equal(placed.accepted, lagging.accepted)  # the same closures, answered again
    assert placed.accepted.sum() >= 100
    assert (_off(lagging, place) > 2).sum() >= 10  # the evidence's best frame lags behind the place
    assert _off(placed, place).max() <= 1


def test_at_the_first_pass_speed_nothing_is_placed():
    x, _ = _route_driven_again(1.0)
    a, b = loop_evidence(x, exclude=30, place_frames=0).decision, loop_evidence(x, exclude=30).decision
    np.testing.assert_array_equal(a.best, b.best)
    np.testing.assert_array_equal(a.accepted, b.accepted)


def test_placing_decisions_taken_equals_the_stream_and_the_detector():
    x, _ = _route_driven_again(2.5)
    whole = {}
    for sessions in ([0], [0, 340]):
        raw = loop_evidence(x, exclude=30, place_frames=0, sessions=sessions).decision
        placed = whole.setdefault(len(sessions), loop_evidence(x, exclude=30, sessions=sessions).decision)
        again = place_closures(raw, x, 30, sessions=sessions)
        assert (again.best != raw.best).sum() >= 10
        np.testing.assert_array_equal(again.best, placed.best)
        np.testing.assert_array_equal(again.accepted, placed.accepted)
    det, online = LoopDetector(exclude=30, n_inputs=N_BITS), []
    for j in range(x.shape[0]):
        d = det.update(x[j])
        online.extend(det.take_late() + ([] if d is None else [d]))
    det.flush()
    online.extend(det.take_late())
    assert [d.frame for d in online] == list(range(x.shape[0]))
    np.testing.assert_array_equal([d.best for d in online], whole[1].best)
    np.testing.assert_array_equal([d.accepted for d in online], whole[1].accepted)


def test_placement_setting_is_checked_and_belongs_to_one_stream():
    for bad in (-1, 1, 2, 2.5, True):
        with pytest.raises(ValueError, match="place_frames"):
            RshosmSeqConf.build({"place_frames": bad})
    assert RshosmSeqConf.build({"place_frames": 0}).loop().place_frames == 0
    with pytest.raises(ValueError, match="place_frames applies to loop closure within one stream"):
        RshosmSeqConf.build({"place_frames": 5}).path()
