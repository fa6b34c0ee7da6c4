"""research.studies.speed_models: the share of a frame's bits the frame before has beyond chance."""
import numpy as np

from research.studies.speed_models import shared_beyond_chance


def test_the_share_is_one_for_a_repeated_frame_and_zero_at_chance():
    a = np.arange(0, 200, dtype=np.int64)
    assert shared_beyond_chance(a, a, 2048) == 1.0
    half = np.arange(100, 300, dtype=np.int64)  # 100 shared, 200 * 200 / 400 = 100 by chance
    assert shared_beyond_chance(a, half, 400) == 0.0
    chance = 200 * 200 / 2048
    assert shared_beyond_chance(a, np.arange(150, 350, dtype=np.int64), 2048) == (50 - chance) / (200 - chance)
