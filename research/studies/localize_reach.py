"""How far ``vpr localize`` could reach on the decision benchmark's database -> query rows: the online answers' own
ceiling, against SeqSLAM's accepted recall in ``vpr compare`` on the same frames.

Reads the benchmark's kept runs (``research.studies.decisions --out DIR``): ``localize/KEY/rshosm-seq/matches.csv``
(each query frame's answer, its path score, accepted, right) and ``compare/KEY/metrics.json``. Printed per row:

- ``best right``: the share of query frames whose answer is right, accepted or not (no decision rule recalls more);
- ``R(acc)``: the accepted right ones, as the benchmark prints them;
- ``R at P 0.99, in hindsight``: the most recall any threshold on the path score reaches at a precision of 0.99
  or more, the threshold chosen on the row's own ground truth (what the best rule over this score could do);
- SeqSLAM's ``R(acc)`` in ``vpr compare`` (offline: its sequences are centred on the query frame).

Usage: python -m research.studies.localize_reach [--runs results/decisions]
"""
from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import numpy as np

ROWS = (("Nordland every file, first 300", "s300-w300"), ("Nordland every file, first 1,000", "s1000-w1000"),
        ("Nordland every file, all 3,576", "s_all-w_all"), ("Nordland every 10th, 1x", "s10-w10"),
        ("Gardens Point, 1x", "left-right"))


def reach(rows: list[dict]) -> tuple[float, float, float]:
    """(best right, accepted right, recall at P >= 0.99 in hindsight) over the query frames with a true match (the
    benchmark's recall)."""
    right = np.array([r["right"] == "1" for r in rows])
    wrong = np.array([r["right"] == "0" for r in rows])
    acc = np.array([r["accepted"] == "1" for r in rows])
    score = np.array([float(r["score"]) if r["score"] not in ("", "-inf") else -np.inf for r in rows])
    n = max(sum(r["true_db"] != "" for r in rows), 1)
    order = np.argsort(-score, kind="stable")
    tp, fp = np.cumsum(right[order]), np.cumsum(wrong[order])
    ok = tp / np.maximum(tp + fp, 1) >= 0.99
    return right.sum() / n, (acc & right).sum() / n, (tp[ok].max() / n if ok.any() else 0.0)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=Path, default=Path("results/decisions"))
    args = ap.parse_args(argv)
    print("| stream | best right | R(acc) | R at P 0.99, in hindsight | SeqSLAM R(acc), compare |")
    print("|---|---|---|---|---|")
    for name, key in ROWS:
        with open(args.runs / "localize" / key / "rshosm-seq" / "matches.csv") as f:
            rows = list(csv.DictReader(f))
        seq = json.loads((args.runs / "compare" / key / "metrics.json").read_text())["methods"]["seqslam"]
        best, acc, hind = reach(rows)
        print(f"| {name} | {best:.2f} | {acc:.2f} | {hind:.2f} | {seq['recall_accepted']:.2f} |")


if __name__ == "__main__":
    main()
