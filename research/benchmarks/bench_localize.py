"""Online localisation: per-frame latency of vpr.Localizer.update.

A database of n frames of ``vpr.simulate.aliased_traverses(n, n // 10)`` is
learned (``vpr.Localizer.from_database``: Algorithm 1, threshold 0.75); then
the query traverse is fed one SDR at a time (encoding excluded). Prints the
learning time and the latency of ``update`` (wall clock,
ms: median / p95 / max over the frames), the causal R@1 within one place, and
the same for ``exact=True`` (dense evidence per frame) up to ``--exact-max``, and for ``follow``: the
:class:`vpr.shosm.SpeedFollower` around the localizer that ``vpr localize`` runs by default (the query here moves
0.8-1.2 places a frame, so its answers are the localizer's; the cost is that of its engines); ``beam2x`` and
``follow2x``: the same with a query moving 1.8-2.2 places a frame (R@1 within one place); ``late``: what ``vpr
localize`` runs, the follower answered ``LOCALIZE_LAG`` frames late (:class:`vpr.shosm.Lagged`; the map's own
choice of dense column or beam; the frame's latency is its ``update``, which answers an earlier frame). ``held
MB``: the arrays the localizer (or the follower, with the engines it built) holds after the query (:func:`held_mb`).

Target: median <= 5 ms at 10,000 database frames.

With ``--nordland DIR`` (the ``nordland_trimmed`` folder) it also prints the
causal R@1 of winter against summer on the 358-frame subset (every 10th file,
pixel encoder k=200, each traverse standardised on its own frames, radius 1),
and the ``update`` latency on real images: the whole summer ride (3,576
frames, the ``fast`` preset's encoder) as the map, every winter frame as a
query (encoding excluded; R@1 within 10 frames, accepted answers' precision).

Usage: python research/benchmarks/bench_localize.py [--sizes 1000,10000,50000] [--frames 2000] [--nordland DIR]
    [--modes beam,follow,beam2x,follow2x,exact,late]
"""
from __future__ import annotations

import argparse
import time

import numpy as np


def held_mb(obj) -> float:
    """MB of the NumPy arrays and SciPy sparse matrices reachable from ``obj`` (its attributes, lists, tuples and
    dicts; each array counted once): what a localizer or a follower holds."""
    import scipy.sparse as sp

    seen, todo, total = set(), [obj], 0
    while todo:
        o = todo.pop()
        if id(o) in seen or o is None or isinstance(o, (str, bytes, int, float, bool)):
            continue
        seen.add(id(o))
        if isinstance(o, np.ndarray):
            total += o.nbytes if o.base is None or id(o.base) not in seen else 0
        elif sp.issparse(o):
            todo += [getattr(o, k) for k in ("data", "indices", "indptr", "row", "col") if hasattr(o, k)]
        elif isinstance(o, dict):
            todo += list(o.values())
        elif isinstance(o, (list, tuple, set)):
            todo += list(o)
        elif hasattr(o, "__dict__") or hasattr(o, "__slots__"):
            todo += list(getattr(o, "__dict__", {}).values())
            todo += [getattr(o, k) for k in getattr(o, "__slots__", ()) if hasattr(o, k)]
    return total / 2**20


