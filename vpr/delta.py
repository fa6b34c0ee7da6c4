"""Delta Descriptors (Garg, Harwood and Milford, RA-L 2020): a traverse's descriptors as their change along it.

Each frame's delta descriptor is, per dimension, the mean of the ``L / 2`` frames from it on minus the mean of the
``L / 2`` frames before it (frames beyond the traverse's ends count as zero, the sums still divided by ``L / 2``); a
frame whose delta sums to exactly zero keeps its raw descriptor. Traverses are then compared by the cosine of their
delta descriptors: the field's simplest training-free sequence method, beside which the sequence memory is measured.
"""
from __future__ import annotations

import numpy as np

from vpr.checks import check_int
from vpr.similarity import cosine

__all__ = ["delta_descriptors", "delta_similarity"]


def delta_descriptors(desc, L: int = 16) -> np.ndarray:
    """The delta descriptors (frames x dims, float32) of one traverse's descriptors ``desc`` (frames x dims).

    ``L``: the window, an even number of frames >= 2 (ValueError otherwise).
    """
    L = check_int(L, "delta: L", 2)
    if L % 2:
        raise ValueError(f"delta: L must be even (half the window on each side of a frame), got {L}")
    x = np.asarray(desc, np.float64)
    if x.ndim != 2:
        raise ValueError(f"delta: descriptors must be frames x dims, got shape {x.shape}")
    n, h = x.shape[0], L // 2
    cum = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])  # cum[t] = sum of frames 0 .. t - 1
    t = np.arange(n)
    ahead = cum[np.minimum(t + h, n)] - cum[t]  # frames t .. t + h - 1
    behind = cum[t] - cum[np.maximum(t - h, 0)]  # frames t - h .. t - 1
    d = (ahead - behind) / h
    d[d.sum(axis=1) == 0] = x[d.sum(axis=1) == 0]
    return d.astype(np.float32)


def delta_similarity(db_desc, q_desc, L: int = 16) -> np.ndarray:
    """Database x query cosine similarity of the two traverses' delta descriptors (higher = more similar)."""
    return cosine(delta_descriptors(db_desc, L), delta_descriptors(q_desc, L))
