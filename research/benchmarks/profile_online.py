"""Where an online loop-closure frame's time goes, stage by stage and kernel phase by phase, and the machine's limit.

The stream: N frames, then their N revisits. ``--source images``: ``make_large_folders.py``'s 64 x 32 frames
(``DIR/db`` then ``DIR/query``), encoded one at a time as ``vpr loops -`` encodes them (the ``fast`` preset's loop
encoder, causal standardisation); ``--source sdr``: ``vpr.simulate.aliased_traverses`` SDRs (200 of 2,048 bits),
the second traverse with 35 % of its bits moved. :class:`vpr.shosm.LoopStream` steps each frame as ``vpr loops -``
does, its stages timed apart: encoding, Algorithm 1 learning the frame (``learn``), the evidence graph taking it in
(``attach``), the evidence over the earlier frames (``evidence``, reading the memory's overlap count of the frame)
and the decision with its confirmation (``decide``). At ``--phase-at`` frames the evidence kernel's phases are
timed alone (counting the overlaps itself) on a copy of its state over the next ``--phase-frames`` frames (the
phases of :func:`vpr.shosm.kernels.stream.stream_step`), with what each touches: the feed-forward postings read, the
cells, the blocks' entries, the beam, the codes' entries and the frames written. The machine's own limits are
measured here too: memory bandwidth (a large copy) and the rate of random reads from an array of the graph's size,
so that each phase's bytes and reads can be held against them.

    python research/benchmarks/profile_online.py --n 5000 --checkpoints 2000,5000,9500 [--source images|sdr]
"""
from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np

STAGES = ("encode", "learn", "attach", "evidence", "decide")
PHASES = ("feed-forward", "prediction", "new evidence and beam", "output")


def machine_limits() -> dict:
    """Copy bandwidth (GB/s, 256 MB) and random 4-byte reads per microsecond from a 64 MB array (one core)."""
    from numba import njit

    @njit(cache=False)
    def gather(a, idx):  # pragma: no cover - compiled
        s = 0
        for i in idx:
            s += a[i]
        return s

    big = np.ones(2 ** 25, np.float64)
    dst = np.ones_like(big)  # pages mapped before the clock starts
    t = time.perf_counter()
    for _ in range(3):
        np.copyto(dst, big)
    bw = 3 * 2 * big.nbytes / (time.perf_counter() - t) / 1e9
    a = np.ones(2 ** 24, np.int32)
    idx = np.random.default_rng(0).integers(0, a.size, 2 ** 22)
    gather(a, idx[:10])
    t = time.perf_counter()
    gather(a, idx)
    reads = idx.size / (time.perf_counter() - t) / 1e6
    seq = np.arange(idx.size) % a.size
    t = time.perf_counter()
    gather(a, seq)
    seq_reads = idx.size / (time.perf_counter() - t) / 1e6
    return {"copy_gb_s": bw, "random_reads_per_us": reads, "sequential_reads_per_us": seq_reads}


def image_stream(n: int, data: Path):
    """(frames' images one by one, first revisit frame): ``make_large_folders.py``'s folders."""
    import sys

    import cv2

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from make_large_folders import write_folders

    write_folders(data, n)
    paths = [data / "db" / f"{i:06d}.png" for i in range(n)] + [data / "query" / f"{i:06d}.png" for i in range(n)]
    return (cv2.imread(str(p)) for p in paths), n


