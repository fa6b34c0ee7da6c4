"""One large rshosm-seq match split across Dask workers: serial against 1 and 2 workers.

Data: the frame-aligned folders of ``make_large_folders.py`` encoded with the
``fast`` preset's pixel SDRs, shared with ``bench_scale_images.py`` (same
``--data``, written and encoded once); ``--frames n`` takes the first n frames
of each folder. The map is learned once in this process (``Method.fit``, timed
apart); then the query is matched three ways, each on the same learned map:

* serial: ``Fitted.match`` in this process (what ``vpr match`` does without
  ``--workers``);
* ``pipelines.cluster.split_match`` on an embedded local cluster of 1 worker and
  of 2 workers (what ``vpr match MAP QUERY --workers N`` does): wall time from
  sending the map to the decided result, the cluster's start apart.

Printed: wall seconds, the speed-up of 2 workers over serial and over 1 worker
(ratios of one run), blocks and margin, the bytes of the map (sent once) and of
the largest task, R@1 (best match within 2 frames) and whether the split
answers equal the serial ones (best matches, decisions; largest similarity and
score difference). Every process single-threaded (NUMBA / BLAS threads = 1).

Usage: python research/benchmarks/bench_split.py [--data DIR] [--frames 20000] [--workers 1,2] [--repeats 1]
"""
from __future__ import annotations

import os

for _var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # before NumPy / numba load, and inherited by the local cluster's workers

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402

TOLERANCE = 2  # frames: the folders are frame-aligned


def _dense(S):
    return S.toarray() if sp.issparse(S) else np.asarray(S)


def compare(whole, split) -> str:
    same_best = np.mean(whole.best == split.best)
    same_acc = np.mean(whole.accepted == split.accepted)
    d_sim = (abs(whole.similarity - split.similarity).max() if sp.issparse(whole.similarity)
             else np.abs(_dense(whole.similarity) - _dense(split.similarity)).max())
    fin = np.isfinite(whole.score) & np.isfinite(split.score)
    d_score = np.abs(whole.score[fin] - split.score[fin]).max() if fin.any() else 0.0
    return (f"same best {100 * same_best:.2f} %, same decision {100 * same_acc:.2f} %, "
            f"largest difference: similarity {d_sim:.1e}, score {d_score:.1e}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(Path(tempfile.gettempdir()) / "vpr_bench_scale_images"))
    ap.add_argument("--frames", type=int, default=20_000)
    ap.add_argument("--workers", default="1,2", help="local cluster sizes to run (comma-separated)")
    ap.add_argument("--repeats", type=int, default=1, help="runs of each way (min / median / max printed)")
    a = ap.parse_args(argv)
    sizes = [int(w) for w in a.workers.split(",") if w]
    from bench_scale_images import encode, sdr_path  # beside this script
    from make_large_folders import write_folders

    from pipelines.cluster import dask_client, split_match
    from vpr import methods
    from vpr.types import EncodedTraverse

    data = Path(a.data)
    t = time.perf_counter()
    n_all = max(a.frames, 50_000)
    write_folders(data / "frames", n_all)
    secs = encode(data, "fast", n_all)
    print(f"folders and fast SDRs in {data}: {time.perf_counter() - t:.0f} s ({'encoded' if secs else 'cached'}); "
          f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    n = a.frames
    db = sp.load_npz(sdr_path(data, "fast", "db")).tocsr()[:n].astype(bool)
    q = sp.load_npz(sdr_path(data, "fast", "query")).tocsr()[:n].astype(bool)
    names = list(range(n))
    tdb, tq = EncodedTraverse(names=names, sdr=db), EncodedTraverse(names=names, sdr=q)
    m = methods.get("rshosm-seq")
    m.warm_up()  # (above 7,000 x 7,000 frames rshosm-seq takes its sparse top-K path, in the workers too)
    t = time.perf_counter()
    fitted = m.fit(tdb)
    print(f"rshosm-seq, {n:,} x {n:,} frames: learned in {time.perf_counter() - t:.1f} s "
          f"(margin {m.block_margin} frames)", flush=True)
    truth = np.arange(n)

    def timed(fn):
        walls, out = [], None
        for _ in range(a.repeats):
            t0 = time.perf_counter()
            out = fn()
            walls.append(time.perf_counter() - t0)
        return walls, out

    def spread(w):
        return f"{np.min(w):.1f} / {np.median(w):.1f} / {np.max(w):.1f} s (min / median / max of {len(w)})"

    walls, whole = timed(lambda: fitted.match(tq))
    runs = {0: np.median(walls)}
    print(f"serial: {spread(walls)}, R@1 {np.mean(np.abs(whole.best - truth) <= TOLERANCE):.4f}, "
          f"{int(whole.accepted.sum()):,} accepted", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for w in sizes:
            t = time.perf_counter()
            with dask_client(w, None, Path(tmp) / f"scratch{w}") as client:
                started = time.perf_counter() - t
                shipped: dict = {}
                walls, split = timed(lambda: split_match(fitted, tq, client, w, shipped))  # noqa: B023
            runs[w] = np.median(walls)
            print(f"{w} worker(s): {spread(walls)} (cluster started in {started:.1f} s); {shipped['blocks']} blocks "
                  f"of {shipped['block_frames']:,} frames + {shipped['margin']} each side; map {shipped['map_bytes']:,}"
                  f" bytes once, largest task {shipped['task_bytes']:,} bytes; time: map pickled "
                  f"{shipped['pickle_seconds']:.1f} s, blocks done at {shipped['blocks_done_seconds']:.1f} s (CPU s "
                  f"per block {', '.join(f'{x:.0f}' for x in shipped['block_cpu_seconds'])}), joined and decided in "
                  f"{shipped['combine_seconds']:.1f} s; R@1 "
                  f"{np.mean(np.abs(split.best - truth) <= TOLERANCE):.4f}; {compare(whole, split)}", flush=True)
    if 2 in runs:
        print(f"speed-up of 2 workers: {runs[0] / runs[2]:.2f} x serial"
              + (f", {runs[1] / runs[2]:.2f} x 1 worker" if 1 in runs else ""))
    print(f"load average at end {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
