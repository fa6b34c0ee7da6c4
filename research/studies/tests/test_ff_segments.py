"""Feed-forward segments taught by the prediction (research/studies/ff_segments.py); no dataset needed."""
import numpy as np
import pytest

from research.studies.ff_segments import SegmentedMemory, segment_codes, teach_from_labels, teacher_precision
from tests.reference import ReferenceMemory
from vpr import sdr, simulate
from vpr.shosm import SequenceMemory

N_PLACES = 6


def _seasons(seed=0):
    """Summer and winter SDRs of the same places; the two appearances share (almost) no bits."""
    summer = sdr.random_sdrs(N_PLACES, seed=seed)
    winter = sdr.random_sdrs(N_PLACES, seed=seed + 100)
    return summer, winter


def _bits(batch, t):
    return batch[t].indices


def _learned(summer, **kw):
    mem = SegmentedMemory(p_extra=0.0, k_active=0, seed=0, **kw)
    db = [mem.step(_bits(summer, t)) for t in range(N_PLACES)]
    mem.reset()
    return mem, db


def _winter_query(mem, summer, winter, teach):
    """Place 0 in summer (recognised by its own segment), then places 1.. in winter."""
    out = [mem.step(_bits(summer, 0), learn=False, teach=teach)]
    out += [mem.step(_bits(winter, t), learn=False, teach=teach) for t in range(1, N_PLACES)]
    return out


def _columns(winners, cpc=32):
    return sorted({c // cpc for c in winners})


def test_teacher_off_is_algorithm_1():
    # same random draws as the literal reference: identical winners when learning and querying
    obs = simulate.observe(simulate.make_world(5, 6, n_bits=256, n_active=12, aliasing=3, seed=0),
                           simulate.random_walk(5, 6, 300, seed=1), 0.3, seed=2)
    kw = dict(n_inputs=256, cells_per_column=4, new_columns=3, p_extra=0.05, k_active=10, seed=7)
    ref, seg = ReferenceMemory(**kw), SegmentedMemory(**kw)
    for t in range(200):
        assert seg.step(obs[t].indices) == ref.step(obs[t].indices), t
    ref.reset()
    seg.reset()
    for t in range(200, 300):
        assert seg.step(obs[t].indices, learn=False, teach=True) == ref.step(obs[t].indices, learn=False), t
    assert all(len(s) == 1 for s in seg.segments) and not seg.taught_log


def test_segment_codes_without_teacher_are_the_papers_rshosm():
    summer, winter = sdr.random_sdrs(40, seed=1), sdr.add_noise(sdr.random_sdrs(40, seed=1), 0.6, seed=2)
    db, q, stats = segment_codes(summer, winter, teach_below=0)
    mem = SequenceMemory(seed=0)
    db_fast = mem.run(summer)
    mem.reset()
    q_fast = mem.run(winter, learn=False)
    assert (db[:, : db_fast.shape[1]] != db_fast).nnz == 0 and (q[:, : q_fast.shape[1]] != q_fast).nnz == 0
    assert stats["taught_segments"] == 0 and stats["teacher_precision"] is None


def test_prediction_teaches_the_winter_appearance():
    summer, winter = _seasons()
    mem, db = _learned(summer, teach_below=1)
    q = _winter_query(mem, summer, winter, teach=True)
    # place 0 bursts (no context: a new random winner per minicolumn); from then on the sequence
    # continues through winter with the summer traverse's winner cells
    assert _columns(q[0]) == _columns(db[0]) and q[1:] == db[1:]
    assert [len(s) for s in mem.segments] == [1] * 10 + [2] * (10 * (N_PLACES - 1))
    # a second pass, no teacher and no context: a winter frame alone now activates its place's minicolumns
    for t in range(1, N_PLACES):
        mem.reset()
        assert _columns(mem.step(_bits(winter, t), learn=False)) == _columns(db[t])


def test_without_teacher_nothing_changes():
    summer, winter = _seasons()
    mem, db = _learned(summer, teach_below=0)
    q = _winter_query(mem, summer, winter, teach=True)
    assert _columns(q[0]) == _columns(db[0]) and q[1:] == [[]] * (N_PLACES - 1)   # winter is not recognised
    assert all(len(s) == 1 for s in mem.segments) and not mem.taught_log
    mem2, _ = _learned(summer, teach_below=1)
    assert _winter_query(mem2, summer, winter, teach=False) == q   # teach=False: no teacher either


def test_cap_stops_the_teacher():
    summer, winter = _seasons()
    mem, _ = _learned(summer, teach_below=1, max_segments=1)
    q = _winter_query(mem, summer, winter, teach=True)
    assert q[1:] == [[]] * (N_PLACES - 1) and all(len(s) == 1 for s in mem.segments)


def test_confirmed_only_ignores_predictions_of_a_burst():
    summer, winter = _seasons()
    mem, db = _learned(summer, teach_below=1, confirmed_only=True)
    # place 0 bursts (no context), so its predictions are not confirmed: winter place 1 is not taught
    assert _winter_query(mem, summer, winter, teach=True)[1] == []
    mem.reset()
    # places 0 and 1 in summer: place 1 was predicted, so its predictions teach winter place 2
    out = [mem.step(_bits(summer, t), learn=False, teach=True) for t in (0, 1)]
    out.append(mem.step(_bits(winter, 2), learn=False, teach=True))
    assert _columns(out[0]) == _columns(db[0]) and out[1:] == db[1:3]
    assert mem.taught_log == [(N_PLACES + 2, _columns(db[2]))]


def test_teacher_precision_and_labels():
    summer, winter = _seasons()
    db, q, stats = segment_codes(summer, winter, teach_below=1)
    assert stats["teacher_precision"] == 1.0 and stats["taught_frames"] >= 1
    mem = SegmentedMemory(seed=0)
    db_codes = mem.run(summer, learn=True)
    teach_from_labels(mem, winter, db_codes)
    assert teacher_precision(mem, db_codes, tolerance=0) == 1.0
    assert all(len(s) == 2 for s in mem.segments)
    _, q_after, _ = segment_codes(summer, winter, read="after", teacher="labels")
    assert np.all(q_after.getnnz(axis=1) > 0)


def test_bad_arguments():
    with pytest.raises(ValueError):
        SegmentedMemory().step([1, 2, 3], learn=True, teach=True)
    with pytest.raises(ValueError):
        SegmentedMemory(max_segments=0)
    with pytest.raises(ValueError):
        segment_codes(sdr.random_sdrs(3, seed=0), sdr.random_sdrs(3, seed=1), read="online", teacher="labels")
