import numpy as np

from studies.loops_acceptance import count


def test_count_splits_false_alias_and_true_closures():
    T = 50
    S = np.full((T, T), -np.inf)
    i, j = np.indices((T, T))
    S[i <= j - 5] = 0.0
    d = np.abs(i - j).astype(float)  # metres = frames apart: no revisit ...
    d[0:3, 40:43] = d[40:43, 0:3] = 1.0  # ... except frames 40-42, which revisit 0-2
    alias = np.zeros((T, T), bool)
    alias[10:13, 30:33] = True  # 30-32 look exactly like 10-12
    for q, b in ((30, 10), (31, 11), (32, 12), (40, 0), (41, 1), (42, 2), (20, 5)):
        S[b, q] = 9.0
    false, onto_alias, true, has = count(S, d, alias, None, z_min=8.0, confirm=0, near=2.0, far=4.0, exclude=5)
    assert (false, onto_alias, true, has) == (1, 3, 3, 3)
    # confirm=2 keeps only the third frame of each run; frame 20 alone is dropped
    assert count(S, d, alias, None, z_min=8.0, confirm=2, near=2.0, far=4.0, exclude=5) == (0, 1, 1, 3)
