"""research.studies.speed_models: the slower query's answers that contradict the frame before's, as the study counts
them."""
import numpy as np

from research.studies.speed_models import contradicting, refusing


def test_an_answer_behind_or_far_ahead_of_the_frame_before_contradicts_it_only_at_a_slower_speed():
    best = np.array([10, 10, 11, 9, 12, 15, 15, 20])
    accepted = np.array([1, 1, 1, 1, 1, 1, 0, 1], bool)
    slower = np.array([1, 1, 1, 1, 1, 1, 1, 0], bool)
    # 11 -> 9 is 2 behind, 9 -> 12 is 3 ahead, 12 -> 15 is 3 ahead; 15 -> 20 is not slower and follows a refusal
    assert contradicting(best, accepted, slower).tolist() == [False, False, False, True, True, True, False, False]


def test_refusing_holds_each_frame_against_the_answer_given_before_it():
    best = np.array([10, 10, 7, 11, 11])
    accepted = np.ones(5, bool)
    slower = np.ones(5, bool)
    # 7 contradicts 10 and is refused; 11 then follows a refused frame and stands (7 is no longer the frame before's)
    assert refusing(best, accepted, slower).tolist() == [True, True, False, True, True]
    assert contradicting(best, accepted, slower).tolist() == [False, False, True, True, False]
