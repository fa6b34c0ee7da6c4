"""Loop closure with rSHOSM-seq on long forward-only streams: time, memory and false closures.

The stream is the database traverse of ``vpr.simulate.aliased_traverses(n, n // 10)``:
n places visited once, in order (no place is revisited, so every accepted closure
is false), each showing one of n / 10 random SDRs (40 of 2,048 bits), so every
appearance recurs, identically, at about ten places. This is a worst case of
perceptual aliasing. :func:`vpr.shosm.loop_evidence` is dense and uncapped
up to 10,000 frames (``LOOP_UNCAPPED_MAX``) and top-50 sparse with beam caps
beyond (``vpr loops`` is dense up to 20,000 frames, capped beyond 10,000).

For each size it prints the wall time and peak RSS of ``loop_evidence`` and the
closures :func:`vpr.shosm.accept_loops` accepts for several ``z_min`` x
``confirm`` (the default rule is z_min 6.0, confirm 2).

Usage: python benchmarks/bench_loops_scale.py [--sizes 2000,5000,10000,25000]
"""
from __future__ import annotations

import argparse
import resource
import time

Z_MIN = (6.0, 7.0, 8.0, 10.0)
CONFIRM = (2, 4, 8, 16)


def run(n: int, seed: int = 0) -> None:
    from vpr import simulate
    from vpr.shosm import accept_loops, loop_evidence

    x = simulate.aliased_traverses(n, max(n // 10, 1), seed=seed)[0]
    t = time.perf_counter()
    S, _ = loop_evidence(x, exclude=30, top_k=None if n <= 10_000 else 50)
    sec = time.perf_counter() - t
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # Linux: kB -> GiB
    cells = []
    for z in Z_MIN:
        counts = [int(accept_loops(S, z_min=z, confirm=c, sdr=x)[2].sum()) for c in CONFIRM]
        cells.append("/".join(str(v) for v in counts))
    print(f"| {n:,} | {'dense' if n <= 10_000 else 'top-50'} | {sec:.1f} | {rss:.2f} | " + " | ".join(cells) + " |",
          flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="2000,5000,10000", help="stream lengths, comma-separated")
    a = ap.parse_args(argv)
    sizes = [int(v) for v in a.sizes.split(",")]
    print("| frames | matrix | loop_evidence s | peak RSS GiB (so far) | "
          + " | ".join(f"false closures at z_min {z}, confirm {'/'.join(map(str, CONFIRM))}" for z in Z_MIN) + " |")
    print("|" + "---|" * (4 + len(Z_MIN)))
    for n in sizes:
        run(n)


if __name__ == "__main__":
    main()
