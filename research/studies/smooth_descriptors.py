"""Descriptors whose neighbouring frames are near alike (a camera at a high frame rate), given as ``.npy``: what
each method answers at a tolerance of 1 and of 3 frames, in ``compare`` and in ``localize``.

Each stream is synthetic and stationary: a database of ``FRAMES`` descriptors of ``DIM`` numbers, each frame
``rho`` times the one before plus fresh noise (an AR(1) process: neighbours' cosine about ``rho``), and a query of
the same frames with independent noise of ``NOISE`` times their scale; the query is aligned with the database
(the same speed, forward), so the ground truth is ``--tolerance``. Printed per stream and tolerance: each method's
R@1 and accepted, P(acc), R(acc) in ``vpr compare`` (defaults of descriptor files), ``localize`` rshosm-seq's, and
where ``localize``'s accepted answers lie from the true frame (answer - truth: count).

Usage: python -m research.studies.smooth_descriptors [--out results/smooth_descriptors]
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import warnings
from pathlib import Path

import numpy as np

from pipelines.cli import main as vpr

FRAMES, DIM, NOISE = 300, 256, 0.5
RHOS = (0.8, 0.95)
TOLERANCES = (1, 3)


def stream(rho: float, seed: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """(database, query) of an AR(1) process of correlation ``rho`` between neighbouring frames."""
    rng = np.random.default_rng(seed)
    e = rng.normal(size=(FRAMES, DIM)).astype(np.float32)
    x = np.zeros_like(e)
    for t in range(FRAMES):
        x[t] = (rho * x[t - 1] if t else 0) + np.sqrt(1 - rho ** 2) * e[t]
    return x, x + NOISE * rng.normal(size=x.shape).astype(np.float32)


def run(argv: list) -> None:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()), \
            warnings.catch_warnings(action="ignore"):
        if vpr([str(a) for a in [*argv, "--no-progress"]]):
            raise SystemExit(f"vpr {' '.join(map(str, argv))} failed")


def cell(m: dict) -> str:
    p = m.get("precision_accepted")
    return f"{m['recall_at_1']:.3f}; {m['n_accepted']}, {'-' if p is None else f'{p:.3f}'}, {m['recall_accepted']:.2f}"


def offsets(matches: Path) -> str:
    with open(matches, newline="") as fh:
        off = [int(r["best_db"]) - int(r["query"]) for r in csv.DictReader(fh) if r["accepted"] == "1"]
    values, counts = np.unique(np.clip(off, -5, 5), return_counts=True)
    return " ".join(f"{v:+d}: {c}" for v, c in zip(values.tolist(), counts.tolist(), strict=True))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("results/smooth_descriptors"))
    args = ap.parse_args(argv)
    rows = []
    for rho in RHOS:
        db, q = stream(rho)
        folder = args.out / f"rho{rho}"
        folder.mkdir(parents=True, exist_ok=True)
        np.save(folder / "db.npy", db)
        np.save(folder / "q.npy", q)
        cos = float(np.mean(np.sum(db[1:] * db[:-1], 1) / np.linalg.norm(db[1:], axis=1)
                            / np.linalg.norm(db[:-1], axis=1)))
        for tol in TOLERANCES:
            out_c, out_l = folder / f"compare_t{tol}", folder / f"localize_t{tol}"
            if not (out_c / "metrics.json").exists():
                run(["compare", folder / "db.npy", folder / "q.npy", "--tolerance", tol, "--out", out_c])
            if not (out_l / "metrics.json").exists():
                run(["localize", folder / "db.npy", folder / "q.npy", "--tolerance", tol, "--out", out_l])
            cmp = json.loads((out_c / "metrics.json").read_text())["methods"]
            loc = json.loads((out_l / "metrics.json").read_text())["methods"]["rshosm-seq"]
            rows.append((f"rho {rho} (neighbours' cosine {cos:.2f}), tolerance {tol}", cmp, loc,
                         offsets(out_l / "rshosm-seq" / "matches.csv")))
    names = list(rows[0][1])
    print("R@1; accepted, P(acc), R(acc):\n")
    print("| stream | " + " | ".join(f"compare {n}" for n in names) + " | localize rshosm-seq | localize: answer - "
          "truth, accepted |")
    print("|---|" + "---|" * (len(names) + 2))
    for name, cmp, loc, off in rows:
        print(f"| {name} | " + " | ".join(cell(cmp[n]) for n in names) + f" | {cell(loc)} | {off} |")


if __name__ == "__main__":
    main()
