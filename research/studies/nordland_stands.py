"""Where `vpr compare` is wrong on Nordland at every file: the trains that stand.

Nordland's files are aligned across seasons (the same file name is the same place), and the project's measure
counts an answer right within 1 file and wrong beyond 3 (`--tolerance 1 --gt-soft 3`). Where a train stands, its
consecutive files show one place, so an answer several files away can show the query's place. Each wrong answer
(accepted, more than 3 files from the query's own) is put in one of three kinds, from the images alone:

- ``one standing place``: every database file between the answer and the query's own (one file of tolerance
  at each end) follows a file it hardly differs from (mean absolute grey difference below a tenth of the
  traverse's median between consecutive files): the answer shows the place the train stood at;
- ``query standing``: otherwise, the query's file hardly differs from the one before or after it (the query's
  train stands, the answer is elsewhere);
- ``other``.

Printed for the first 1,000 files and for all 3,576 (summer the database, winter the query; default preset,
``rshosm-seq``): accepted, wrong, each kind, and the precision with the standing places' answers counted as
neither right nor wrong (a soft band, as ``--gt-soft``).

Usage: python -m research.studies.nordland_stands [--data DIR] [--out DIR] [--frames 1000,3576]
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import io
import os
import warnings
from pathlib import Path

import numpy as np
from PIL import Image

from pipelines.cli import main as vpr

#: a step between consecutive files is standing below this fraction of the traverse's median step
STANDING = 0.1


def standing_steps(files: list[Path]) -> np.ndarray:
    """Whether file i + 1 hardly differs from file i (bool, one per step)."""
    grey = np.stack([np.asarray(Image.open(f).convert("L"), np.float32) for f in files])
    step = np.abs(np.diff(grey, axis=0)).mean(axis=(1, 2))
    return step < STANDING * np.median(step)


def kinds(best, accepted, db_still, q_still) -> dict:
    """Counts of the wrong answers of each kind (and the accepted ones)."""
    out = {"accepted": int(accepted.sum()), "wrong": 0, "one standing place": 0, "query standing": 0, "other": 0}
    for q in np.flatnonzero(accepted & (np.abs(best - np.arange(best.size)) > 3)):
        lo, hi = sorted((int(best[q]), int(q)))
        out["wrong"] += 1
        if db_still[lo + 1:hi - 1].all():
            out["one standing place"] += 1
        elif q_still[max(q - 1, 0):q + 1].any():
            out["query standing"] += 1
        else:
            out["other"] += 1
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(os.environ.get("VPR_DATASETS", "../shared/datasets")))
    ap.add_argument("--out", type=Path, default=Path("results/nordland_stands"))
    ap.add_argument("--frames", default="1000,3576", help="first N files of each season, comma-separated")
    a = ap.parse_args(argv)
    nl = a.data / "nordland_trimmed"
    print("| files | accepted | P(acc) | wrong | one standing place | query standing | other | P(acc), standing "
          "places neither right nor wrong |")
    print("|---|---|---|---|---|---|---|---|")
    for n in (int(v) for v in a.frames.split(",")):
        folders = {}
        for season in ("summer", "winter"):
            files = sorted((nl / season).iterdir())[:n]
            folders[season] = a.out / f"{season}{n}"
            folders[season].mkdir(parents=True, exist_ok=True)
            for f in files:
                if not (folders[season] / f.name).exists():
                    (folders[season] / f.name).symlink_to(f.resolve())
        run = a.out / f"compare{n}"
        if not (run / "metrics.json").exists():
            with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings(action="ignore"):
                if vpr([str(x) for x in ["compare", folders["summer"], folders["winter"], "--methods", "rshosm-seq",
                                         "--tolerance", 1, "--gt-soft", 3, "--cache", a.out / "cache", "--out", run,
                                         "--no-progress"]]):
                    raise SystemExit(f"vpr compare of {n} files failed")
        with open(run / "rshosm-seq" / "matches.csv", newline="") as fh:
            rows = list(csv.DictReader(fh))
        best = np.array([int(r["best_db"]) for r in rows])
        accepted = np.array([r["accepted"] == "1" for r in rows])
        db_still = standing_steps(sorted(folders["summer"].iterdir()))
        q_still = standing_steps(sorted(folders["winter"].iterdir()))
        k = kinds(best, accepted, db_still, q_still)
        right = int((accepted & (np.abs(best - np.arange(best.size)) <= 1)).sum())
        judged = right + k["wrong"] - k["one standing place"]
        print(f"| {n:,} | {k['accepted']:,} | {right / (right + k['wrong']):.3f} | {k['wrong']} | "
              f"{k['one standing place']} | {k['query standing']} | {k['other']} | {right / judged:.3f} |",
              flush=True)


if __name__ == "__main__":
    main()