def latency(n, frames, exact, seed=0, follow=False, speed=(0.8, 1.2), late=False, parts=None):
    from vpr import simulate
    from vpr.shosm import LOCALIZE_LAG, Lagged, Localizer, SpeedFollower

    db, q, dp, qp = simulate.aliased_traverses(n, max(n // 10, 1), seed=seed, speed=speed)
    t = time.perf_counter()
    base = Localizer.from_database(db, [str(i) for i in range(n)], exact=exact, seed=seed)
    # what `vpr localize` runs by default: the localizer and the engines that follow another speed
    loc = SpeedFollower(base, db) if follow else base
    if late:  # and each frame answered LOCALIZE_LAG frames late
        loc = Lagged(base, loc, lag=LOCALIZE_LAG)
    t_learn = time.perf_counter() - t
    rows = [q.indices[q.indptr[j]:q.indptr[j + 1]] for j in range(min(frames, q.shape[0]))]
    loc.warm_up()  # compile / load the kernels
    if late and parts is not None:  # the two threads of a late update, timed apart
        parts.update(backward=[], own=[])
        backward, own = loc._backward, loc.answering.update

        def timed(f, key):
            def run(*args):
                t = time.perf_counter()
                out = f(*args)
                parts[key].append((time.perf_counter() - t) * 1e3)
                return out
            return run

        loc._backward, loc.answering.update = timed(backward, "backward"), timed(own, "own")
    ms, out = [], []
    for bits in rows:
        t = time.perf_counter()
        o = loc.update(bits)
        ms.append((time.perf_counter() - t) * 1e3)
        out.extend(o if late else [o])
    if late:
        out.extend(loc.flush())
    best = [o.best for o in sorted(out, key=lambda o: o.frame)]
    ms = np.array(ms)
    r1 = np.mean(np.abs(dp[np.maximum(best, 0)] - qp[: len(rows)]) <= 1)
    return ms, r1, t_learn, held_mb(loc)


def nordland(path):
    from pathlib import Path

    import encoders
    from vpr.shosm import Engine, Graph, SequenceMemory
    from vpr.sources import open_source

    enc = encoders.get("pixel", k=200, standardise="fit")
    x = {}
    for season in ("summer", "winter"):
        images = [f.image for f in open_source(Path(path) / season, step=10)]
        x[season] = enc.fit(images).encode(images)
    mem = SequenceMemory(threshold=0.75)
    codes = mem.run(x["summer"])
    mem.reset()
    for exact in (False, True):
        loc = Engine(Graph.of(mem, codes), exact=exact)
        w = x["winter"]
        best = np.array([loc.step(w.indices[w.indptr[j]:w.indptr[j + 1]].astype(np.int64)).best()[0]
                         for j in range(w.shape[0])])
        r1 = np.mean(np.abs(best - np.arange(w.shape[0])) <= 1)
        print(f"Nordland 358 winter vs summer, causal forward evidence ({'exact' if exact else 'beam'}): "
              f"R@1 (radius 1) {r1:.3f}")
    from pipelines.stream import StreamEncoder
    from vpr import presets
    from vpr.shosm import Localizer

    s = presets.resolve("fast")
    enc = encoders.get(s["encoder"], **s["encoder_conf"])
    summer = [f.image for f in open_source(Path(path) / "summer")]
    db = enc.fit(summer).encode(summer)
    loc = Localizer.from_database(db, [str(i) for i in range(db.shape[0])])
    loc.warm_up()
    qenc = StreamEncoder(enc)
    ms, best, acc = [], [], []
    for f in open_source(Path(path) / "winter"):
        x = qenc.encode(f.image)
        t = time.perf_counter()
        r = loc.update(x)
        ms.append((time.perf_counter() - t) * 1e3)
        best.append(r.best)
        acc.append(r.accepted)
    ms, best, acc = np.array(ms), np.array(best), np.array(acc)
    right = np.abs(best - np.arange(best.size)) <= 10
    print(f"Nordland 3,576 winter vs summer, real images (fast preset), Localizer.update: median {np.median(ms):.2f} "
          f"ms, p95 {np.percentile(ms, 95):.2f}, max {ms.max():.1f}; R@1 (10 frames) {right.mean():.3f}; accepted "
          f"{acc.sum()} (precision {right[acc].mean() if acc.any() else float('nan'):.3f})")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="1000,10000,50000")
    ap.add_argument("--frames", type=int, default=2000, help="query frames timed per size")
    ap.add_argument("--exact-max", type=int, default=10000)
    ap.add_argument("--nordland", default=None)
    ap.add_argument("--modes", default="beam,follow,beam2x,follow2x,exact,late",
                    help="late: what `vpr localize` runs, the follower answered LOCALIZE_LAG frames late")
    ap.add_argument("--parts", action="store_true", help="late: also the median ms of its two threads, the due "
                    "frame's backward pass and the newest frame's own steps (the follower's update)")
    a = ap.parse_args(argv)
    print("Localizer.update latency per query frame (ms, encoding excluded), top-50")
    print(f"{'n_db':>7} {'mode':>8} {'frames':>7} {'median':>8} {'p95':>8} {'max':>8} {'R@1':>7} {'learn s':>8} "
          f"{'held MB':>8}")
    for n in (int(s) for s in a.sizes.split(",")):
        for mode in a.modes.split(","):
            if mode == "exact" and n > a.exact_max:
                continue
            exact = None if mode == "late" else mode == "exact"  # late: as `vpr localize`, the map's own choice
            parts: dict = {}
            ms, r1, t_learn, mb = latency(n, a.frames, exact, follow=mode.startswith("follow") or mode == "late",
                                          speed=(1.8, 2.2) if mode.endswith("2x") else (0.8, 1.2),
                                          late=mode == "late", parts=parts if a.parts else None)
            print(f"{n:7d} {mode:>8} {ms.size:7d} {np.median(ms):8.3f} "
                  f"{np.percentile(ms, 95):8.3f} {ms.max():8.3f} {r1:7.3f} {t_learn:8.1f} {mb:8.1f}", flush=True)
            if parts.get("own"):
                print(f"{'':>16} its two threads, median ms: the backward pass {np.median(parts['backward']):.3f}, "
                      f"the newest frame's own steps {np.median(parts['own']):.3f}", flush=True)
    if a.nordland:
        nordland(a.nordland)


if __name__ == "__main__":
    main()
