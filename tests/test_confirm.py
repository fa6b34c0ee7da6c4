"""A loop closure is kept only where the frames after it single out its place (vpr.shosm.Confirmation)."""
import numpy as np
import pytest
import scipy.sparse as sp

from vpr import sdr
from vpr.shosm import LoopStream, RshosmSeqConf, confirm_closures, loop_evidence
from vpr.shosm.confirm import Columns, ahead_scores, standardised_overlaps

LOOSE = {"min_score": 6.0, "drift": 0.5, "n_inputs": 1024}
TURN = 140


def _leaves_the_route():
    """Frames 0..79 a first pass, 80..139 a noisy revisit of 0..59, then 40 places never seen (the robot turned off)."""
    places = sdr.random_sdrs(80, 1024, 40, seed=0)
    return sp.vstack([places, sdr.add_noise(places[:60], 0.2, seed=1), sdr.random_sdrs(40, 1024, 40, seed=2)]).tocsr()


def _closures(d):
    acc = np.flatnonzero(d.accepted)
    revisit = acc[acc < TURN]
    return int((np.abs(d.best[revisit] - (revisit - 80)) <= 1).sum()), int((acc >= TURN).sum())


def test_no_closure_runs_on_after_a_revisit_leaves_the_route():
    x = _leaves_the_route()
    right, after = _closures(loop_evidence(x, exclude=30, confirm_frames=0, **LOOSE).decision)
    assert right >= 55 and after >= 10  # decided at once, the answers run on along the earlier route
    right_c, after_c = _closures(loop_evidence(x, exclude=30, **LOOSE).decision)
    assert after_c == 0 and right_c >= right - 2


def test_confirming_decisions_taken_equals_the_stream_also_across_sessions():
    x = _leaves_the_route()
    for sessions in ([0], [0, 100]):
        raw = loop_evidence(x, exclude=30, confirm_frames=0, sessions=sessions, **LOOSE).decision
        kept = loop_evidence(x, exclude=30, sessions=sessions, **LOOSE).decision
        again = confirm_closures(raw, x, 30, LOOSE, sessions=sessions)
        np.testing.assert_array_equal(again.accepted, kept.accepted)
        np.testing.assert_array_equal(again.best, raw.best)
        assert raw.accepted.sum() > kept.accepted.sum()


def test_closures_verified_on_their_own_pair_are_final_at_once():
    x = _leaves_the_route()
    raw = loop_evidence(x, exclude=30, confirm_frames=0, **LOOSE).decision
    verified = raw.accepted & (np.arange(x.shape[0]) >= TURN)
    d = confirm_closures(raw, x, 30, LOOSE, verified=verified)
    np.testing.assert_array_equal(d.accepted[TURN:], raw.accepted[TURN:])


def test_a_waiting_closure_holds_the_frames_after_it_in_order():
    x = _leaves_the_route()
    stream = LoopStream(30, RshosmSeqConf.build({**LOOSE, "backfill_frames": 0}))  # the confirmation's wait alone
    got, held = [], 0
    for j in range(x.shape[0]):
        ds = stream.step(x[j])[1]
        held = max(held, stream.waiting)
        got.extend(ds)
    got.extend(stream.finish())
    assert [d.frame for d in got] == list(range(x.shape[0])) and held == 19  # a closure and the 19 frames after it
    assert stream.waiting == 0


def test_the_look_ahead_follows_a_path_and_its_costs():
    rows = [np.array([0.0, 5.0, 0.0, 0.0]), np.array([0.0, 0.0, 5.0, 0.0]), np.array([0.0, 0.0, 0.0, 5.0, 1.0])]
    # candidate 1 follows 1 -> 2 -> 3; 0 and 2 reach that path with a skip or a stay (cost 0.05 each)
    np.testing.assert_allclose(ahead_scores(rows, 0.05, 0.05), [9.95, 15.0, 9.95, 4.9])
    # one step a frame only: candidate 3's path leaves the candidates
    np.testing.assert_allclose(ahead_scores(rows, -1.0, -1.0), [0.0, 15.0, 1.0, -np.inf])
    x = sdr.from_indices([[0, 1, 2], [0, 1, 3], [4, 5, 6], [0, 1, 2]], 8)
    z = standardised_overlaps(x.indptr, x.indices, 3, 3, 8)
    assert z.argmax() == 0 and z.mean() == pytest.approx(0.0) and z.std() == pytest.approx(1.0)
    # through blocks of columns of the first rows (bit -> rows), the rest row by row: the same
    y = sdr.random_sdrs(300, 256, 20, seed=3)
    ptr, ind = y.indptr.astype(np.int64), y.indices.astype(np.int64)
    cols = Columns(256, every=64)
    for n in (280, 150, 40):
        through = standardised_overlaps(ptr, ind, 299, n, 256, cols.extend(ptr, ind, 280))
        np.testing.assert_allclose(through, standardised_overlaps(ptr, ind, 299, n, 256))
    assert cols.rows == 256  # four whole blocks of 64


def test_confirmation_settings_are_checked_and_belong_to_one_stream():
    with pytest.raises(ValueError, match="confirm_frames must be an integer >= 0"):
        RshosmSeqConf.build({"confirm_frames": -1})
    with pytest.raises(ValueError, match="confirm_z must be a finite z-score"):
        RshosmSeqConf.build({"confirm_z": float("inf")})
    with pytest.raises(ValueError, match="confirm_frames applies to loop closure within one stream"):
        RshosmSeqConf.build({"confirm_frames": 5}).path()
    assert RshosmSeqConf.build({"confirm_frames": 5}).path(between_sessions=True).min_score == 12.0
