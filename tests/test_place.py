"""A closure of a revisit driven faster than the evidence follows is placed by the frames up to it
(vpr.shosm.Placement)."""
import numpy as np
import pytest

from tests.revisits import N_BITS, route_driven_again
from vpr.shosm import LoopDetector, RshosmSeqConf, loop_evidence, place_closures


def _off(d, place) -> np.ndarray:
    acc = np.flatnonzero(d.accepted)
    return np.abs(d.best[acc] - place[acc])


def test_a_revisit_driven_faster_is_answered_at_its_place():
    x, place = route_driven_again(2.5)
    lagging = loop_evidence(x, exclude=30, place_frames=0, backfill_frames=0).decision
    placed = loop_evidence(x, exclude=30, backfill_frames=0).decision  # the closures the path rule took
    np.testing.assert_array_equal(placed.accepted, lagging.accepted)  # the same closures, answered again
    assert placed.accepted.sum() >= 100
    assert (_off(lagging, place) > 2).sum() >= 10  # the evidence's best frame lags behind the place
    assert _off(placed, place).max() <= 1


def test_at_the_first_pass_speed_nothing_is_placed():
    x, _ = route_driven_again(1.0)
    a, b = loop_evidence(x, exclude=30, place_frames=0).decision, loop_evidence(x, exclude=30).decision
    np.testing.assert_array_equal(a.best, b.best)
    np.testing.assert_array_equal(a.accepted, b.accepted)


def test_placing_decisions_taken_equals_the_stream_and_the_detector():
    x, _ = route_driven_again(2.5)
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
