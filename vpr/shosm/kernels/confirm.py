"""Compiled kernels of a closure after the rule (numba): a frame's overlaps with its candidates, the look-ahead of the
confirmation."""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def standardised_overlaps(ptr, ind, q, n, block_ptr, col_rows, m, mask, out):  # pragma: no cover - compiled
    """``out[:n]``: the SDR overlap of row ``q`` with rows ``0 .. n - 1`` (sorted CSR ``ptr``, ``ind``), standardised
    over them (all 0 where they do not vary). Rows below ``m`` are counted through blocks of columns: block ``k``'s
    rows with bit ``b`` are ``col_rows[block_ptr[k, b]:block_ptr[k, b + 1]]``, ascending; the others row by row.
    ``mask``: a zeroed bool scratch of one entry per bit (left zeroed)."""
    for i in range(n):
        out[i] = 0.0
    for p in range(ptr[q], ptr[q + 1]):
        mask[ind[p]] = True
    for k in range(block_ptr.shape[0]):
        for p in range(ptr[q], ptr[q + 1]):
            b = ind[p]
            for t in range(block_ptr[k, b], block_ptr[k, b + 1]):
                r = col_rows[t]
                if r >= n:
                    break
                out[r] += 1.0
    for r in range(min(m, n), n):
        c = 0
        for p in range(ptr[r], ptr[r + 1]):
            if mask[ind[p]]:
                c += 1
        out[r] = c
    for p in range(ptr[q], ptr[q + 1]):
        mask[ind[p]] = False
    if n == 0:
        return
    mu = 0.0
    for i in range(n):
        mu += out[i]
    mu /= n
    var = 0.0
    for i in range(n):
        var += (out[i] - mu) ** 2
    sd = np.sqrt(var / n)
    for i in range(n):
        out[i] = (out[i] - mu) / sd if sd > 0 else 0.0


@njit(cache=True, nogil=True)
def ahead_scores(flat, row_ptr, stay, skip, acc, nxt):  # pragma: no cover - compiled
    """The best sum of per-frame scores along a path from each candidate of the first frame through the frames' rows
    (``flat[row_ptr[k]:row_ptr[k + 1]]``: frame ``k``'s scores over its candidates), moving 0 (cost ``stay``;
    negative: not allowed), 1, or 2 (cost ``skip``; negative: not allowed) candidates a frame. ``acc``, ``nxt``:
    scratch of the widest row + 2 entries. Returns the scores in ``acc[:width of the first row]``."""
    k_rows = row_ptr.shape[0] - 1
    width = 0
    for k in range(k_rows):
        width = max(width, row_ptr[k + 1] - row_ptr[k])
    for i in range(width + 2):
        acc[i] = -np.inf
        nxt[i] = -np.inf
    cur, prev = acc, nxt  # the rows swap: ``prev`` holds the frame after, ``cur`` takes this one's
    for k in range(k_rows - 1, -1, -1):
        cur, prev = prev, cur
        a, w = row_ptr[k], row_ptr[k + 1] - row_ptr[k]
        last = k == k_rows - 1
        for i in range(width):
            if i >= w:
                cur[i] = -np.inf
                continue
            if last:
                best = 0.0
            else:
                best = prev[i + 1]
                if skip >= 0 and prev[i + 2] - skip > best:
                    best = prev[i + 2] - skip
                if stay >= 0 and prev[i] - stay > best:
                    best = prev[i] - stay
            cur[i] = flat[a + i] + best
    if cur is not acc:
        for i in range(width):
            acc[i] = cur[i]
