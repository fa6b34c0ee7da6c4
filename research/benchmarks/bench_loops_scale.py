"""Loop closure on long streams: the online detector's latency and memory, and the batch run at 50,000 frames.

The stream (encoding excluded: SDRs) is the two traverses of
``vpr.simulate.aliased_traverses(P, P / 10, k=200)`` played one after the
other, cut to N frames (P about N / 2): P places driven once, each showing one of P / 10 random SDRs (200 of
2,048 bits, the density of the default loop encoder), so every appearance
recurs at about ten places (perceptual aliasing at its worst: every closure
accepted in the first half is false), then the same route again at a varying
speed with 35 % of every SDR's bits moved (every frame of the second half
revisits a place; a closure is true within 2 places).

Two runs, each in its own process so that each peak RSS is its own:

1. :class:`vpr.LoopDetector`, one ``update`` per frame: the latency of the 200
   updates before each checkpoint (median / p95 / max, ms), the process RSS and
   the detector's saved state there. The beam carries every cell (the evidence over the stream laid out by
   frame, :class:`vpr.shosm.StreamEngine`: a frame's cost grows with the cells learned, in one pass over them).
2. ``vpr.shosm.loop_evidence`` over the whole stream in its top-K form (what
   ``vpr loops`` runs beyond 20,000 frames): time and peak RSS; and whether its
   decisions equal the detector's, frame for frame.

Then the accepted closures of both: false in the first half, true / false in the second.

The update latency includes handing out the decisions that waited for the frames after them (``take_late``).

Usage: python research/benchmarks/bench_loops_scale.py [--frames 50000] [--checkpoints 1000,5000,10000,20000,50000]
       [--confirm-frames N]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

WINDOW = 200


def stream(n: int, seed: int = 0):
    """(SDR batch, place per frame, first frame of the second traverse)."""
    import scipy.sparse as sp

    from vpr import simulate

    places = n // 2
    while True:  # the second traverse's length varies with its speed: enough places for n frames
        db, q, db_place, q_place = simulate.aliased_traverses(places, max(places // 10, 1), k=200, seed=seed)
        if db.shape[0] + q.shape[0] >= n:
            break
        places = int(places * 1.05) + 1
    x = sp.vstack([db, q]).tocsr()[:n]
    return x, np.concatenate([db_place, q_place])[:n], db.shape[0]


def _rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def run_detector(n: int, checkpoints: list[int], out: Path, conf: dict) -> dict:
    from vpr.shosm import LoopDetector

    x, _, _ = stream(n)
    det = LoopDetector(**conf)
    det.warm_up()
    lat = np.zeros(n)
    best, score, acc, waited = np.zeros(n, np.int64), np.zeros(n), np.zeros(n, bool), np.zeros(n, np.int64)
    rows = []
    base = _rss_mb()

    def take(ds, j):
        for r in ds:
            best[r.frame], score[r.frame], acc[r.frame], waited[r.frame] = r.best, r.score, r.accepted, j - r.frame

    for j in range(n):
        bits = x.indices[x.indptr[j]:x.indptr[j + 1]]
        t = time.perf_counter()
        r = det.update(bits)
        late = det.take_late()
        lat[j] = time.perf_counter() - t
        take([*late, *([] if r is None else [r])], j)
        if j + 1 in checkpoints:
            w = lat[j + 1 - WINDOW:j + 1] * 1e3
            with tempfile.TemporaryDirectory() as d:
                det.save(Path(d) / "state.npz")
                state_mb = (Path(d) / "state.npz").stat().st_size / 2**20
            rows.append({"frames": j + 1, "median": float(np.median(w)), "p95": float(np.percentile(w, 95)),
                         "max": float(w.max()), "rss_mb": _rss_mb(), "rss_growth_mb": _rss_mb() - base,
                         "state_mb": state_mb, "memory_mb": det.stream.mem.nbytes / 2**20})
            print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    det.flush()
    take(det.take_late(), n)
    np.savez(out, best=best, score=score, accepted=acc)
    w = waited[acc]
    return {"checkpoints": rows, "seconds": float(lat.sum()), "peak_mb": _peak_mb(),
            "waited": [float(np.median(w)) if w.size else 0.0, int(w.max()) if w.size else 0]}


def run_batch(n: int, out: Path, conf: dict) -> dict:
    from vpr.shosm import loop_evidence

    x, _, _ = stream(n)
    t = time.perf_counter()
    ev = loop_evidence(x, top_k=50, **conf)
    sec = time.perf_counter() - t
    d = ev.decision
    np.savez(out, best=d.best, score=d.score, accepted=d.accepted)
    return {"seconds": sec, "peak_mb": _peak_mb(), "nnz": int(ev.similarity.nnz)}


def _child(args) -> int:
    out = Path(args.out)
    conf = {k: getattr(args, k) for k in ("confirm_frames",) if getattr(args, k) is not None}
    res = run_detector(args.frames, args.cp, out, conf) if args.child == "detector" else \
        run_batch(args.frames, out, conf)
    print(json.dumps(res))
    return 0


def _spawn(kind: str, n: int, checkpoints, out: Path, conf: dict):
    cmd = [sys.executable, __file__, "--child", kind, "--frames", str(n), "--out", str(out),
           "--checkpoints", ",".join(map(str, checkpoints)),
           *[a for k, v in conf.items() if v is not None for a in (f"--{k.replace('_', '-')}", str(v))]]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)


def closures(d, place, half: int) -> tuple[int, int, int]:
    """(false in the first half, true and false in the second) of accepted closures."""
    j = np.flatnonzero(d["accepted"])
    b = d["best"][j]
    first = j < half
    right = np.abs(place[b] - place[j]) <= 2
    return int(first.sum()), int((~first & right).sum()), int((~first & ~right).sum())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=50_000)
    ap.add_argument("--checkpoints", default="1000,5000,10000,20000,50000")
    ap.add_argument("--confirm-frames", type=int, default=None,
                    help="rshosm-seq.confirm_frames (default: its default; 0: closures decided at once)")
    ap.add_argument("--child", choices=("detector", "batch"), help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    a.cp = [int(c) for c in a.checkpoints.split(",") if int(c) <= a.frames]
    if a.child:
        return _child(a)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        conf = {"confirm_frames": a.confirm_frames}
        procs = {k: _spawn(k, a.frames, a.cp, Path(tmp) / f"{k}.npz", conf) for k in ("detector", "batch")}
        res = {k: json.loads(p.communicate()[0].strip().splitlines()[-1]) for k, p in procs.items()}
        wall = time.perf_counter() - t0
        det, bat = (dict(np.load(Path(tmp) / f"{k}.npz")) for k in ("detector", "batch"))
    _, place, half = stream(a.frames)
    print(f"stream: {a.frames:,} frames ({half:,} places driven once, then again); the beam uncapped; both runs "
          f"side by side, {wall:.0f} s wall\n")
    print("| frames seen | update median ms | p95 ms | max ms | process RSS MB | detector state file MB | "
          "memory arrays MB |")
    print("|---|---|---|---|---|---|---|")
    for r in res["detector"]["checkpoints"]:
        print(f"| {r['frames']:,} | {r['median']:.1f} | {r['p95']:.1f} | {r['max']:.1f} | {r['rss_mb']:.0f} | "
              f"{r['state_mb']:.0f} | {r['memory_mb']:.0f} |")
    same = {k: bool(np.array_equal(det[k], bat[k])) for k in ("best", "accepted")}
    same["score"] = bool(np.allclose(det["score"], bat["score"]))
    print("\n| run | seconds | peak RSS MB | accepted: false in the first half | true in the second | false in the "
          "second |")
    print("|---|---|---|---|---|---|")
    for k, label in (("detector", "LoopDetector.update, frame by frame"), ("batch", "loop_evidence, top-50")):
        f1, t2, f2 = closures(det if k == "detector" else bat, place, half)
        print(f"| {label} | {res[k]['seconds']:.0f} | {res[k]['peak_mb']:.0f} | {f1} | {t2} | {f2} |")
    print(f"\nthe same decisions, frame for frame: {same}; an accepted closure answered online "
          f"{res['detector']['waited'][0]:g} frames after it came (median; at most {res['detector']['waited'][1]}: "
          "it waits for the frames that confirm it)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
