"""The sequence layer on descriptors computed elsewhere: rSHOSM-seq beside Delta Descriptors, SeqSLAM and single frames.

Each traverse's CNN descriptors (the ``cnn`` encoder's GeM of EfficientNet-Lite0, the model the project ships) are
computed once and written as ``.npy`` files, as a user's NetVLAD or MixVPR descriptors would come; then ``vpr compare
DB.npy QUERY.npy`` runs with its defaults for descriptor files (the ``descriptors`` preset: rshosm-seq on their
random-projection top-k, delta, seqslam-desc and pairwise on the descriptors as they are). Ground truth by frame
number: Gardens Point day_left -> day_right right within 2 frames, soft 8; Nordland summer -> winter every 10th file
(358) right within 1, soft 3.

Usage: VPR_DATASETS=../shared/datasets python -m research.studies.descriptor_peers [--out results/descriptor_peers]
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import warnings
from pathlib import Path

import cv2
import numpy as np

import encoders
from pipelines.cli import main as vpr

#: case -> (database folder, query folder, every k-th file, tolerance, soft band) under the data folder
CASES = {"Gardens Point day_left -> day_right": ("gardens_point_day/day_left", "gardens_point_day/day_right",
                                                 1, 2, 8),
         "Nordland summer -> winter, every 10th (358)": ("nordland_trimmed/summer", "nordland_trimmed/winter",
                                                         10, 1, 3)}


def _described(files: list[Path], out: Path) -> Path:
    """The ``cnn`` encoder's descriptors of ``files``, written once as ``out``."""
    if not out.exists():
        enc = encoders.get("cnn")
        d = np.concatenate([enc.describe([cv2.imread(str(f)) for f in files[i:i + 32]])
                            for i in range(0, len(files), 32)])
        out.parent.mkdir(parents=True, exist_ok=True)
        np.save(out, d)
    return out


def run(data: Path, out: Path) -> dict:
    rows = {}
    for case, (db_dir, q_dir, every, tol, soft) in CASES.items():
        key = db_dir.split("/")[0]
        descs = [_described(sorted((data / d).iterdir())[::every], out / f"{key}-{Path(d).name}.npy")
                 for d in (db_dir, q_dir)]
        run_out = out / f"compare-{key}"
        if not (run_out / "metrics.json").exists():
            with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings(action="ignore"):
                if vpr([str(a) for a in ["compare", *descs, "--tolerance", tol, "--gt-soft", soft, "--out", run_out,
                                         "--no-progress"]]):
                    raise SystemExit(f"vpr compare {descs} failed")
        rows[case] = json.loads((run_out / "metrics.json").read_text())["methods"]
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("results/descriptor_peers"))
    args = ap.parse_args(argv)
    data = Path(os.environ.get("VPR_DATASETS", Path(__file__).resolve().parents[3] / "shared" / "datasets"))
    rows = run(data, args.out)
    methods = list(next(iter(rows.values())))
    print("| method (on the same CNN descriptors, given as .npy) | " + " | ".join(f"{c}: AP, R@1" for c in rows) + " |")
    print("|---|" + "---|" * len(rows))
    for m in methods:
        print(f"| {m} | " + " | ".join(f"{r[m]['ap']:.3f}, {r[m]['recall_at_1']:.3f}" for r in rows.values()) + " |")


if __name__ == "__main__":
    main()
