"""The frames that led up to a confirmed loop closure on its path are accepted with it (vpr.shosm.Backfill)."""
import numpy as np
import pytest

from tests.revisits import route_driven_again
from vpr.shosm import Backfill, LoopConf, RshosmSeqConf, backfill_closures, loop_evidence
from vpr.types import Decision


def _d(frame, best, score, accepted=False):
    return Decision(best, score, accepted, 0.0, frame)


def _run(b: Backfill, ds) -> list[Decision]:
    out = [o for d in ds for o in b.push([d])] + b.flush()
    assert [o.frame for o in out] == [d.frame for d in ds]  # every frame once, in order
    return out


def test_a_path_is_accepted_back_to_where_it_began_and_no_further():
    # frame 0 a new place; 1-4 a path building up (best moving on); 5 accepted; 6 a new place
    ds = [_d(0, -1, 0.0), _d(1, 10, 3.0), _d(2, 11, 8.0), _d(3, 12, 14.0), _d(4, 13, 20.0), _d(5, 14, 26.0, True),
          _d(6, 50, 0.0)]
    out = _run(Backfill(40, 4, 6, 24.0), ds)
    assert [o.accepted for o in out] == [False, True, True, True, True, True, False]
    assert [o.best for o in out] == [d.best for d in ds]  # each onto its own best
    # only within ``frames`` before the closure
    assert [o.accepted for o in _run(Backfill(2, 4, 6, 24.0), ds)] == [False, False, False, True, True, True, False]
    assert [o.accepted for o in _run(Backfill(0, 4, 6, 24.0), ds)] == [d.accepted for d in ds]


def test_a_broken_path_or_a_refused_closure_is_not_accepted_back():
    jump = [_d(1, 10, 3.0), _d(2, 11, 8.0), _d(3, 40, 14.0), _d(4, 41, 20.0), _d(5, 42, 26.0, True)]
    assert [o.accepted for o in _run(Backfill(40, 4, 6, 24.0), jump)] == [False, False, True, True, True]
    refused = [_d(1, 10, 3.0), _d(2, 11, 30.0), _d(3, 12, 14.0), _d(4, 13, 26.0, True)]  # 2: at the bar, refused
    assert [o.accepted for o in _run(Backfill(40, 4, 6, 24.0), refused)] == [False, False, True, True]
    unconfirmed = [_d(1, 10, 3.0), _d(2, 11, 8.0), _d(3, 12, 14.0)]  # the path never closes: all as decided
    assert not any(o.accepted for o in _run(Backfill(40, 4, 6, 24.0), unconfirmed))


def test_a_revisit_is_accepted_from_its_first_frames_and_the_replay_equals_the_stream():
    x, place = route_driven_again(1.0)
    before = loop_evidence(x, exclude=30, backfill_frames=0).decision
    after = loop_evidence(x, exclude=30).decision
    assert after.accepted.sum() > before.accepted.sum() and not (before.accepted & ~after.accepted).any()
    added = np.flatnonzero(after.accepted & ~before.accepted)
    assert added.min() >= 300 and np.abs(after.best[added] - place[added]).max() <= 2  # the revisit's own frames
    sessions = [0, 450]  # nothing waits across a session's start
    raw = loop_evidence(x, exclude=30, backfill_frames=0, sessions=sessions).decision
    whole = loop_evidence(x, exclude=30, sessions=sessions).decision
    c = LoopConf()
    again = backfill_closures(raw, c.backfill_frames, c.back, c.ahead, c.min_score, sessions=sessions)
    np.testing.assert_array_equal(again.accepted, whole.accepted)
    np.testing.assert_array_equal(again.best, whole.best)


def test_the_setting_is_checked_and_belongs_to_one_stream():
    for bad in (-1, 2.5, True):
        with pytest.raises(ValueError, match="backfill_frames"):
            RshosmSeqConf.build({"backfill_frames": bad})
    with pytest.raises(ValueError, match="backfill_frames applies to loop closure within one stream"):
        RshosmSeqConf.build({"backfill_frames": 5}).path()
