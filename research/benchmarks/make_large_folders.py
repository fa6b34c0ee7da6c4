"""Write two frame-aligned 50,000-frame image folders for the ``vpr compare`` large-input run.

Place ``i`` of the route shows one of ``n / 10`` appearances (smooth random
64 x 32 grey images, each reused at about ten random places, so single frames
are ambiguous and only sequences tell the places apart). The database folder
shows every place once; the query folder shows the same places, frame-aligned
(ground truth ``--tolerance``), darker, shifted by up to two pixels and with
pixel noise.

Usage: python research/benchmarks/make_large_folders.py OUT [--n 50000] [--seed 0]
then: vpr compare OUT/db OUT/query --methods rshosm-seq,seqslam,pairwise --tolerance 2 --out RESULT
      --encoder pixel --encoder-conf k=200 --encoder-conf standardise=fit
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import numpy as np


def route_appearances(n: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """``n // 10`` smooth random 68 x 36 grey appearances, and the appearance of each of ``n`` places
    (each appearance at about ten random places, so that single frames are ambiguous)."""
    n_app = max(n // 10, 1)
    low = rng.random((n_app, 6, 12)).astype(np.float32)
    looks = np.stack([cv2.resize(x, (68, 36), interpolation=cv2.INTER_CUBIC) for x in low])
    looks = (looks - looks.min()) / (np.ptp(looks) + 1e-9) * 200 + 20
    return looks, rng.permutation(np.resize(np.arange(n_app), n))


def write_folders(out, n: int = 50_000, seed: int = 0) -> bool:
    """Write ``out/db`` and ``out/query`` (``n`` frames each) unless a complete set is there; True if written."""
    out = Path(out)
    done = out / "done.json"
    want = {"n": n, "seed": seed}
    if done.is_file() and json.loads(done.read_text()) == want:
        return False
    rng = np.random.default_rng(seed)
    looks, place_look = route_appearances(n, rng)
    done.unlink(missing_ok=True)
    for name in ("db", "query"):
        folder = out / name
        folder.mkdir(parents=True, exist_ok=True)
        for i in range(n):
            img = looks[place_look[i]]
            if name == "db":
                img = img[2:34, 2:66]
            else:
                dy, dx = rng.integers(0, 5, 2)
                img = 0.8 * img[dy:dy + 32, dx:dx + 64] + rng.normal(0, 8, (32, 64))
            cv2.imwrite(str(folder / f"{i:06d}.png"), np.clip(img, 0, 255).astype(np.uint8))
    done.write_text(json.dumps(want))
    return True


def main(argv=None, write=None, doc: str | None = None, what: str = "64 x 32 grey PNG"):
    """``OUT [--n N] [--seed S]``: write the folders with ``write`` (default: :func:`write_folders`)."""
    ap = argparse.ArgumentParser(description=doc or __doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out")
    ap.add_argument("--n", type=int, default=50_000)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    t = time.perf_counter()
    written = (write or write_folders)(a.out, a.n, a.seed)
    print(f"{'wrote' if written else 'found'} 2 x {a.n} frames ({what}) in {a.out} "
          f"({time.perf_counter() - t:.1f} s)")


if __name__ == "__main__":
    main()
