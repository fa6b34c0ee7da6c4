"""Where a beam pass spends its time, phase by phase: milliseconds per query frame of each phase of the kernel.

Data: direct SDRs, ``vpr.simulate.aliased_traverses(n, n // 10, k=200)`` (200
of 2,048 bits, the density of the ``fast`` preset's pixel SDRs), or with
``--folders DIR`` the ``fast`` preset's SDRs of ``make_large_folders.py``'s
``DIR/db`` and ``DIR/query`` (encoded here; ``--cache`` keeps the encoding).
The database is learned, then the forward pass of rshosm-seq's default conf
runs the first ``--warm`` query frames as ``vpr`` runs it
(:func:`vpr.shosm.kernels.beam.beam_frames`), and the next ``--frames``
frames twice from that state: phase by phase (each phase of the kernel called
alone from Python and timed: enter by overlap, enter by prediction, new
evidence, carry floor, carry and output) and by the kernel
itself. Prints the median and 90th percentile ms per frame of each phase, its
share of their sum, the kernel's own ms per frame over the same frames, and
whether both gave the same columns.

    python research/benchmarks/bench_beam_phases.py [--sizes 20000,50000] [--folders DIR] [--warm 2000] [--frames 500]
"""
from __future__ import annotations

import argparse
import resource
import time

PHASES = ("enter by overlap", "enter by prediction", "new evidence", "carry floor", "carry and output")


