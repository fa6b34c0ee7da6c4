import numpy as np
import scipy.sparse as sp

from research.studies.loop_stops import stop_beyond_chance, stop_raw
from vpr import sdr


def test_a_chance_overlap_reads_a_stop_raw_but_not_beyond_chance():
    # 30 random frames of 200 bits in 2,048 (about 20 shared by chance); the last shares 24 bits with the first only
    x = sdr.random_sdrs(30, 2048, 200, seed=1).tolil()
    first = x.rows[0][:24]
    last = sorted(set(first) | set(np.setdiff1d(np.arange(2048), x.rows[0])[-176:]))
    x[29] = sp.csr_matrix((np.ones(len(last), bool), (np.zeros(len(last), int), last)), shape=(1, 2048))
    x = x.tocsr()
    assert x[29].nnz == 200 and len(set(x[0].indices) & set(x[29].indices)) == 24
    assert stop_raw(x, 0, 29, 0.35) and not stop_beyond_chance(x, 0, 29, 0.35)


def test_a_camera_that_stood_is_a_stop_either_way():
    base = sdr.random_sdrs(1, 2048, 200, seed=2)
    x = sp.vstack([base] * 12).tocsr()  # the same view, frame after frame
    assert stop_raw(x, 0, 11, 0.35) and stop_beyond_chance(x, 0, 11, 0.35)