def sdr_stream(n: int):
    import scipy.sparse as sp

    from vpr import simulate

    places = n
    while True:  # the query's length varies with its speed: enough places for n frames
        db, q = simulate.aliased_traverses(places, max(places // 10, 1), k=200, seed=0)[:2]
        if q.shape[0] >= n:
            break
        places = int(places * 1.05) + 1
    x = sp.vstack([db[:n], q[:n]]).tocsr()
    return (x.indices[x.indptr[j]:x.indptr[j + 1]].astype(np.int64) for j in range(x.shape[0])), n


def phase_profile(stream, bits_ahead: list, n: int) -> dict:
    """The evidence kernel's phases alone (:mod:`vpr.shosm.kernels.stream`), on a copy of the stream's evidence,
    over the frames ``bits_ahead`` against the candidates ``0 .. n - 1``; with what each touches."""
    from vpr.shosm.kernels import stream as KS

    g, eng = stream.graph, stream.engine
    e_beam = eng.e_beam.copy()
    params = eng._params[False]
    ff, cells, blocks, codes = g.kernel_args()
    n_r = g.learned_by(n - 1)
    scratch = (eng.counts, eng.touched, eng.p1, eng.p2, eng.z, eng.e_new, eng.cand)
    times, touched = [], []
    for bits in bits_ahead:
        c = [time.perf_counter()]
        KS.feed_forward(bits, -1, n_r, ff, cells, params, e_beam, scratch)
        c.append(time.perf_counter())
        KS.predict(n_r, g.n_blocks, blocks, params, e_beam, scratch)
        c.append(time.perf_counter())
        thr = KS.new_beam(n_r, params, e_beam, scratch)
        c.append(time.perf_counter())
        m = KS.output(n_r, n, thr, codes, params, scratch, eng.out_idx, eng.out_val)
        c.append(time.perf_counter())
        times.append(np.diff(c) * 1e3)
        touched.append((int(g.bit_len[bits].sum()), n_r, int(g.s_ptr[g.n_blocks] + g.d_ptr[g.n_blocks]
                                                              + 2 * g.p_ptr[g.n_blocks]),
                        int((e_beam[:n_r] > 0).sum()), int(g.code_ptr[n]), m))
    t = np.array(times)
    k = np.median(np.array(touched, np.float64), axis=0)
    med = np.median(t, axis=0)
    return {"median_ms": dict(zip(PHASES, med.round(3).tolist(), strict=True)),
            "postings": k[0], "cells": k[1], "block_entries": k[2], "beam": k[3], "code_entries": k[4],
            "frames_written": k[5]}


def run(n: int, source: str, checkpoints: list[int], data: Path, window: int) -> tuple:
    import encoders
    from pipelines.stream import StreamEncoder
    from vpr import presets
    from vpr.shosm import LoopStream, RshosmSeqConf
    from vpr.similarity import n_candidates

    if source == "images":
        frames, first = image_stream(n, data)
        s = presets.resolve("fast", loops=True)
        enc = StreamEncoder(encoders.get(s["encoder"], **s["encoder_conf"]))
    else:
        frames, first = sdr_stream(n)
        enc = None
    stream = LoopStream(30, RshosmSeqConf.build({}))
    total = 2 * n
    parts = np.zeros((total, len(STAGES)))
    out = {"n": n, "source": source, "checkpoints": {c: {} for c in checkpoints}}
    feed = iter(frames)
    ready: list = []
    for j in range(total):
        t0 = time.perf_counter()
        if enc is not None:
            while not ready:
                img = next(feed, None)
                x = enc.push(img) if img is not None else enc.flush()
                ready = [x.indices[x.indptr[r]:x.indptr[r + 1]] for r in range(x.shape[0])]
            bits = np.asarray(ready.pop(0), np.int64)
        else:
            bits = next(feed)
        t1 = time.perf_counter()
        old_len, ne_old = stream.mem.view(sizes=False).bit_len.copy(), stream.mem.n_connections
        winners = stream.mem.step(bits, keep_overlaps=True)  # as LoopStream.step: the count read by the evidence
        t2 = time.perf_counter()
        stream.graph.attach(bits, winners, old_len, ne_old)
        stream.engine.grow()
        t3 = time.perf_counter()
        column = stream.engine.step(bits, n_candidates(j, stream.exclude, stream.starts[-1]), False, frame=j,
                                    overlaps=stream.mem.overlaps())
        t4 = time.perf_counter()
        stream.decider.add_sdr(bits)
        if stream.decider.rows is None:
            stream._rows.append(bits)
        stream.frames += 1
        d = stream.decider.decide(column)
        stream._final(stream.confirmation.push(d, stream.rows, stream.decider.pair_verified))
        t5 = time.perf_counter()
        parts[j] = np.diff([t0, t1, t2, t3, t4, t5]) * 1e3
    for c in checkpoints:
        lo = max(0, c - window)
        out["checkpoints"][c]["stages"] = dict(zip(STAGES, np.median(parts[lo:c], axis=0).round(3).tolist(),
                                                   strict=True))
    return out, parts, stream


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=5000)
    ap.add_argument("--source", choices=("images", "sdr"), default="images")
    ap.add_argument("--checkpoints", default=None, help="frames at which the stages' medians (over the window before "
                    "them) are printed (default: every 1,000 and the end)")
    ap.add_argument("--window", type=int, default=500)
    ap.add_argument("--phase-at", default=None, help="frames at which the kernel's phases are profiled (on a copy "
                    "of the state at the end of the run is not possible: a second run stops there)")
    ap.add_argument("--phase-frames", type=int, default=100)
    ap.add_argument("--data", default=None)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    data = Path(args.data or f"/tmp/vpr-large-{args.n}")
    total = 2 * args.n
    checkpoints = sorted({int(c) for c in args.checkpoints.split(",")} if args.checkpoints else
                         set(range(1000, total, 1000)) | {total})
    print(f"machine: {json.dumps({k: round(v, 1) for k, v in machine_limits().items()})}", flush=True)
    out, parts, stream = run(args.n, args.source, checkpoints, data, args.window)
    print(f"{args.source}, {args.n:,} frames then their {args.n:,} revisits; ms per frame, median over the "
          f"{args.window} frames before each checkpoint")
    print("| frames | " + " | ".join(STAGES) + " | sum |")
    print("|---:|" + "---:|" * (len(STAGES) + 1))
    for c in checkpoints:
        st = out["checkpoints"][c]["stages"]
        print(f"| {c:,} | " + " | ".join(f"{st[k]:.2f}" for k in STAGES) + f" | {sum(st.values()):.2f} |")
    if args.phase_at:
        for c in [int(v) for v in args.phase_at.split(",")]:
            print(f"\nphases at {c:,} (run again to there):", flush=True)
            r = phase_at(args, c, data)
            print(json.dumps(r))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))


def phase_at(args, c: int, data: Path) -> dict:
    """Run the stream to frame ``c`` (stages untimed), then time the kernel's phases over the next frames."""
    from vpr.shosm import LoopStream, RshosmSeqConf
    from vpr.similarity import n_candidates

    if args.source == "images":
        import encoders
        from pipelines.stream import StreamEncoder
        from vpr import presets

        frames, _ = image_stream(args.n, data)
        s = presets.resolve("fast", loops=True)
        enc = StreamEncoder(encoders.get(s["encoder"], **s["encoder_conf"]))
        rows = []
        for img in frames:
            x = enc.push(img)
            rows += [x.indices[x.indptr[r]:x.indptr[r + 1]].astype(np.int64) for r in range(x.shape[0])]
            if len(rows) >= c + args.phase_frames:
                break
    else:
        frames, _ = sdr_stream(args.n)
        rows = [b for _, b in zip(range(c + args.phase_frames), frames, strict=False)]
    stream = LoopStream(30, RshosmSeqConf.build({}))
    for bits in rows[:c]:
        stream.step(bits)
    # the phases read the graph as it stands at frame c (the next frames are not learned: the graph stays)
    return phase_profile(stream, rows[c:c + args.phase_frames], n_candidates(c, stream.exclude, 0))


if __name__ == "__main__":
    main()
