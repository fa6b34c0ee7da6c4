"""Write two frame-aligned 50,000-frame image folders for the ``vpr compare`` large-input run (issue 13).

Place ``i`` of the route shows one of ``n / 10`` appearances (smooth random
64 x 32 grey images, each reused at about ten random places, so single frames
are ambiguous and only sequences tell the places apart). The database folder
shows every place once; the query folder shows the same places, frame-aligned
(ground truth ``--tolerance``), darker, shifted by up to two pixels and with
pixel noise.

Usage: python benchmarks/make_large_folders.py OUT [--n 50000] [--seed 0]
then: vpr compare OUT/db OUT/query --methods rshosm-seq,seqslam,pairwise --tolerance 2 --out RESULT
      --encoder pixel --encoder-conf k=200 --encoder-conf standardise=fit
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out")
    ap.add_argument("--n", type=int, default=50_000)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    rng = np.random.default_rng(a.seed)
    n_app = max(a.n // 10, 1)
    low = rng.random((n_app, 6, 12)).astype(np.float32)
    looks = np.stack([cv2.resize(x, (68, 36), interpolation=cv2.INTER_CUBIC) for x in low])
    looks = (looks - looks.min()) / (np.ptp(looks) + 1e-9) * 200 + 20
    place_look = rng.permutation(np.resize(np.arange(n_app), a.n))
    t = time.perf_counter()
    for name in ("db", "query"):
        folder = Path(a.out) / name
        folder.mkdir(parents=True, exist_ok=True)
        for i in range(a.n):
            img = looks[place_look[i]]
            if name == "db":
                img = img[2:34, 2:66]
            else:
                dy, dx = rng.integers(0, 5, 2)
                img = 0.8 * img[dy:dy + 32, dx:dx + 64] + rng.normal(0, 8, (32, 64))
            cv2.imwrite(str(folder / f"{i:06d}.png"), np.clip(img, 0, 255).astype(np.uint8))
    print(f"wrote 2 x {a.n} frames (64 x 32 grey PNG) to {a.out} in {time.perf_counter() - t:.1f} s")


if __name__ == "__main__":
    main()
