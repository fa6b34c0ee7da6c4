"""CNN encoding on Dask: frames/s with 1 and 2 local workers, and their ratio.

Renders ``--frames`` frames of the ``two_seasons`` scene at 640x480 into a
temporary folder (PNG), then encodes them with ``encoders.get("cnn")`` through
:func:`pipelines.encode.encode_sources`: serially in this process, and on a
local cluster of 1 and of 2 single-threaded worker processes. The cluster is
started once per size and warmed up (each worker loads the ONNX model once), so
the timed runs measure reading, describing, shipping the chunks back, fitting
and writing the cache file (SDRs and descriptors). Prints min / median / max over ``--repeats`` runs.

    python research/benchmarks/bench_encode_dask.py [--frames 240] [--repeats 3] [--chunk-frames 30]
"""
from __future__ import annotations

import argparse
import logging
import os
import statistics
import tempfile
import time
from pathlib import Path

import cv2


def _render(folder: Path, n: int) -> None:
    from vpr.render import render_scene

    scene = render_scene("two_seasons", size=(640, 480), n_frames=n, traverses=["summer_day"])
    for i, im in enumerate(scene.traverses[0].images):
        cv2.imwrite(str(folder / f"{i:06d}.png"), im)


def _runs(folder, cache, repeats, **kw) -> list[float]:
    from pipelines.encode import encode_sources

    secs = []
    for _ in range(repeats):
        t = time.perf_counter()
        # SDRs and CNN descriptors: what the cnn encoder costs (SeqSLAM pixels would add their own resize)
        encode_sources([folder], cache, "cnn", {"standardise": "fit"}, parts=("sdr", "desc"), overwrite=True,
                       progress=False, **kw)
        secs.append(time.perf_counter() - t)
    return secs


def _fmt(n, secs) -> str:
    fps = sorted(n / s for s in secs)
    return f"{fps[0]:7.1f} {statistics.median(fps):7.1f} {fps[-1]:7.1f} frames/s (min/median/max)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=240)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--chunk-frames", type=int, default=30)
    a = ap.parse_args()
    from distributed import LocalCluster

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "frames"
        folder.mkdir()
        t = time.perf_counter()
        _render(folder, a.frames)
        print(f"rendered {a.frames} frames at 640x480 in {time.perf_counter() - t:.1f} s")
        cache = Path(tmp) / "cache"
        _runs(folder, cache, 1, workers=0, chunk_frames=a.chunk_frames)  # warm-up: model load, imports
        results = {"serial (in-process)": _runs(folder, cache, a.repeats, workers=0, chunk_frames=a.chunk_frames)}
        for n in (1, 2):
            with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                              dashboard_address=None, silence_logs=logging.ERROR) as cluster:
                addr = cluster.scheduler_address
                _runs(folder, cache, 1, scheduler=addr, chunk_frames=a.chunk_frames)  # warm-up
                results[f"{n} worker{'s' if n > 1 else ''}"] = _runs(folder, cache, a.repeats, scheduler=addr,
                                                                       chunk_frames=a.chunk_frames)
    print(f"cnn encoder (EfficientNet-Lite0 block 10, 1 onnxruntime thread per worker), {a.frames} frames, "
          f"chunks of {a.chunk_frames}, {a.repeats} repeats; {os.cpu_count()} cores, load average "
          f"{os.getloadavg()[0]:.1f} at the end (other processes share the cores)")
    for name, secs in results.items():
        print(f"  {name:<20} {_fmt(a.frames, secs)}")
    one, two = sorted(results["1 worker"]), sorted(results["2 workers"])
    ratios = sorted(x / y for x in one for y in two)
    print(f"  speed-up 2 workers / 1 worker: median {statistics.median(one) / statistics.median(two):.2f} "
          f"(range over run pairs {ratios[0]:.2f}-{ratios[-1]:.2f})")


if __name__ == "__main__":
    main()
