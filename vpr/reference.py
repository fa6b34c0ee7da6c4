"""A slow, literal implementation of Algorithm 1 (sets and dicts) for cross-checking.

:class:`ReferenceMemory` follows the paper's listing line by line and draws its
random numbers from the same generator in the same order as
:class:`vpr.memory.SequenceMemory`, so for the same seed both must produce
identical winner cells. The tests compare them; ``benchmarks/bench_memory.py``
uses it for a speed ratio. Do not use it for real work.
"""
from __future__ import annotations

from collections import defaultdict

import numpy as np

__all__ = ["ReferenceMemory", "learn_lateral"]


def learn_lateral(forward, backward, prev_winners, winners, cpc, p_extra, rng) -> None:
    """Alg. 1 lines 12-13 with rSHOSM's extra connections, on dict-of-set connections.

    Each previous winner ``s`` connects to each winner ``c`` unless a cell of
    ``s``'s minicolumn already does; with probability ``p_extra`` (one draw from
    ``rng`` per such pair) it connects anyway, unless ``s -> c`` exists.
    """
    for s in prev_winners:
        for c in winners:
            sources = backward[c]
            has_column = any(x // cpc == s // cpc for x in sources)
            make = not has_column
            if has_column and p_extra > 0:
                make = rng.random() < p_extra and s not in sources
            if make:
                forward[s].add(c)
                backward[c].add(s)


class ReferenceMemory:
    """Same parameters and semantics as :class:`vpr.memory.SequenceMemory`."""

    def __init__(self, n_inputs=2048, cells_per_column=32, new_columns=10, connectivity=0.5, threshold=0.25,
                 p_extra=0.05, k_active=10, seed=0):
        self.n_inputs, self.cpc, self.new_columns = n_inputs, cells_per_column, new_columns
        self.connectivity, self.threshold, self.p_extra, self.k_active = connectivity, threshold, p_extra, k_active
        self.rng = np.random.default_rng(seed)
        self.columns: list[set[int]] = []       # feed-forward connections of each minicolumn
        self.thresholds: list[int] = []
        self.forward = defaultdict(set)          # cell -> cells it predicts
        self.backward = defaultdict(set)         # cell -> cells that predict it
        self.predicted: set[int] = set()
        self.prev_winners: list[int] = []

    def reset(self):
        self.predicted, self.prev_winners = set(), []

    def step(self, bits, learn=True):
        bits = sorted(int(b) for b in bits)
        bitset = set(bits)
        cpc = self.cpc
        # line 1
        overlaps = [len(c & bitset) for c in self.columns]
        active = [m for m, o in enumerate(overlaps) if o >= self.thresholds[m]]
        if not active and not learn and self.k_active > 0:
            cand = sorted((-o, m) for m, o in enumerate(overlaps) if o > 0)
            active = [m for _, m in cand[: self.k_active]]
        # lines 2-4
        if not active and learn and bits:
            n_conn = max(1, int(np.round(self.connectivity * len(bits))))
            thr = int(np.ceil(self.threshold * n_conn - 1e-9))
            for _ in range(self.new_columns):
                keys = [self.rng.random() for _ in bits]
                order = sorted(range(len(bits)), key=lambda i: (keys[i], i))
                self.columns.append({bits[i] for i in order[:n_conn]})
                self.thresholds.append(thr)
                active.append(len(self.columns) - 1)
        if not active:
            self.reset()
            return []
        winners, next_predicted = [], set()
        for m in sorted(active):                     # line 5
            cells = range(m * cpc, (m + 1) * cpc)
            predicted = [c for c in cells if c in self.predicted]   # line 6
            if predicted:
                for c in predicted:                  # line 7
                    next_predicted |= self.forward[c]
                winners += predicted                 # line 8
            else:                                    # line 9
                for c in cells:                      # line 10
                    next_predicted |= self.forward[c]
                keys = [len(self.forward[c]) + 0.5 * self.rng.random() for c in cells]
                winners.append(cells[int(np.argmin(keys))])   # line 11
        if learn:                                    # lines 12-13
            learn_lateral(self.forward, self.backward, self.prev_winners, winners, cpc, self.p_extra, self.rng)
        self.predicted = next_predicted
        self.prev_winners = winners
        return winners
