"""A revisit of a route at another speed, as SDRs: the oracle of the placement and the back-fill tests."""
import numpy as np
import scipy.sparse as sp

from vpr import sdr

N_BITS, K, ROUTE = 2048, 80, 300


def route_driven_again(speed: float, seed: int = 0):
    """A first pass of ROUTE frames whose view changes a fifth of its bits a frame, then the same route again at
    ``speed`` frames a frame, a third of every frame's bits moved; returns (SDR batch, each frame's place or -1)."""
    rng = np.random.default_rng(seed)
    route = [rng.choice(N_BITS, K, replace=False)]
    for _ in range(ROUTE - 1):
        row = route[-1].copy()
        row[rng.choice(K, K // 5, replace=False)] = rng.choice(np.setdiff1d(np.arange(N_BITS), row), K // 5,
                                                              replace=False)
        route.append(row)
    first = sp.csr_matrix((np.ones(ROUTE * K, bool), np.concatenate(route), np.arange(ROUTE + 1) * K),
                          shape=(ROUTE, N_BITS))
    places = np.arange(0, ROUTE, speed).astype(int)
    again = sdr.add_noise(first[places], 0.35, seed=seed + 1)
    return sp.vstack([first, again]).tocsr(), np.r_[np.full(ROUTE, -1), places]
