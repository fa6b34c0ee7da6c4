"""Compiled kernels of the blocked top-K SeqSLAM (numba): contrast enhancement, trajectories."""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["enhance_rows", "trajectories"]


@njit(cache=True, nogil=True)
def enhance_rows(D, d0, z0, z1, n_db, h, out):  # pragma: no cover - compiled
    # Same arithmetic, in the same order, as enhance_contrast (float64 two-pass sums over the rows ascending), so each
    # z equals the dense one bit for bit; the loops run over columns innermost so that they vectorise.
    C = D.shape[1]
    s = np.empty(C)
    ss = np.empty(C)
    for i in range(z0, z1):
        j0 = max(0, i - h)
        j1 = min(n_db - 1, i + h)
        cnt = float(j1 - j0 + 1)
        s[:] = 0.0
        ss[:] = 0.0
        for j in range(j0, j1 + 1):
            for c in range(C):
                s[c] += np.float64(D[j - d0, c])
        for c in range(C):
            s[c] = s[c] / cnt
        for j in range(j0, j1 + 1):
            for c in range(C):
                d = np.float64(D[j - d0, c]) - s[c]
                ss[c] += d * d
        for c in range(C):
            mean = s[c]
            std = np.sqrt(ss[c] / max(cnt - 1.0, 1.0))
            if std <= 1e-10 * abs(mean) or std == 0.0 or cnt == 1.0:
                out[i - z0, c] = 0.0
            else:
                out[i - z0, c] = np.float32((np.float64(D[i - d0, c]) - mean) / std)


@njit(cache=True, nogil=True)
def trajectories(Z, z0, o0, o1, n_db, rel, colvalid, S, P):  # pragma: no cover - compiled
    # Z holds enhanced rows z0.. (global) and the block's query columns shifted so that point k of the trajectory of
    # output column j is column j + k; columns outside the query sequence are zero, as in _trajectory_scores' padding,
    # so sums are the same float32 sums in the same order.
    w = S.shape[1]
    n_v, n_pts = rel.shape
    interior = True
    for c in range(colvalid.shape[0]):
        if not colvalid[c]:
            interior = False
    nfr = np.zeros(w, np.int64)
    for j in range(w):
        for k in range(n_pts):
            if colvalid[j + k]:
                nfr[j] += 1
    acc = np.empty(w, np.float32)
    rowin = np.empty(n_pts, np.bool_)
    inf = np.float32(np.inf)
    fpts = np.float32(n_pts)
    for i in range(o0, o1):
        li = i - o0
        for j in range(w):
            S[li, j] = inf
            P[li, j] = inf
        for v in range(n_v):
            acc[:] = 0.0
            nin = 0
            for k in range(n_pts):
                r = i + rel[v, k]
                rowin[k] = 0 <= r < n_db
                if rowin[k]:
                    nin += 1
                    zr = r - z0
                    for j in range(w):
                        acc[j] += Z[zr, j + k]
            if nin == 0:
                continue
            if interior:
                # every query frame exists: one factor for the row, branch-free minima (vectorised)
                f = fpts / np.float32(nin)
                full = nin == n_pts
                if full:
                    for j in range(w):
                        pv = acc[j] * f
                        P[li, j] = min(P[li, j], pv)
                        S[li, j] = min(S[li, j], pv)
                else:
                    for j in range(w):
                        P[li, j] = min(P[li, j], acc[j] * f)
                continue
            for j in range(w):
                cnt = 0
                for k in range(n_pts):
                    if rowin[k] and colvalid[j + k]:
                        cnt += 1
                if cnt == 0:
                    continue
                pv = acc[j] * (fpts / np.float32(cnt))
                if pv < P[li, j]:
                    P[li, j] = pv
                if cnt == nfr[j] and pv < S[li, j]:
                    S[li, j] = pv
