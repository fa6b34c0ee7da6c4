"""Where an online loop-closure frame's time goes: the memory, the graph, the evidence, the decision, per frame.

Renders ``loop_revisits`` (64x48, ``--frames`` frames, three laps), encodes it
with the ``fast`` preset's encoder, then runs :class:`vpr.shosm.LoopStream`'s
step by hand, timing each part of every frame: Algorithm 1 learning the frame
(``mem``), the evidence graph taking it in (``attach``, ``grow``), the beam's
evidence over the earlier frames (``engine``) and the decision (``decide``).
Prints the median and 99th percentile (ms) over the last 500 frames, uncapped (as ``vpr`` runs it) and with the
beam's caps from the start.

    python research/benchmarks/bench_loop_step.py [--frames 2000,5000]
"""
from __future__ import annotations

import argparse
import time
import warnings


def _run(n: int, caps) -> dict:
    import numpy as np

    import encoders
    from vpr import presets
    from vpr.render import render_scene
    from vpr.shosm import RshosmSeqConf
    from vpr.shosm.loops import LoopStream, n_candidates

    images = render_scene("loop_revisits", size=(64, 48), n_frames=n).traverses[0].images
    s = presets.resolve("fast")
    x = encoders.get(s["encoder"], **s["encoder_conf"]).fit(images).encode(images)
    stream = LoopStream(30, RshosmSeqConf.build(s["method_conf"].get("rshosm-seq", {})), caps=caps)
    parts = {k: [] for k in ("mem", "attach", "grow", "engine", "decide")}
    for j in range(x.shape[0]):
        bits = x.indices[x.indptr[j]:x.indptr[j + 1]].astype(np.int64)
        t = [time.perf_counter()]
        old_len, ne_old = stream.mem.view().bit_len.copy(), stream.mem.n_connections
        winners = stream.mem.step(bits)
        t.append(time.perf_counter())
        stream.graph.attach(bits, winners, old_len, ne_old)
        t.append(time.perf_counter())
        stream.engine.grow()
        t.append(time.perf_counter())
        column = stream.engine.step(bits, n_candidates(j, stream.exclude, stream.starts[-1]), caps, frame=j)
        t.append(time.perf_counter())
        stream.decider.add_sdr(bits)
        stream.frames += 1
        stream.decider.decide(column)
        t.append(time.perf_counter())
        for k, a, b in zip(parts, t[:-1], t[1:], strict=True):
            parts[k].append((b - a) * 1e3)
    last = slice(max(0, n - 500), n)
    out = {k: (float(np.median(v[last])), float(np.percentile(v[last], 99))) for k, v in parts.items()}
    out["columns per input bit"] = float(np.mean(stream.mem.view().bit_len))
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", default="2000,5000")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    print("| frames | caps | mem | attach | grow | engine | decide | minicolumns per input bit |")
    print("|---:|---|---|---|---|---|---|---:|")
    for n in [int(v) for v in args.frames.split(",")]:
        for caps in (False, True):
            r = _run(n, caps)
            cells = " | ".join(f"{r[k][0]:.2f} / {r[k][1]:.2f}" for k in ("mem", "attach", "grow", "engine", "decide"))
            print(f"| {n:,} | {'from the start' if caps else 'none'} | {cells} | "
                  f"{r['columns per input bit']:.0f} |")
    print("(ms per frame, median / 99th percentile over the last 500 frames; encoding not included)")


if __name__ == "__main__":
    main()
