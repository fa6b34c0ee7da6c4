"""rSHOSM-seq's two evidence passes on one thread and on two: wall seconds, the ratio, and the answers compared.

Data: ``vpr.simulate.aliased_traverses(n, n // 10)`` (as ``bench_scale.py``).
The database is learned once per size; then :meth:`vpr.shosm.Engine.run`
(direction ``both``, the default conf and beam) runs ``--repeats`` times with
``threads=1`` and ``threads=2`` alternately, paired. Prints min / median / max
wall seconds of each, the median ratio, the peak RSS of the process, and
whether the two give the same similarity (entries and values) and best matches.

    python research/benchmarks/bench_passes.py [--sizes 5000,10000,20000] [--repeats 3]
"""
from __future__ import annotations

import argparse
import resource
import statistics
import time


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="5000,10000,20000")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    import numpy as np

    from vpr import simulate
    from vpr.shosm import Localizer, RshosmSeqConf
    from vpr.shosm.evidence import Engine
    from vpr.shosm.graph import Graph

    print("| frames | 1 thread s (min / median / max) | 2 threads s (min / median / max) | median ratio "
          "| same answers |")
    print("|---:|---|---|---:|---|")
    for n in [int(x) for x in args.sizes.split(",")]:
        db, q, _ = simulate.aliased_traverses(n, n // 10, seed=0)[:3]
        conf = RshosmSeqConf.build({})
        loc = Localizer.from_database(db, [str(i) for i in range(db.shape[0])], conf=conf)
        g = Graph.of(loc.memory, loc.db_codes, backward=True)
        secs = {1: [], 2: []}
        out = {}
        for _ in range(args.repeats):
            for t in (1, 2):
                e = Engine(g, conf.evidence, conf.beam, threads=t)
                t0 = time.perf_counter()
                out[t] = e.run(q, "both")
                secs[t].append(time.perf_counter() - t0)
        a, b = out[1], out[2]
        same = (a.similarity != b.similarity).nnz == 0 and np.array_equal(a.best, b.best)
        ratio = statistics.median(secs[1]) / statistics.median(secs[2])
        cells = [f"{min(s):.2f} / {statistics.median(s):.2f} / {max(s):.2f}" for s in (secs[1], secs[2])]
        print(f"| {n:,} | {cells[0]} | {cells[1]} | {ratio:.2f} | {'yes' if same else 'NO'} |")
    print(f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
