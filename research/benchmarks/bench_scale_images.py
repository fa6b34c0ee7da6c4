"""rshosm-seq on image SDRs at 5,000 - 50,000 frames, one core.

Data: the two frame-aligned folders of ``make_large_folders.py`` (written once
into ``--data``, 2 x 50,000 grey 64 x 32 PNG: n / 10 smooth random appearances
each shown at about ten places, the query darker, shifted by up to two pixels
and noisy). Each preset's encoder (``fast``: pixel SDRs, 200 of 2,048 bits;
``default``: the joined pixel + CNN SDRs, 150 + 50 of 1,536 + 512 bits; both
standardised on their traverse) encodes both whole folders once (cached in
``--data``; the encoding time is printed apart), and a size ``n`` is the first
``n`` frames of each.

For each preset and size, in a fresh child process (its peak RSS its own; one
thread: NUMBA / OMP / OPENBLAS / MKL threads = 1), ``rshosm-seq`` with its
default conf, sparse top-50 path at every size (``vpr`` switches to it above
:func:`vpr.similarity.dense_pairs`): CPU seconds of learning the database
(``Method.fit``) and of matching the query (``Fitted.match``) apart, peak RSS,
R@1 (best match within 2 frames, the folders' tolerance). At the ``--agree``
sizes the child also runs the dense evidence on the same memory and prints the
share of queries with the same best match, the dense R@1 and the dense
evidence's CPU seconds (so the sizes where the sparse path becomes the faster
one are measured where both run). At the ``--profile`` sizes it times one
forward pass with the default caps and with tiny caps (what is left is counting
the query's overlap with every minicolumn through the inverted index), and counts
the distinct successor lists of the cells that relay evidence (cells sharing one
could relax it once).

Goals (50,000 x 50,000 image frames, one core): <= 3 min including
learning, <= 3 GB peak, R@1 >= 0.95, the same best match as the dense evidence
for >= 99 % of queries at 10,000 and 20,000 frames, growth exponent <= 1.3.

``--source rendered`` takes the rendered continuous drive of
``make_rendered_drive.py`` instead (a 20 km street, 0.4 m per frame: about
ten frames per place, consecutive frames alike; use ``--tolerance 5``, 2 m,
and a ``--data`` folder of its own).

Usage: python research/benchmarks/bench_scale_images.py [--data DIR] [--presets fast,default]
[--frames 50000] [--sizes 5000,10000,20000,50000] [--agree 2000,5000,10000,20000]
[--profile 5000,10000] [--source random|rendered] [--tolerance 2]
"""
from __future__ import annotations

import os

# one thread everywhere; must precede the NumPy / numba imports
for _var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
from children import child_json  # noqa: E402, I001 (run as a script: its own folder is on the path)

TOLERANCE = 2  # frames: the query folder is frame-aligned with the database folder (--tolerance)


def sdr_path(data: Path, preset: str, which: str) -> Path:
    return data / f"sdr_{preset}_{which}.npz"


def encode(data: Path, preset: str, n: int) -> float:
    """Encode both folders with ``preset``'s encoder into ``data`` (once); the seconds it took (0 if cached)."""
    if all(sdr_path(data, preset, w).is_file() for w in ("db", "query")):
        return 0.0
    import encoders
    from pipelines.extract import extract
    from vpr import presets
    from vpr.sources import open_source

    p = presets.get(preset)
    t = time.perf_counter()
    for which in ("db", "query"):
        enc = encoders.get(p["encoder"], **p["encoder_conf"])
        ex = extract(open_source(data / "frames" / which), enc, progress=False)
        if ex.features.sdr.shape[0] != n:
            raise RuntimeError(f"{which}: {ex.features.sdr.shape[0]} frames encoded, expected {n}")
        sp.save_npz(sdr_path(data, preset, which), ex.features.sdr.tocsr(), compressed=False)
    return time.perf_counter() - t


