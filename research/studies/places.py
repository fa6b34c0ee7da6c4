"""Places, not frames: does stepping the sequence memory per place make the loop decision hold at a robot's frame rate?

This study steps rSHOSM-seq per *place* (a new step
when the appearance has changed enough, or every N metres of odometry) and to
map every frame's answer back, because at Nordland's every file (7,152 frames)
the loop recall of accepted closures falls to 0.51 from 0.88 at every 10th
file. This study measures the premise and the remedy on the loop streams of
:mod:`research.studies.loop_streams`:

1. **How fast the appearance changes per frame.** Median SDR overlap (shared
   active bits over active bits) of frame ``t`` with frame ``t + d`` of the
   same traverse, and with the other traverse's frame ``t + d`` (its revisit
   at ``d = 0``). Ten frames per place would show as a high overlap over ``d``
   up to about ten.
2. **Stepping by appearance.** A new place when a frame shares fewer than
   ``min_overlap`` of the active bits of its place's first frame (and at each
   traverse's start); the memory learns and scores the places' first frames;
   each frame takes its place's decision and, as its match, the frame of the
   matched place that overlaps it most. Frames per step and the loop
   decisions (``LoopConf`` defaults) at frame level, against the per-frame run.
3. **Stepping by distance** (odometry's form, here every 10th frame index as
   a stand-in for equal distances), once with both traverses' steps on the
   same frames (``offset 0``: Nordland's files are synchronised across
   seasons) and once with the second traverse's steps shifted by a few frames,
   as two real runs would be; then with each place's SDR pooled over its
   frames (top-k of the summed bits).
4. **A longer sequence memory** instead (``decay`` 0.95, 0.97 against 0.9).

Usage: python -m research.studies.places [--cache DIR] [--data DIR] [--preset default]
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from research.studies.loop_decisions import EXCLUDE, evidence
from research.studies.loop_streams import load_stream
from vpr.shosm import LoopConf, accept_loops, loop_evidence

LAGS = (0, 1, 2, 5, 10, 30, 100)


def overlap_profile(x: sp.csr_matrix, start: int) -> tuple[list[float], list[float]]:
    """Median overlap of frame ``t`` with ``t + d`` (same traverse) and with the second traverse's ``t + d``."""
    x = x.tocsr().astype(np.float32)
    k = float(x[0].sum())
    a, b = x[:start], x[start:]
    n = min(a.shape[0], b.shape[0])
    same, other = [], []
    for d in LAGS:
        m = n - d
        same.append(float(np.median(np.asarray(a[:m].multiply(a[d:d + m]).sum(1)).ravel())) / k)
        other.append(float(np.median(np.asarray(a[:m].multiply(b[d:d + m]).sum(1)).ravel())) / k)
    return same, other


def places_by_appearance(x: sp.csr_matrix, min_overlap: float, starts=()) -> np.ndarray:
    """Place index per frame: a new place when a frame shares < ``min_overlap`` of its place's first frame's bits."""
    x = x.tocsr()
    starts = set(starts)
    p = np.zeros(x.shape[0], np.int64)
    key, n = x.indices[x.indptr[0]:x.indptr[1]], 0
    for t in range(1, x.shape[0]):
        row = x.indices[x.indptr[t]:x.indptr[t + 1]]
        if t in starts or np.intersect1d(row, key, assume_unique=True).size < min_overlap * max(1, key.size):
            n, key = n + 1, row
        p[t] = n
    return p


def places_by_stride(T: int, every: int, starts=()) -> np.ndarray:
    """Place index per frame: one place per ``every`` frames, counted from each traverse's start."""
    bounds = sorted({0, *starts, T})
    p, n = np.zeros(T, np.int64), -1
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        local = np.arange(b - a) // every
        p[a:b] = n + 1 + local
        n = int(p[b - 1])
    return p


def pooled(x: sp.csr_matrix, p: np.ndarray) -> sp.csr_matrix:
    """One SDR per place: the ``k`` bits most often active over its frames (ties broken by bit index)."""
    T = x.shape[0]
    k = int(x[0].sum())
    P = sp.csr_matrix((np.ones(T, np.float32), (p, np.arange(T))), shape=(int(p.max()) + 1, T))
    c = (P @ x.astype(np.float32)).toarray() - np.arange(x.shape[1]) * 1e-6
    idx = np.argpartition(-c, k, axis=1)[:, :k]
    rows = np.repeat(np.arange(c.shape[0]), k)
    return sp.csr_matrix((np.ones(rows.size, bool), (rows, idx.ravel())), shape=c.shape)