def _sdrs(n: int, folders: str | None, cache: str | None):
    if folders is None:
        from vpr import simulate

        db, q = simulate.aliased_traverses(n, n // 10, k=200, seed=0)[:2]
        return db, q
    import encoders
    from pipelines.extract import extract
    from vpr import presets
    from vpr.sources import open_source

    s = presets.resolve("fast")
    out = []
    for side in ("db", "query"):
        src = open_source(f"{folders}/{side}")
        if len(src.names()) > n:  # the whole folder keeps the key of a cache vpr compare wrote
            src = open_source(f"{folders}/{side}", max_frames=n)
        enc = encoders.get(s["encoder"], **s["encoder_conf"])
        out.append(extract(src, enc, inputs=("sdr",), cache_dir=cache, progress=False).features.sdr)
    return out[0], out[1]


def _profile(g, conf, q, warm: int, frames: int) -> dict:
    import numpy as np

    from vpr.shosm.evidence import beam_params
    from vpr.shosm.graph import Beam
    from vpr.shosm.kernels import beam as KB

    params = beam_params(conf.evidence, conf.beam, 0.5)
    q_ptr, q_ind = q.indptr.astype(np.int64), q.indices.astype(np.int64)
    order = np.arange(warm + frames, dtype=np.int64)
    beams = [Beam(g), Beam(g)]
    for b in beams:
        b.run(g, g.fwd, q_ptr, q_ind, order[:warm], params)
    # the kernel itself over the measured frames
    t0 = time.perf_counter()
    ref = beams[0].run(g, g.fwd, q_ptr, q_ind, order[warm:], params)
    kernel_ms = (time.perf_counter() - t0) * 1e3 / frames
    b = beams[1]
    ff = (g.bit_cols, g.bit_len, g.col_size, g.col_ptr)
    lateral = (g.fwd[0], g.fwd[1], g.fwd[2], g.fwd[3] if len(g.fwd) == 4 else np.zeros(0, np.int32))
    if lateral[3].size and b.gmax.size < lateral[0].size:
        b.gmax, b.gmark, b.gtouch = (np.zeros(lateral[0].size), np.zeros(lateral[0].size, bool),
                                     np.zeros(lateral[0].size, np.int64))
    cells = (g.c_head, g.c_next, g.c_frame, g.r_col, g.db_norm)
    state = (b.st, b.beam, b.beam_e, b.in_beam)
    times = np.zeros((frames, len(PHASES)))
    cols = []
    for k, t in enumerate(order[warm:]):
        scratch = (b.counts, b.touched_cols, b.p1, b.p2, b.z, b.slot, b.cand, b.e_new, b.gmax, b.gmark, b.gtouch,
                   b.acc, b.db_mark, b.db_touch)
        bits = q_ind[q_ptr[t]:q_ptr[t + 1]]
        c = [time.perf_counter()]
        n_tc, n_c = KB.enter_by_overlap(bits, ff, params, scratch)
        c.append(time.perf_counter())
        n_c = KB.enter_by_prediction(n_c, lateral, params, state, scratch)
        c.append(time.perf_counter())
        thr = KB.new_evidence(n_c, ff, cells, params, state, scratch)
        c.append(time.perf_counter())
        keep = KB.carry_floor(n_c, thr, params[7], scratch)
        c.append(time.perf_counter())
        if g.n_db > b.out_idx.size:
            b.out_idx, b.out_val = np.zeros(g.n_db, np.int64), np.zeros(g.n_db)
        out_ptr = np.zeros(2, np.int64)
        b.st[KB.B_OUT_POS] = 0
        KB.carry_and_output(0, n_c, n_tc, thr, keep, params[3], cells, state, scratch,
                             (out_ptr, b.out_idx, b.out_val))
        c.append(time.perf_counter())
        times[k] = np.diff(c) * 1e3
        cols.append((b.out_idx[:out_ptr[1]].copy(), b.out_val[:out_ptr[1]].copy()))
    same = all(np.array_equal(ref[1][ref[0][k]:ref[0][k + 1]], i) and
               np.array_equal(ref[2][ref[0][k]:ref[0][k + 1]], v) for k, (i, v) in enumerate(cols))
    return {"times": times, "kernel_ms": kernel_ms, "same": same, "beam": b.largest}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="20000,50000")
    ap.add_argument("--folders", default=None, help="make_large_folders.py output (DIR/db, DIR/query)")
    ap.add_argument("--cache", default=None, help="encoding cache folder (with --folders)")
    ap.add_argument("--warm", type=int, default=2000, help="query frames run before the measured ones")
    ap.add_argument("--frames", type=int, default=500, help="query frames measured")
    a = ap.parse_args(argv)
    import warnings

    import numpy as np

    from vpr.shosm import Localizer, RshosmSeqConf
    from vpr.shosm.graph import Graph

    warnings.simplefilter("ignore", UserWarning)  # the folders' repeated SDRs are what they are built for
    conf = RshosmSeqConf.build({})
    print(f"{'folders ' + a.folders if a.folders else 'direct SDRs (aliased_traverses, k=200)'}; forward pass, "
          f"query frames {a.warm:,} .. {a.warm + a.frames - 1:,}; ms per frame, median / 90th percentile\n")
    print("| database frames | learn s | " + " | ".join(PHASES) + " | sum of medians | the kernel itself | "
          "largest beam / candidates | same columns |")
    print("|---:|---:|" + "---|" * len(PHASES) + "---:|---:|---|---|")
    for n in [int(x) for x in a.sizes.split(",")]:
        db, q = _sdrs(n, a.folders, a.cache)
        t0 = time.perf_counter()
        loc = Localizer.from_database(db, [str(i) for i in range(db.shape[0])], conf=conf)
        learn = time.perf_counter() - t0
        g = Graph.of(loc.memory, loc.db_codes)
        r = _profile(g, conf, q, a.warm, a.frames)
        med = np.median(r["times"], axis=0)
        p90 = np.percentile(r["times"], 90, axis=0)
        cells = [f"{m:.2f} / {p:.2f} ({m / med.sum():.0%})" for m, p in zip(med, p90, strict=True)]
        print(f"| {db.shape[0]:,} | {learn:.1f} | " + " | ".join(cells) + f" | {med.sum():.2f} | "
              f"{r['kernel_ms']:.2f} | {r['beam'][0]:,} / {r['beam'][1]:,} | {'yes' if r['same'] else 'NO'} |",
              flush=True)
    print(f"\npeak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