def peak_rss_mb() -> float:
    """Peak resident memory of this process (VmHWM: unlike ru_maxrss, not inherited from the parent)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def profile(mem, codes, q) -> dict:
    """Where matching time goes: one forward pass with the default caps, and with caps so small (64 cells,
    8 minicolumns) that what is left is counting the overlaps through the inverted index."""
    from vpr.shosm import BeamConf, sparse_evidence

    lateral = mem.connections.lateral
    lists = {lateral.indices[a:b].tobytes() for a, b in zip(lateral.indptr[:-1], lateral.indptr[1:], strict=True)
             if b > a}
    out = {"bit_len": float(mem.view().bit_len.mean()), "columns": int(mem.view().n_columns),
           "sources": int(np.count_nonzero(np.diff(lateral.indptr))), "edges": int(lateral.nnz),
           "lists": len(lists)}
    for key, beam in (("pass_ms", BeamConf()), ("count_ms", BeamConf(max_beam=64, max_enter=8))):
        c = time.process_time()
        sparse_evidence(mem, q, codes, direction="forward", beam=beam)
        out[key] = (time.process_time() - c) / q.shape[0] * 1e3
    return out


def child(data: Path, preset: str, n: int, agree: bool, prof: bool = False, tolerance: int = TOLERANCE) -> None:
    from vpr import methods, similarity
    from vpr.shosm import query_evidence
    from vpr.types import EncodedTraverse

    db = sp.load_npz(sdr_path(data, preset, "db")).tocsr()[:n].astype(bool)
    q = sp.load_npz(sdr_path(data, preset, "query")).tocsr()[:n].astype(bool)
    similarity.DENSE_PAIRS_LIMIT = 0  # the large-input path at every size (the exponent is that path's)
    m = methods.get("rshosm-seq")
    m.warm_up()
    names = list(range(n))
    tdb, tq = EncodedTraverse(names=names, sdr=db), EncodedTraverse(names=names, sdr=q)
    c0 = time.process_time()
    fitted = m.fit(tdb)
    c1 = time.process_time()
    r = fitted.match(tq)
    c2 = time.process_time()
    truth = np.arange(n)
    out = {"preset": preset, "n": n, "bits": int(db.shape[1]), "active": float(db.sum(1).mean()),
           "learn_s": c1 - c0, "match_s": c2 - c1, "r1": float(np.mean(np.abs(r.best - truth) <= tolerance)),
           "sparse": bool(sp.issparse(r.similarity)),
           "peak_rss_mb": peak_rss_mb()}
    if agree:
        mem, codes = fitted.state
        c3 = time.process_time()
        d = query_evidence(mem, q, codes, m.seq.evidence, direction=m.seq.direction, top_k=None)
        out.update(dense_s=time.process_time() - c3, agree=float(np.mean(d.best == r.best)),
                   dense_r1=float(np.mean(np.abs(d.best - truth) <= tolerance)))
    if prof:
        out.update(profile(*fitted.state, q))
    print(json.dumps(out))


def run_child(data: Path, preset: str, n: int, agree: bool, prof: bool = False, tolerance: int = TOLERANCE) -> dict:
    cmd = [sys.executable, __file__, "--child", preset, "--n", str(n), "--data", str(data),
           "--tolerance", str(tolerance)]
    cmd += ["--agree-child"] if agree else []
    return child_json(cmd + (["--profile-child"] if prof else []), f"{preset} at {n} frames")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(Path(tempfile.gettempdir()) / "vpr_bench_scale_images"))
    ap.add_argument("--frames", type=int, default=50_000, help="frames of each folder (>= every size)")
    ap.add_argument("--presets", default="fast,default")
    ap.add_argument("--sizes", default="5000,10000,20000,50000")
    ap.add_argument("--agree", default="2000,5000,10000,20000",
                    help="sizes at which the dense evidence runs too ('' for none)")
    ap.add_argument("--profile", default="", help="sizes at which one forward pass is also profiled: ms per "
                    "frame with the default caps and of counting the overlaps alone")
    ap.add_argument("--source", choices=("random", "rendered"), default="random",
                    help="random: make_large_folders.py's random places; rendered: make_rendered_drive.py's "
                    "continuous drive (about ten frames per place)")
    ap.add_argument("--tolerance", type=int, default=TOLERANCE, help="frames within which a best match is right")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--profile-child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--n", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--agree-child", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    data = Path(a.data)
    if a.child is not None:
        child(data, a.child, a.n, a.agree_child, a.profile_child, a.tolerance)
        return
    from vpr import presets

    sizes = sorted(int(s) for s in a.sizes.split(",") if s)
    agree = {int(s) for s in a.agree.split(",") if s}
    prof = {int(s) for s in a.profile.split(",") if s}
    names = [p for p in a.presets.split(",") if p]
    for p in names:
        presets.get(p)  # refuses an unknown preset before any work
    n_max = a.frames
    if max(sizes + sorted(agree | prof)) > n_max:
        ap.error(f"sizes above --frames {n_max}")
    if a.tolerance < 0:
        ap.error("--tolerance: frames >= 0")
    if a.source == "rendered":
        from make_rendered_drive import write_folders  # beside this script
    else:
        from make_large_folders import write_folders

    t = time.perf_counter()
    written = write_folders(data / "frames", n_max)
    print(f"folders: 2 x {n_max} frames in {data / 'frames'} ({'written' if written else 'reused'}, "
          f"{time.perf_counter() - t:.0f} s); load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}",
          flush=True)
    print(f"{'preset':>8} {'n':>6} {'bits':>10} {'learn s':>8} {'match s':>8} {'total s':>8} {'peak MB':>8} "
          f"{'R@1':>6} {'dense s':>8} {'dense R@1':>9} {'same best':>9}", flush=True)
    for p in names:
        secs = encode(data, p, n_max)
        print(f"{p:>8} encoding 2 x {n_max} frames: {f'{secs:.0f} s' if secs else 'cached'}", flush=True)
        totals = {}
        for n in sorted(set(sizes) | agree | prof):
            r = run_child(data, p, n, n in agree, n in prof, a.tolerance)
            total = r["learn_s"] + r["match_s"]
            if n in sizes:
                totals[n] = total
            dense = (f"{r['dense_s']:8.1f} {r['dense_r1']:9.4f} {100 * r['agree']:8.2f}%" if "agree" in r
                     else f"{'-':>8} {'-':>9} {'-':>9}")
            print(f"{p:>8} {n:6d} {r['bits']:5d}/{r['active']:<4.0f} {r['learn_s']:8.1f} {r['match_s']:8.1f} "
                  f"{total:8.1f} {r['peak_rss_mb']:8.0f} {r['r1']:6.4f} {dense}", flush=True)
            if "pass_ms" in r:
                print(f"{p:>8} {n:6d} profile, one forward pass: {r['pass_ms']:.2f} ms per frame, of which counting "
                      f"the overlaps {r['count_ms']:.2f} ms ({r['columns']} minicolumns, {r['bit_len']:.0f} per input "
                      f"bit); {r['sources']} cells relay evidence along {r['edges']} connections, with "
                      f"{r['lists']} distinct successor lists", flush=True)
        if len(totals) >= 2:
            x, y = np.log(list(totals)), np.log(list(totals.values()))
            print(f"{p:>8} growth exponent of learn + match CPU s {min(totals)} -> {max(totals)} frames: "
                  f"{np.polyfit(x, y, 1)[0]:.2f}", flush=True)
    print(f"load average at end {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
