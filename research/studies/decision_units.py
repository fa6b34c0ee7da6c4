"""A decision with one knob, a false-alarm rate: does a unit-free per-frame statistic hold across streams?

The loop and map rules (:class:`vpr.shosm.LoopConf`, :class:`vpr.shosm.PathConf`)
sum the best place's z-margin over the strongest other place, less a drift,
along a consistent path. Their units (z-scores of one column) change with the
stream. This study tries the design that would remove them: per frame, the
best place's lead over the strongest other place in units of the spacings
between the next ``K`` other places (an island above ``island`` or a local
maximum below it is a place; candidates without evidence fill in), which for
an exponential tail of "no revisit" places is F-distributed whatever the
number of candidates, the frame rate or the encoder: ``p = (1 + t / nu) **
-nu``. The per-frame evidence ``-ln p`` (nats; Exp(1) under the null),
weighted by the frame's novelty (:func:`novelty`: a camera that stands still
repeats one observation), less a cost of 2 nats, is summed along a consistent
path (a CUSUM) and accepted at the threshold whose average run length under
the null is ``1000 / rate`` frames (:func:`cusum_threshold`, a Markov chain on
the score).

Printed, against the current rules on the same evidence: loop closure on
every loop stream (recall of accepted closures, false accepted; forward
drives: false, + onto an identical copy), the false accepts per 1,000 frames
on the forward drives and on shuffled streams (the knob's honesty), the
per-frame evidence of right, wrong and no-loop frames, and localisation on the
cases of :mod:`research.studies.localize_decisions` (precision and recall of accepted
answers).

Usage: python -m research.studies.decision_units [--cache DIR] [--data DIR] [--rates 1,0.1,0.01,0.001]
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np
from numba import njit

from research.studies.localize_decisions import columns
from research.studies.loop_decisions import EXCLUDE, REVISITS, aliases, count, evidence
from research.studies.loop_streams import FORWARD, load_stream
from vpr import sdr as _sdr
from vpr.shosm import LoopConf, PathConf, accept_path, loop_evidence
from vpr.similarity import n_candidates, stationary

COST, K, PRIOR = 2.0, 10, 1.0
LOC_CASES = ("gardens_point", "nordland_358", "nordland_half", "nordland_3576")


def cusum_threshold(rate: float, cost: float = COST) -> float:
    """The score at which a CUSUM of Exp(1) - ``cost`` alarms ``rate`` times per 1,000 frames (Markov chain)."""
    arl = 1000.0 / rate

    def run_length(h, m=400):
        edges = np.linspace(0.0, h, m + 1)
        mid = 0.5 * (edges[:-1] + edges[1:])
        upper = np.concatenate([np.zeros((m, 1)), edges[None, 1:] - mid[:, None] + cost], axis=1)
        cdf = 1.0 - np.exp(-np.maximum(upper, 0.0))
        P = np.diff(cdf, axis=1)
        P[:, 0] = cdf[:, 1]
        return float(np.linalg.solve(np.eye(m) - P, np.ones(m))[0])

    lo, hi = 0.5, 60.0
    for _ in range(50):
        h = 0.5 * (lo + hi)
        lo, hi = (h, hi) if run_length(h) < arl else (lo, h)
    return hi


def novelty(x) -> np.ndarray:
    """How much of each frame is new since the one before, in [0, 1] (0: the same frame; 1: as unrelated frames)."""
    x = _sdr.check_batch(x).astype(np.float32)
    out = np.ones(x.shape[0])
    shared = np.asarray(x[1:].multiply(x[:-1]).sum(axis=1)).ravel()
    active = np.maximum(np.asarray(x[1:].sum(axis=1)).ravel(), 1)
    chance = active / x.shape[1]
    out[1:] = np.clip((1 - shared / active) / (1 - chance), 0, 1)
    return out


@njit(cache=True)
def lead_evidence(col, fill, island, k, prior):  # pragma: no cover - compiled
    """(best row, -ln p) of one dense column (see the module docstring)."""
    m = col.shape[0]
    kb = 0
    for i in range(1, m):
        if col[i] > col[kb]:
            kb = i
    lo, hi = kb, kb
    while lo > 0 and col[lo - 1] >= island:
        lo -= 1
    while hi < m - 1 and col[hi + 1] >= island:
        hi += 1
    top = np.full(k + 1, -np.inf)
    nt = 0
    i = 0
    while i < m:
        if i == lo:
            i = hi + 1
            continue
        j, peak = i, col[i]
        if col[i] >= island:
            while j + 1 < m and col[j + 1] >= island and j + 1 != lo:
                j += 1
                peak = max(peak, col[j])
        else:
            left = col[i - 1] if i > 0 else fill
            right = col[i + 1] if i + 1 < m else fill
            if col[i] < left or col[i] < right:
                i += 1
                continue
        q = min(nt, k)
        while q > 0 and top[q - 1] < peak:
            top[q] = top[q - 1]
            q -= 1
        top[q] = peak
        nt = min(nt + 1, k + 1)
        i = j + 1
    if nt == 0:
        return kb, 0.0
    spacing, nu = prior, 1.0
    for q in range(1, nt):
        spacing += q * (top[q - 1] - top[q])
        nu += 1.0
    t = max(col[kb] - top[0], 0.0) * nu / spacing
    return kb, nu * np.log1p(t / nu)


def decide(S, fill, n_of, nov, h, back=4, ahead=6, sdr=None, stop_ratio=0.35, exclude=None):
    """(best, evidence, accepted) of every column of ``S`` (dense; candidates ``0 .. n_of[j] - 1``) in order."""
    T = S.shape[1]
    best, ev, ok = np.full(T, -1), np.zeros(T), np.zeros(T, bool)
    score, head = 0.0, None
    ptr = ind = None
    if sdr is not None:
        x = _sdr.check_batch(sdr).copy()
        x.sort_indices()
        ptr, ind = x.indptr.astype(np.int64), x.indices.astype(np.int64)
    for j in range(T):
        n = int(n_of[j])
        if n < 2:
            score, head = 0.0, None
            continue
        b, e = lead_evidence(np.asarray(S[:n, j], np.float64), float(fill[j]), 1.0, K, PRIOR)
        cont = head is not None and head - back <= b <= head + ahead
        score = max(0.0, (score if cont else 0.0) + nov[j] * (e - COST))
        head = max(head, b) if cont else b
        if score == 0.0:
            head = b
        best[j], ev[j] = b, e
        near = exclude is not None and b >= n - 1 - ahead
        accepted = score >= h and not near
        if accepted and ptr is not None and stop_ratio > 0:
            accepted = not stationary(ptr, ind, b, j, stop_ratio, x.shape[1])
        ok[j] = accepted
    return best, ev, ok


def loops(stream, ev, alias, h) -> dict:
    """Loop closure of one stream with the lead statistic: as :func:`research.studies.loop_decisions.count`."""
    S = ev.similarity
    T = S.shape[1]
    n_of = np.array([n_candidates(j, EXCLUDE) for j in range(T)])
    best, e, ok = decide(S, ev.fill, n_of, novelty(stream.x), h, sdr=stream.x, exclude=EXCLUDE)
    j = np.flatnonzero(ok)
    b = best[j]
    if stream.forward_only:
        copy = alias[b, j] if alias is not None else np.zeros(j.size, bool)
        return {"false": int((~copy).sum()), "copy": int(copy.sum()), "frames": T, "evidence": e, "best": best}
    true, soft = stream.hard[b, j], stream.soft[b, j]
    frames = int(np.triu(stream.hard, EXCLUDE).any(axis=0).sum())
    return {"true": int(true.sum()), "false": int((~true & ~soft).sum()), "frames": frames, "evidence": e,
            "best": best}


def localise(case: str, data: Path, cache: Path, h: float | None):
    """(precision, recall, accepted, wrong) of the localizer's columns of ``case``, the lead rule (``h``) or
    the current PathConf (``h`` None)."""
    C, fill, _, hard, soft = columns(case, "default", data, cache)
    n = C.shape[1]
    if h is None:
        d = accept_path(_dense(C, fill).T, PathConf())
        best, ok = d.best, d.accepted
    else:
        best, _, ok = decide(_dense(C, fill).T, fill, np.full(C.shape[0], n), np.ones(C.shape[0]), h)
    q = np.arange(best.size)
    right = ok & hard[np.maximum(best, 0), q]
    wrong = ok & ~right & ~soft[np.maximum(best, 0), q]
    has = hard.any(axis=0)
    return right.sum() / max(right.sum() + wrong.sum(), 1), right.sum() / max(has.sum(), 1), int(ok.sum()), \
        int(wrong.sum())


def _dense(C, fill) -> np.ndarray:
    """Query x map z-scores of the localizer's stored columns, the rest at each column's fill."""
    D = np.repeat(np.asarray(fill, np.float32)[:, None], C.shape[1], axis=1)
    rows = np.repeat(np.arange(C.shape[0]), np.diff(C.indptr))
    D[rows, C.indices] = C.data
    return D


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", default="results/loop_streams")
    ap.add_argument("--data", default=None)
    ap.add_argument("--rates", default="1,0.1,0.01,0.001")
    a = ap.parse_args(argv)
    cache = Path(a.cache)
    data = Path(a.data or os.environ.get("VPR_DATASETS", "../shared/datasets"))
    rates = [float(r) for r in a.rates.split(",")]
    streams = {}
    for name in (*REVISITS, *FORWARD):
        s = load_stream(name, cache=cache, data=data)
        streams[name] = (s, evidence(s, cache), aliases(name))
    rng = np.random.default_rng(0)
    for name in ("gardens_point", "nordland_stream"):  # the frames in a random order: every closure is false
        s = streams[name][0]
        x = s.x[rng.permutation(len(s))]
        shuffled = type(s)(name + " shuffled", x, None, None)
        streams[shuffled.name] = (shuffled, loop_evidence(x, exclude=EXCLUDE), None)
    names = list(streams)
    print("| rule | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))

    def cell(s, c):
        return f"{c['false']} false" + (f" (+{c['copy']})" if c.get("copy") else "") if s.forward_only else \
            f"{c['true'] / c['frames']:.2f} ({c['false']})"

    cur = {n: count(s, ev, al, LoopConf()) for n, (s, ev, al) in streams.items()}
    print("| current LoopConf | " + " | ".join(cell(streams[n][0], cur[n]) for n in names) + " |")
    per = {}
    for r in rates:
        h = cusum_threshold(r)
        per[r] = {n: loops(s, ev, al, h) for n, (s, ev, al) in streams.items()}
        print(f"| lead, {r:g} per 1,000 (h {h:.1f}) | " + " | ".join(cell(streams[n][0], per[r][n]) for n in names)
              + " |")
    print("\nFalse accepts per 1,000 frames where every accept is false (the knob's honesty):\n")
    fwd = [n for n in names if streams[n][0].forward_only]
    print("| rate | " + " | ".join(fwd) + " |")
    print("|---|" + "---|" * len(fwd))
    for r in rates:
        print(f"| {r:g} | " + " | ".join(f"{1000 * per[r][n]['false'] / len(streams[n][0]):.1f}" for n in fwd) + " |")
    print("\nPer-frame evidence (nats) of frames whose best earlier frame is right / wrong / with no loop:\n")
    print("| stream | right: median, 90 % | wrong | no loop |")
    print("|---|---|---|---|")
    r0 = rates[0]
    for n in REVISITS:
        s = streams[n][0]
        e, best = per[r0][n]["evidence"], per[r0][n]["best"]
        lab = np.array(["none" if not s.hard[:, j].any() else "right" if best[j] >= 0 and
                        (s.hard[best[j], j] or s.soft[best[j], j]) else "wrong" for j in range(len(s))])
        cells = [f"{np.median(e[lab == k]):.2f}, {np.quantile(e[lab == k], 0.9):.2f}" if (lab == k).any() else "-"
                 for k in ("right", "wrong", "none")]
        print(f"| {n} | " + " | ".join(cells) + " |")
    print("\nLocalisation (vpr localize's columns, default preset): precision, recall of accepted answers:\n")
    lcache = Path("results/localize_decisions")
    lcache.mkdir(parents=True, exist_ok=True)
    print("| rule | " + " | ".join(LOC_CASES) + " |")
    print("|---|" + "---|" * len(LOC_CASES))
    for label, h in [("current PathConf", None), *[(f"lead, {r:g} per 1,000", cusum_threshold(r)) for r in rates]]:
        cells = []
        for c in LOC_CASES:
            p, rec, acc, wrong = localise(c, data, lcache, h)
            cells.append(f"P {p:.3f}, R {rec:.2f} ({wrong} wrong)")
        print(f"| {label} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
