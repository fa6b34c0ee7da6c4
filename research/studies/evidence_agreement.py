"""Sparse (beam, top-K) against dense rshosm-seq evidence on camera-like data: same best matches?

Rendered two_seasons (day database, night query) and speed_change (slow vs
fast), pixel encoder k=200 standardised per traverse; optionally Nordland 358
summer vs winter (``--nordland DIR``, every 10th file). Prints, per direction,
the share of queries whose best database frame is the same, and R@1 / AUC of both.

Usage: python -m research.studies.evidence_agreement [--size 160x120] [--frames 300] [--nordland DIR]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import encoders
from vpr import shosm as ev
from vpr.evaluate import auc_pr
from vpr.groundtruth import gt_from_tolerance
from vpr.shosm import SequenceMemory


def _zscore(D):
    sd = D.std(axis=0)
    return (D - D.mean(axis=0)) / np.where(sd > 0, sd, 1.0)


def compare(name, a, b, gt):
    mem = SequenceMemory(threshold=0.75)
    codes = mem.run(a)
    mem.reset()
    n_q = b.shape[0]
    for direction in ("both", "forward"):
        t = time.process_time()
        D = _zscore(ev.dense_evidence(mem, b, codes, direction=direction).astype(np.float64))
        t_d = time.process_time() - t
        t = time.process_time()
        r = ev.sparse_evidence(mem, b, codes, direction=direction, top_k=50)
        t_s = time.process_time() - t
        bd = D.argmax(axis=0)
        r1 = lambda best: gt[np.maximum(best, 0), np.arange(n_q)].mean()  # noqa: E731
        print(f"{name:28s} {direction:8s} same best match {100 * np.mean(bd == r.best):6.2f} %  "
              f"R@1 dense {r1(bd):.3f} sparse {r1(r.best):.3f}  AUC dense {auc_pr(D, gt):.3f} "
              f"sparse top-50 {auc_pr(r.similarity, gt):.3f}  ({t_d:.2f} s / {t_s:.2f} s)", flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="160x120")
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--nordland", default=None)
    a = ap.parse_args(argv)
    from vpr.render import gt_matrix, render_scene

    size = tuple(int(v) for v in a.size.split("x"))
    enc = encoders.get("pixel", k=200, standardise="fit")
    for scene in ("two_seasons", "speed_change"):
        d, n = render_scene(scene, size=size, n_frames=a.frames).traverses
        compare(f"rendered {scene}", enc.fit(d.images).encode(d.images), enc.fit(n.images).encode(n.images),
                gt_matrix(d, n, 4.0))
    if a.nordland:
        from pathlib import Path

        from vpr.sources import open_source

        x = {}
        for s in ("summer", "winter"):
            images = [f.image for f in open_source(Path(a.nordland) / s, step=10)]
            x[s] = enc.fit(images).encode(images)
        compare("nordland 358", x["summer"], x["winter"], gt_from_tolerance(358, 358, 1))


if __name__ == "__main__":
    main()
