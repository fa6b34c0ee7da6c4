"""The query's speed along accepted paths (studies.speed_models.path_speed)."""
import numpy as np

from studies.speed_models import path_speed


def test_speed_counts_only_long_consistent_accepted_runs():
    fast = np.arange(0, 40, 2)                 # 20 frames moving 2 map frames a frame
    slow = 100 + np.arange(30) // 2            # 30 frames moving half a frame a frame
    short = np.array([500, 501, 502])          # too short to count
    best = np.r_[fast, slow, short]
    accepted = np.ones(best.size, bool)
    v, n = path_speed(best, accepted)
    assert n == 19 + 29
    assert np.isclose(v, (38 + 14) / 48)
    accepted[20:50] = False                    # only the fast run is left
    assert path_speed(best, accepted) == (2.0, 19)


def test_no_speed_without_a_run_of_min_run_frames():
    best = np.arange(9)
    assert path_speed(best, np.ones(9, bool)) == (None, 0)
    assert path_speed(np.r_[best, -1, best], np.ones(19, bool)) == (None, 0)
    jumpy = np.arange(0, 100, 5)               # 5 frames a frame: not one path
    assert path_speed(jumpy, np.ones(jumpy.size, bool)) == (None, 0)
