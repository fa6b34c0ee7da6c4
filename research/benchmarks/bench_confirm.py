"""What confirming a loop closure costs a frame, by the number of earlier frames (candidates).

While a closure waits (:class:`vpr.shosm.Confirmation`), every frame is scored against all its candidates by SDR
overlap alone, standardised (``row``: :func:`vpr.shosm.confirm.standardised_overlaps` through the blocks of
columns, built beforehand), and each closure, once its frames are seen, gets the look-ahead over them
(``look_ahead``: :func:`vpr.shosm.confirm.look_ahead_z`, :func:`~vpr.shosm.confirm.ahead_scores` over
``confirm_frames`` rows then the z over the other places; ``ahead_scores`` and the ``concatenate`` of its rows
apart). Random SDRs of 200 bits in 2,048 (the default loop encoder's density);
milliseconds per call, min / median / max over ``--repeats`` rounds of 20 calls each.

    python research/benchmarks/bench_confirm.py [--candidates 10000,50000] [--repeats 5]
"""
from __future__ import annotations

import argparse
import time

import numpy as np


def _ms(fn, calls: int, repeats: int) -> tuple[float, float, float]:
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        for k in range(calls):
            fn(k)
        out.append((time.perf_counter() - t) / calls * 1e3)
    return float(np.min(out)), float(np.median(out)), float(np.max(out))


def _one(n: int, frames: int, calls: int, repeats: int) -> list:
    """(row, look_ahead, ahead_scores, concatenate) timings at ``n`` candidates."""
    from vpr import sdr as _sdr
    from vpr.shosm.confirm import Columns, ahead_scores, look_ahead_z, standardised_overlaps

    x = _sdr.random_sdrs(n + calls + frames, 2048, 200, seed=0)
    x.sort_indices()
    ptr, ind = x.indptr.astype(np.int64), x.indices.astype(np.int64)
    blocks = Columns(2048).extend(ptr, ind, n)  # built once, as the stream grows

    def overlaps(q):
        return standardised_overlaps(ptr, ind, q, n, 2048, blocks)

    z = [overlaps(q) for q in range(n, n + frames)]
    return [_ms(lambda k: overlaps(n + k), calls, repeats),
            _ms(lambda k: look_ahead_z(z, 100, n, 0.05, 0.05), calls, repeats),
            _ms(lambda k: ahead_scores(z, 0.05, 0.05), calls, repeats),
            _ms(lambda k: np.concatenate(z), calls, repeats)]


def main(argv=None) -> None:
    from vpr.shosm import LoopConf
    from vpr.shosm.confirm import warm_up

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--candidates", default="10000,50000")
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args(argv)
    frames, calls = LoopConf().confirm_frames, 20
    warm_up()
    print(f"ms per call (min / median / max of {a.repeats} rounds of {calls}); confirm_frames {frames}")
    print("| candidates | row | look_ahead | of it ahead_scores | of that concatenate |")
    print("|---|---|---|---|---|")
    for n in (int(v) for v in a.candidates.split(",")):
        cells = [" / ".join(f"{v:.2f}" for v in r) for r in _one(n, frames, calls, a.repeats)]
        print(f"| {n:,} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
