"""Cost per frame of the presets: encode + match on two rendered 1,000-frame traverses.

For each preset of :mod:`vpr.presets` (``default`` and ``fast`` unless ``--presets``
says otherwise) the rendered ``two_seasons`` database and query traverses
(1,000 frames each, 160x120 by default) are encoded as ``vpr compare`` does it
(the encoder's dense descriptor, per-traverse fit, the SDRs, and SeqSLAM's
64x32 pixels when a method needs them), then every method of the preset is
matched. Printed: min / median / max over the repeats of

- encode: milliseconds per frame (both traverses' frames counted),
- each method: milliseconds per query frame,
- total: (encoding both traverses + every method) per query frame.

One thread (the CNN's onnxruntime session is single-threaded by default). The load
average is printed before and after: the figures are only comparable at a similar load.

Usage: python research/benchmarks/bench_presets.py [--frames 1000] [--size 160x120] [--repeats 3] [--presets
default,fast]
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from vpr import presets

# where the seqslam-desc method is not registered yet: SeqSLAM on the encoder's descriptor by cosine distance
_EMULATED = {"seqslam-desc": ("seqslam", {"descriptor": "encoder", "metric": "cosine"})}


def _method(name: str, conf: dict):
    from vpr.methods import available

    if name in available() or name not in _EMULATED:
        return name, dict(conf.get(name, {})), False
    base, extra = _EMULATED[name]
    return base, {**extra, **conf.get(name, {})}, True


def encode(preset: dict, images, need_pixels: bool):
    """EncodedTraverse of one traverse the way the compare pipeline builds them."""
    import encoders
    from vpr.seqslam import pixel_descriptors
    from vpr.types import EncodedTraverse

    enc = encoders.get(preset["encoder"], **preset["encoder_conf"])
    desc = enc.describe(images)
    if any(v == "fit" for k, v in enc.conf.items() if k.endswith("standardise")):
        enc.fit_descriptors(desc)
    sdr = enc.encode_descriptors(desc)
    pixels = pixel_descriptors(images) if need_pixels else None
    return EncodedTraverse(names=list(range(len(images))), sdr=sdr, desc=desc, pixels=pixels)


def bench(preset: dict, db_images, q_images, repeats: int) -> dict:
    from vpr.methods import match

    runs = [_method(m, preset["method_conf"]) for m in preset["methods"]]
    need_pixels = any(base == "seqslam" and conf.get("descriptor", "pixel") == "pixel" for base, conf, _ in runs)
    n_db, n_q = len(db_images), len(q_images)
    out: dict = {"encode ms/frame": []}
    for label, (_, _, emulated) in zip(preset["methods"], runs, strict=True):
        out[f"{label}{' (emulated)' if emulated else ''} ms/query frame"] = []
    out["total ms/query frame"] = []
    for _ in range(repeats):
        t = time.perf_counter()
        db = encode(preset, db_images, need_pixels)
        q = encode(preset, q_images, need_pixels)
        t_enc = time.perf_counter() - t
        out["encode ms/frame"].append(1e3 * t_enc / (n_db + n_q))
        total = t_enc
        for key, (base, conf, _) in zip(list(out)[1:-1], runs, strict=True):
            t = time.perf_counter()
            match(base, db, q, conf)  # compiles outside its timed region (methods._warm_up)
            dt = time.perf_counter() - t
            out[key].append(1e3 * dt / n_q)
            total += dt
        out["total ms/query frame"].append(1e3 * total / n_q)
    return out


def main(argv=None) -> None:
    from vpr import render

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=1000, help="frames per traverse (default 1000)")
    ap.add_argument("--size", default="160x120", help="render size WxH (default 160x120)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--presets", default="default,fast",
                    help=f"comma-separated subset of {', '.join(presets.available())} (default: default,fast)")
    args = ap.parse_args(argv)
    names = [p.strip() for p in args.presets.split(",") if p.strip()]
    unknown = [p for p in names if p not in presets.available()]
    if unknown:
        ap.error(f"--presets: unknown {unknown}; choose from {presets.available()}")
    w, h = (int(v) for v in args.size.lower().split("x"))
    t = time.perf_counter()
    scene = render.render_scene("two_seasons", size=(w, h), n_frames=args.frames)
    db, q = scene.traverses[:2]
    print(f"two_seasons {db.name} vs {q.name}: {len(db)} + {len(q)} frames at {w}x{h} "
          f"(rendered in {time.perf_counter() - t:.0f} s); min / median / max over {args.repeats} repeats")
    print("load average (1, 5, 15 min) before: " + " ".join(f"{v:.2f}" for v in os.getloadavg()))
    for name in names:
        p = presets.get(name)
        print(f"\n{name}: encoder {p['encoder']} {p['encoder_conf']}, methods {', '.join(p['methods'])}")
        for key, vals in bench(p, db.images, q.images, args.repeats).items():
            print(f"  {key:40s} {min(vals):9.2f} {np.median(vals):9.2f} {max(vals):9.2f}")
    print("load average (1, 5, 15 min) after: " + " ".join(f"{v:.2f}" for v in os.getloadavg()))


if __name__ == "__main__":
    main()