def per_place(stream, p: np.ndarray, pool: bool = False):
    """Loop decisions on places, mapped back to frames: (best, accepted, steps, seconds)."""
    x = stream.x.tocsr()
    T = x.shape[0]
    first = np.flatnonzero(np.r_[True, p[1:] != p[:-1]])
    xp = pooled(x, p) if pool else x[first]
    t = time.perf_counter()
    d = accept_loops(loop_evidence(xp, exclude=EXCLUDE), LoopConf(), sdr=xp)
    seconds = time.perf_counter() - t
    members = np.split(np.arange(T), first[1:])
    xf = x.astype(np.float32)
    best, accepted = np.full(T, -1), np.zeros(T, bool)
    for j in range(T):
        b = d.best[p[j]]
        if b >= 0:
            m = members[b]
            best[j] = m[int(np.argmax(np.asarray((xf[m] @ xf[j].T).todense()).ravel()))]
            accepted[j] = d.accepted[p[j]]
    return best, accepted, first.size, seconds


def score(stream, best: np.ndarray, accepted: np.ndarray) -> dict:
    """Recall of the accepted closures over the frames with a loop, false closures, R@1."""
    j = np.flatnonzero(accepted)
    if stream.forward_only:
        return {"false": int(j.size)}
    true = stream.hard[best[j], j]
    soft = stream.soft[best[j], j] & ~true
    w = np.flatnonzero(np.triu(stream.hard, EXCLUDE).any(axis=0))
    b = best[w]
    return {"recall": float(true.sum()) / w.size, "false": int((~true & ~soft).sum()),
            "r1": float(np.mean((b >= 0) & stream.hard[np.maximum(b, 0), w]))}


def cell(r: dict) -> str:
    if "recall" not in r:
        return f"{r['false']} false"
    return f"{r['recall']:.2f}, {r['false']} false (R@1 {r['r1']:.2f})"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", default="results/loop_streams", help="encodings and evidence are cached here")
    ap.add_argument("--data", default=None, help="datasets folder (default: $VPR_DATASETS or ../shared/datasets)")
    ap.add_argument("--preset", default="default", help="preset whose loop encoder is used")
    a = ap.parse_args(argv)
    cache = Path(a.cache)
    cache.mkdir(parents=True, exist_ok=True)
    streams = {n: load_stream(n, a.preset, cache=cache, data=a.data)
               for n in ("gardens_point", "nordland_stream", "nordland_full", "nordland_summer")}
    start = {"gardens_point": 200, "nordland_stream": 358, "nordland_full": 3576}

    print(f"1. Median SDR overlap of frame t with frame t + d ({a.preset} loop encoder): same traverse / "
          "the other traverse (its revisit at d = 0); two unrelated frames share about 0.10\n")
    print("| stream | " + " | ".join(f"d = {d}" for d in LAGS) + " |")
    print("|---|" + "---|" * len(LAGS))
    for n, s0 in start.items():
        same, other = overlap_profile(streams[n].x, s0)
        print(f"| {n} | " + " | ".join(f"{u:.2f} / {v:.2f}" for u, v in zip(same, other, strict=True)) + " |")

    print("\n2. Stepping by appearance (LoopConf defaults; frame-level recall of accepted closures, false closures)\n")
    print("| stream | per frame | " + " | ".join(f"min_overlap {o}: frames per step, result" for o in (0.2, 0.3))
          + " |")
    print("|---|---|---|---|")
    for n, s in streams.items():
        d = accept_loops(evidence(s, cache, a.preset), LoopConf(), sdr=s.x)
        cells = [cell(score(s, d.best, d.accepted))]
        for o in (0.2, 0.3):
            p = places_by_appearance(s.x, o, starts=(start[n],) if n in start else ())
            best, acc, steps, sec = per_place(s, p)
            cells.append(f"{len(s) / steps:.2f}: {cell(score(s, best, acc))}")
        print(f"| {n} | " + " | ".join(cells) + " |", flush=True)

    s = streams["nordland_full"]
    print("\n3. Stepping every 10 frames on Nordland every file (7,152 frames, 716 steps): the second traverse's "
          "steps shifted by `offset` frames\n")
    print("| offset | first frames of the places | SDR pooled over each place |")
    print("|---|---|---|")
    for off in (0, 2, 5):
        p = places_by_stride(len(s), 10, starts=(start["nordland_full"] + off,))
        cells = [cell(score(s, *per_place(s, p, pool)[:2])) for pool in (False, True)]
        print(f"| {off} | " + " | ".join(cells) + " |", flush=True)

    print("\n4. A longer sequence memory instead (per frame, LoopConf defaults)\n")
    print("| decay | " + " | ".join(n for n in start) + " |")
    print("|---|" + "---|" * len(start))
    for dec in (0.9, 0.95, 0.97):
        cells = []
        for n in start:
            st = streams[n]
            ev = evidence(st, cache, a.preset) if dec == 0.9 else loop_evidence(st.x, exclude=EXCLUDE, decay=dec)
            d = accept_loops(ev, LoopConf(), sdr=st.x)
            cells.append(cell(score(st, d.best, d.accepted)))
        print(f"| {dec} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
