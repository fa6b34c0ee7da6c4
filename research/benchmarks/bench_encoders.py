"""Throughput of the image encoders on 640x480 frames, one thread.

The frames (rendered by :mod:`vpr.render`, ``two_seasons`` scene) are written
to a temporary folder and read back, so every encoder times only encoding of
already decoded images. Each rate is reported as min / median / max over
``--repeats`` runs and as a ratio to bare ``cv2.imread`` of the same files
(median over median).

Targets: pixel >= 1,000 img/s, projection >= 2,000 desc/s (sparsifying cached
2048-dim pixel descriptors), orb >= 150 img/s, cnn >= 100 img/s (224x224
network input).

Usage: python research/benchmarks/bench_encoders.py [--frames 64] [--repeats 5] [--format png] [--json out.json]
"""
from __future__ import annotations

import os

# one thread everywhere; must be set before NumPy / OpenCV load their pools
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

TARGETS = {"pixel": 1000.0, "projection": 2000.0, "orb": 150.0, "cnn": 100.0}


def synthetic_frames(n: int, size=(640, 480), seed: int = 0) -> list[np.ndarray]:
    """Random coloured blobs on a sky / ground split: a stand-in when the renderer is absent."""
    rng = np.random.default_rng(seed)
    w, h = size
    out = []
    for _ in range(n):
        im = np.empty((h, w, 3), np.uint8)
        im[: h // 2], im[h // 2:] = (200, 170, 120), (60, 90, 70)
        for _ in range(60):
            x, y, r = int(rng.integers(0, w)), int(rng.integers(0, h)), int(rng.integers(4, 60))
            cv2.circle(im, (x, y), r, tuple(int(c) for c in rng.integers(0, 256, 3)), -1)
        out.append(im)
    return out


def load_frames(n: int, size=(640, 480)) -> tuple[list[np.ndarray], str]:
    """``n`` rendered BGR frames of ``size``, cycling over the scene's traverses."""
    try:
        from vpr.render import render_scene
    except ImportError:
        return synthetic_frames(n, size), "synthetic blobs (vpr.render not available)"

    scene = render_scene("two_seasons", size=size, n_frames=max(1, (n + 1) // 2))
    frames = [im for tr in scene.traverses for im in tr.images][:n]
    while len(frames) < n:
        frames += frames[: n - len(frames)]
    return frames, "render_scene('two_seasons')"


def rates(fn, n_items: int, repeats: int) -> np.ndarray:
    """Items per second of ``fn()`` over ``repeats`` timed runs, after one warm-up."""
    fn()
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        out.append(n_items / (time.perf_counter() - t))
    return np.array(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--frames", type=int, default=64)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--format", choices=("png", "jpg"), default="png")
    p.add_argument("--json", type=Path, default=None, help="also save the numbers as JSON")
    args = p.parse_args(argv)
    if args.frames < 1 or args.repeats < 1:
        p.error("--frames and --repeats must be >= 1")

    cv2.setNumThreads(1)
    import encoders

    frames, source = load_frames(args.frames)
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        paths = [str(Path(tmp) / f"{i:05d}.{args.format}") for i in range(len(frames))]
        for path, im in zip(paths, frames, strict=True):
            if not cv2.imwrite(path, im):
                raise OSError(f"could not write {path}")
        results["imread"] = rates(lambda: [cv2.imread(q) for q in paths], len(paths), args.repeats)
        # encode exactly what imread decodes (JPEG is lossy)
        frames = [cv2.imread(q) for q in paths]

    runs = [
        ("pixel", "pixel", {}, "img"),
        ("projection", "projection", {}, "desc"),
        ("projection(hog)", "projection", {"descriptor": "hog"}, "img"),
        ("orb", "orb", {}, "img"),
        ("orb(grid)", "orb", {"mode": "grid"}, "img"),
        ("cnn", "cnn", {"threads": 1, "input_size": (224, 224)}, "img"),
    ]
    units = {"imread": "img"}
    for label, name, conf, unit in runs:
        enc = encoders.get(name, **conf)
        if label == "projection":
            desc = encoders.get("pixel").describe(frames)
            results[label] = rates(lambda enc=enc, desc=desc: enc.encode_descriptors(desc), len(desc), args.repeats)
        else:
            results[label] = rates(lambda enc=enc: enc.encode(frames), len(frames), args.repeats)
        units[label] = unit

    imread_med = float(np.median(results["imread"]))
    print(f"encoder throughput, {len(frames)} frames 640x480 from {source}, one thread, "
          f"{args.repeats} repeats; imread of {args.format.upper()} files")
    print(f"{'':16s} {'min':>9s} {'median':>9s} {'max':>9s}  {'x imread':>8s}  target")
    table = {}
    for label, r in results.items():
        med = float(np.median(r))
        base = label.split("(")[0]
        target = TARGETS.get(base) if label == base else None
        verdict = "" if target is None else f">= {target:,.0f} {'ok' if med >= target else 'MISSED'}"
        print(f"{label:16s} {r.min():9.0f} {med:9.0f} {r.max():9.0f}  {med / imread_med:8.2f}  "
              f"{units[label]}/s {verdict}")
        table[label] = {"min": float(r.min()), "median": med, "max": float(r.max()),
                        "ratio_to_imread": med / imread_med, "unit": f"{units[label]}/s", "target": target}
    if args.json:
        from vpr.io import save_json

        save_json(args.json, {"frames": len(frames), "repeats": args.repeats, "format": args.format,
                              "source": source, "rates": table})
    return 0


if __name__ == "__main__":
    sys.exit(main())
