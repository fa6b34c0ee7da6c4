"""The simulated world of the paper's section 5."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from vpr import sdr as _sdr

__all__ = ["World", "make_world", "loop_trajectory", "random_walk", "observe", "simulate_loops", "aliased_traverses"]


@dataclass
class World:
    """Places on a ``rows x cols`` grid; ``sdrs[p]`` is what the sensor shows at place ``p``.

    ``aliased`` lists the (place, twin) pairs whose SDRs are identical.
    """

    rows: int
    cols: int
    sdrs: sp.csr_matrix
    aliased: np.ndarray

    @property
    def n_places(self) -> int:
        return self.rows * self.cols

    def xy(self, places) -> np.ndarray:
        """Grid coordinates (x, y) of places."""
        p = np.asarray(places)
        return np.stack([p % self.cols, p // self.cols], axis=-1).astype(float)


def make_world(rows: int, cols: int, n_bits: int = 2048, n_active: int = 40, aliasing: int = 0,
               alias_places=None, seed=None) -> World:
    """A grid world with one random SDR per place; ``aliasing`` pairs of places (from ``alias_places``, the
    paper's visited places) share one.
    """
    if rows <= 0 or cols <= 0:
        raise ValueError(f"grid must have positive size, got {rows} x {cols}")
    rng = np.random.default_rng(seed)
    n = rows * cols
    sdrs = _sdr.random_sdrs(n, n_bits, n_active, seed=rng)
    pool = np.arange(n) if alias_places is None else np.unique(np.asarray(alias_places))
    if 2 * aliasing > pool.size:
        raise ValueError(f"aliasing={aliasing} needs {2 * aliasing} places, only {pool.size} available")
    pairs = rng.choice(pool, size=2 * aliasing, replace=False).reshape(-1, 2) if aliasing else np.zeros((0, 2), int)
    if aliasing:
        lil = sdrs.tolil()
        for p, q in pairs:
            lil[q] = lil[p]
        sdrs = _sdr.check_batch(lil.tocsr())
    return World(rows, cols, sdrs, pairs)


def loop_trajectory(rows: int = 6, cols: int = 6, n_loops: int = 10) -> np.ndarray:
    """Places of ``n_loops`` laps around the border of a ``rows x cols`` grid.

    With the defaults a lap has 20 places and the trajectory 200 observations, as in the paper's experiments (each
    place visited 10 times).
    """
    if rows < 2 or cols < 2:
        raise ValueError("a loop needs a grid of at least 2 x 2")
    top = [(0, c) for c in range(cols)]
    right = [(r, cols - 1) for r in range(1, rows)]
    bottom = [(rows - 1, c) for c in range(cols - 2, -1, -1)]
    left = [(r, 0) for r in range(rows - 2, 0, -1)]
    lap = np.array([r * cols + c for r, c in top + right + bottom + left])
    return np.tile(lap, n_loops)


def random_walk(rows: int, cols: int, n_steps: int, seed=None) -> np.ndarray:
    """Places of a 4-neighbour random walk on the grid (never standing still)."""
    rng = np.random.default_rng(seed)
    moves = np.array([(0, 1), (0, -1), (1, 0), (-1, 0)])
    r, c = rng.integers(rows), rng.integers(cols)
    out = np.empty(n_steps, dtype=np.int64)
    choice = rng.integers(0, 4, size=n_steps)
    for t in range(n_steps):
        out[t] = r * cols + c
        dr, dc = moves[choice[t]]
        # reflect at the border so every step moves
        r = r + dr if 0 <= r + dr < rows else r - dr
        c = c + dc if 0 <= c + dc < cols else c - dc
    return out


def observe(world: World, trajectory, noise: float = 0.0, seed=None) -> sp.csr_matrix:
    """The sensor's SDRs along a trajectory, with ``noise`` fraction of 1-bits moved."""
    traj = np.asarray(trajectory)
    obs = world.sdrs[traj]
    return _sdr.add_noise(obs, noise, seed=seed) if noise > 0 else _sdr.check_batch(obs)


def simulate_loops(aliasing: int = 0, noise: float = 0.0, rows: int = 6, cols: int = 6, n_loops: int = 10,
                   n_bits: int = 2048, n_active: int = 40, seed=None):
    """The paper's experiment input: (observations, place labels) for ``n_loops`` laps.

    Aliased pairs are drawn among the places of the loop.
    """
    rng = np.random.default_rng(seed)
    traj = loop_trajectory(rows, cols, n_loops)
    world = make_world(rows, cols, n_bits, n_active, aliasing, alias_places=traj, seed=rng)
    return observe(world, traj, noise, seed=rng), traj


def aliased_traverses(n_places: int, n_appearances: int, n_bits: int = 2048, k: int = 40, move: float = 0.35,
                      speed=(0.8, 1.2), seed=0):
    """Two traverses of a long route whose places reuse a few appearances (scale benchmarks).

    Each place shows one of ``n_appearances`` random SDRs (``k`` of ``n_bits``). The database visits every place once;
    the query moves at speeds from ``speed`` (places per frame, changing every 50 to 200 frames) with ``move`` of each
    SDR's bits moved. Returns ``db_sdr, q_sdr`` (csr bool) and ``db_place, q_place`` (int64).
    """
    if int(n_places) < 1 or int(n_appearances) < 1:
        raise ValueError(f"n_places and n_appearances must be >= 1, got {n_places}, {n_appearances}")
    lo, hi = (float(s) for s in speed)
    if not 0.0 < lo <= hi:
        raise ValueError(f"speed must be (min, max) with 0 < min <= max, got {speed}")
    rng = np.random.default_rng(seed)
    looks = _sdr.random_sdrs(int(n_appearances), n_bits, k, seed=rng)
    place_look = rng.permutation(np.resize(np.arange(int(n_appearances)), int(n_places)))
    db_place = np.arange(int(n_places), dtype=np.int64)
    steps = []
    total = 0.0
    while total < n_places + hi:
        n = int(rng.integers(50, 201))
        steps.append(np.full(n, rng.uniform(lo, hi)))
        total += n * steps[-1][0]
    pos = np.concatenate([[0.0], np.cumsum(np.concatenate(steps))])
    q_place = np.floor(pos[pos < n_places]).astype(np.int64)
    db_sdr = _sdr.check_batch(looks[place_look])
    q_sdr = _sdr.add_noise(looks[place_look[q_place]], move, seed=rng) if move > 0 else \
        _sdr.check_batch(looks[place_look[q_place]])
    return db_sdr, q_sdr, db_place, q_place
