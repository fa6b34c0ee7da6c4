"""Place stepping of research/studies/places.py on small hand-made streams; no dataset needed."""
import numpy as np
import scipy.sparse as sp

from research.studies.places import overlap_profile, places_by_appearance, places_by_stride, pooled


def _rows(bits, n=16):
    r = np.repeat(np.arange(len(bits)), [len(b) for b in bits])
    c = np.concatenate([np.asarray(b) for b in bits])
    return sp.csr_matrix((np.ones(r.size, bool), (r, c)), shape=(len(bits), n))


def test_places_by_stride_counts_from_each_traverse_start():
    p = places_by_stride(10, 3, starts=(5,))
    assert p.tolist() == [0, 0, 0, 1, 1, 2, 2, 2, 3, 3]


def test_places_by_appearance_steps_when_the_overlap_with_the_place_start_drops():
    x = _rows([[0, 1, 2, 3], [0, 1, 2, 4], [0, 1, 5, 6], [7, 8, 9, 10], [7, 8, 9, 11]])
    # frame 1 shares 3/4 of frame 0, frame 2 2/4 (new place at 0.6), frame 3 none, frame 4 3/4 of frame 3
    assert places_by_appearance(x, 0.6).tolist() == [0, 0, 1, 2, 2]
    assert places_by_appearance(x, 0.4).tolist() == [0, 0, 0, 1, 1]
    assert places_by_appearance(x, 0.4, starts=(4,)).tolist() == [0, 0, 0, 1, 2]  # a traverse starts anew


def test_pooled_keeps_the_bits_most_often_active_in_each_place():
    x = _rows([[0, 1], [0, 2], [0, 1], [5, 6]])
    y = pooled(x, np.array([0, 0, 0, 1]))
    assert y.shape == (2, 16) and (y.sum(axis=1) == 2).all()
    assert sorted(y[0].indices) == [0, 1] and sorted(y[1].indices) == [5, 6]


def test_overlap_profile_sees_a_revisit_and_a_stop():
    rng = np.random.default_rng(0)
    first = [sorted(rng.choice(64, 8, replace=False)) for _ in range(120)]
    x = _rows(first + first, n=64)  # the second traverse repeats the first exactly
    same, other = overlap_profile(x, 120)
    assert same[0] == 1.0 and other[0] == 1.0 and max(same[1:]) < 0.5 and max(other[1:]) < 0.5
