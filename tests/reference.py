"""Test oracle: a slow, literal implementation of Algorithm 1 (sets and dicts).

:class:`ReferenceMemory` follows the paper's listing line by line and draws its
random numbers from the same generator in the same order as
:class:`vpr.shosm.SequenceMemory`, so for the same seed both must produce
identical winner cells (with learning off neither draws any: ties between
bursting cells are broken by :func:`query_tie_key`). The tests compare them;
``research/benchmarks/bench_memory.py`` uses it for a speed ratio and the studies in
``research/studies/`` build their pure-Python variants on it. Not part of the product.
"""
from __future__ import annotations

from collections import defaultdict

import numpy as np

__all__ = ["ReferenceMemory", "activate_cells", "learn_lateral", "query_tie_key"]

_M64 = (1 << 64) - 1


def query_tie_key(cell: int) -> float:
    """splitmix64 of ``cell`` in [0, 1): the same fixed tie-break as ``vpr.shosm.kernels.memory.query_tie_key``."""
    z = (int(cell) + 0x9E3779B97F4A7C15) & _M64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _M64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _M64
    z ^= z >> 31
    return (z >> 11) / 9007199254740992.0


def activate_cells(active, predicted, forward, cpc, rng, learn=True):
    """Alg. 1 lines 5-11: winner cells, cells predicted next, and those predicted by predicted winners.

    A minicolumn with predicted cells lets them win and predict (lines 6-8);
    otherwise it bursts (lines 9-11): all its cells predict and the cell with
    the fewest forward connections wins, ties broken by ``rng`` while learning
    and by :func:`query_tie_key` with learning off.
    """
    winners, next_predicted, next_confirmed = [], set(), set()
    for m in sorted(active):                     # line 5
        cells = range(m * cpc, (m + 1) * cpc)
        hit = [c for c in cells if c in predicted]   # line 6
        if hit:
            for c in hit:                        # line 7
                next_predicted |= forward[c]
                next_confirmed |= forward[c]
            winners += hit                       # line 8
        else:                                    # line 9
            for c in cells:                      # line 10
                next_predicted |= forward[c]
            ties = [rng.random() for _ in cells] if learn else [query_tie_key(c) for c in cells]
            keys = [len(forward[c]) + 0.5 * u for c, u in zip(cells, ties, strict=True)]
            winners.append(cells[int(np.argmin(keys))])   # line 11
    return winners, next_predicted, next_confirmed


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
    """Same parameters and semantics as :class:`vpr.shosm.SequenceMemory`."""

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
        winners, next_predicted, _ = activate_cells(active, self.predicted, self.forward, cpc, self.rng, learn)
        if learn:                                    # lines 12-13
            learn_lateral(self.forward, self.backward, self.prev_winners, winners, cpc, self.p_extra, self.rng)
        self.predicted = next_predicted
        self.prev_winners = winners
        return winners


def field_recalls(S, db_xy, q_xy, ns, radius: float = 25.0) -> np.ndarray:
    """Recall@N as VPR-methods-evaluation computes it, from its description: each query's positives are the database
    positions within ``radius`` (scikit-learn's ``radius_neighbors``), its predictions the database frames by
    decreasing similarity (ties: lower index first), and a query counts at N (and every larger N) once one of its N
    first predictions is a positive; the counts are divided by the number of queries, every query."""
    from sklearn.neighbors import NearestNeighbors

    positives = NearestNeighbors().fit(db_xy).radius_neighbors(q_xy, radius=radius, return_distance=False)
    predictions = np.argsort(-np.asarray(S, np.float64), axis=0, kind="stable")[:max(ns)].T
    recalls = np.zeros(len(ns))
    for q, preds in enumerate(predictions):
        for i, n in enumerate(ns):
            if np.any(np.isin(preds[:n], positives[q])):
                recalls[i:] += 1
                break
    return recalls / len(q_xy)


def delta_descriptors_by_convolution(x, L: int) -> np.ndarray:
    """Delta Descriptors as the paper's code describes its ``delta`` op: each dimension convolved (``"same"``) with a
    kernel of ``L / 2`` entries ``+2 / L`` then ``L / 2`` entries ``-2 / L`` (NumPy's convolution flips it: the mean of
    the frames ahead minus that of the frames behind), a frame summing to exactly zero keeping its raw descriptor."""
    v = np.full(L, -2.0 / L)
    v[:L // 2] *= -1
    d = np.array([np.convolve(x[:, i], v, "same") for i in range(x.shape[1])]).T
    return np.array([x[j] if row.sum() == 0 else row for j, row in enumerate(d)])


def hloc_pairs(path) -> dict[str, list[str]]:
    """An hloc pairs file read by hloc's own rule (``parse_retrieval``): one pair a line, ``name0 name1`` split on white
    space; the retrieved names of each query, in the file's order."""
    out: dict[str, list[str]] = defaultdict(list)
    with open(path, encoding="utf-8") as fh:
        for line in fh.read().rstrip("\n").split("\n"):
            q, r = line.split()
            out[q].append(r)
    return dict(out)


def stream_beam_reference(stream, exclude: int, decay: float, stay: float, skip: float, floor: float,
                          rel_floor: float, z_floor: float, z_weight: float = 0.0, sessions=()) -> list[dict]:
    """The beam's evidence of every frame of a stream over the frames before it, literally (sets and dicts).

    ``stream``: the SDR rows (active bits) of the stream; a :class:`vpr.shosm.SequenceMemory` learns each (a fresh
    context at each frame of ``sessions``), then frame ``j`` is scored over the frames ``0 .. L`` (``L = j - exclude``,
    or every frame of the earlier sessions) with only the cells that first won by frame ``L`` taking part: a cell is
    a candidate when its minicolumn's overlap fraction is above ``z_floor``, when a beam cell predicts it (a
    connection, or two: a skipped frame at ``skip``), or when it is a beam cell above ``stay``; its evidence is its
    fraction plus ``decay`` times the best of those offers (never below 0); the cells above ``max(floor, rel_floor
    * largest)`` form the next beam and give each frame whose code holds one the mean of ``evidence - z_weight *
    fraction`` over its code. Returns per frame ``{frame: raw evidence}`` (uncapped).
    """
    from vpr.shosm import SequenceMemory

    mem = SequenceMemory(n_inputs=int(max(max(r) for r in stream if len(r)) + 1), seed=0) \
        if not hasattr(stream, "memory") else stream.memory
    rows = list(stream)
    born: dict[int, int] = {}
    codes: list[list[int]] = []
    beam: dict[int, float] = {}
    out = []
    start = 0
    for j, bits in enumerate(rows):
        if j in set(sessions) and j > 0:
            mem.reset()
            beam = {}
            start = j
        winners = [int(c) for c in mem.step(np.asarray(bits, np.int64))]
        for c in winners:
            born.setdefault(c, j)
        codes.append(winners)
        limit = max(j - max(exclude, 1) + 1, start, 0) - 1  # the candidate frames 0 .. limit
        con = mem.connections
        lateral = con.lateral.tocsr()
        ff = con.feedforward.tocsr()
        active = set(int(b) for b in bits)
        size = np.diff(ff.indptr)
        frac = {}
        for m in range(ff.shape[0]):
            if size[m]:
                frac[m] = sum(1 for b in ff.indices[ff.indptr[m]:ff.indptr[m + 1]] if b in active) / size[m]
        cpc = mem.cells_per_column
        live = {c for c, b in born.items() if b <= limit}

        def z(c, frac=frac, cpc=cpc):
            return frac.get(c // cpc, 0.0)

        cand = {c for c in live if z(c) > z_floor}
        cand |= {c for c, v in beam.items() if c in live and stay >= 0 and v > stay}
        p1: dict[int, float] = {}
        for s, v in beam.items():
            if s in live:
                for d in lateral.indices[lateral.indptr[s]:lateral.indptr[s + 1]]:
                    if d in live:
                        cand.add(int(d))
                        p1[int(d)] = max(p1.get(int(d), 0.0), v)
        p2: dict[int, float] = {}
        if skip >= 0:
            for s, v in list(p1.items()):
                if v > skip:
                    for d in lateral.indices[lateral.indptr[s]:lateral.indptr[s + 1]]:
                        if d in live:
                            cand.add(int(d))
                            p2[int(d)] = max(p2.get(int(d), 0.0), v)
        e = {}
        for c in cand:
            p = p1.get(c, 0.0)
            if skip >= 0:
                p = max(p, p2.get(c, 0.0) - skip)
            if stay >= 0 and c in beam:
                p = max(p, beam[c] - stay)
            e[c] = z(c) + decay * max(p, 0.0)
        thr = max(floor, rel_floor * max(e.values(), default=0.0))
        beam = {c: v for c, v in e.items() if v > thr}
        col = {}
        for f in range(limit + 1):
            hits = [c for c in codes[f] if c in beam]
            if hits:
                col[f] = sum((beam[c] - z_weight * z(c)) / max(len(codes[f]), 1) for c in hits)
        out.append(col)
    return out
