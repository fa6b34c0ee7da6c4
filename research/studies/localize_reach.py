"""How far ``vpr localize`` could reach on the decision benchmark's database -> query rows: the online answers' own
ceiling, against SeqSLAM's accepted recall in ``vpr compare`` on the same frames.

Reads the benchmark's kept runs (``research.studies.decisions --out DIR``): ``localize/KEY/rshosm-seq/matches.csv``
(each query frame's answer, its path score, accepted, right) and ``compare/KEY/metrics.json``. Printed per row:

- ``best right``: the share of query frames whose answer is right, accepted or not (no decision rule recalls more);
- ``R(acc)``: the accepted right ones, as the benchmark prints them;
- ``R at P 0.99, in hindsight``: the most recall any threshold on the path score reaches at a precision of 0.99
  or more, the threshold chosen on the row's own ground truth (what the best rule over this score could do);
- SeqSLAM's ``R(acc)`` in ``vpr compare`` (offline: its sequences are centred on the query frame);
- SeqSLAM online (``compare_causal/KEY``: ``seqslam.causal=true``, each sequence the frames up to the query frame, as
  an online run sees them): its best right and its ``R(acc)``.

A second table joins ``localize``'s decisions with SeqSLAM online's, frame by frame (accepted, P(acc), R(acc)): either
accepted (``localize``'s answer where it accepted, SeqSLAM's otherwise); either accepted where the two answers lie
within the row's tolerance of each other; both accepted and so close.

Usage: python -m research.studies.localize_reach [--runs results/decisions]
"""
from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import numpy as np

#: (name, run key, tolerance in frames: the benchmark's radius)
ROWS = (("Nordland every file, first 300", "s300-w300", 1), ("Nordland every file, first 1,000", "s1000-w1000", 1),
        ("Nordland every file, all 3,576", "s_all-w_all", 1), ("Nordland every 10th, 1x", "s10-w10", 1),
        ("Gardens Point, 1x", "left-right", 2))


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


def _frames(path: Path) -> list[dict]:
    with open(path) as f:
        return list(csv.DictReader(f))


def joined(a: list[dict], b: list[dict], tolerance: int) -> dict[str, tuple]:
    """Decisions joined frame by frame (``a`` first): name -> (accepted, P(acc), R(acc)), P over the accepted frames
    scored right or wrong (the soft band left out), R over the frames with a true match."""
    def col(rows, key):
        return np.array([r[key] for r in rows])
    acc_a, acc_b = col(a, "accepted") == "1", col(b, "accepted") == "1"
    right = np.where(acc_a, col(a, "right"), col(b, "right"))
    close = np.abs(col(a, "best_db").astype(int) - col(b, "best_db").astype(int)) <= tolerance
    n = max(int((col(a, "true_db") != "").sum()), 1)

    def cell(acc):
        tp, fp = int((acc & (right == "1")).sum()), int((acc & (right == "0")).sum())
        return int(acc.sum()), (tp / (tp + fp) if tp + fp else None), tp / n
    return {"either": cell(acc_a | acc_b), "either, answers close": cell((acc_a | acc_b) & close),
            "both, answers close": cell(acc_a & acc_b & close)}


def _cell(c: tuple) -> str:
    return f"{c[0]}, {'-' if c[1] is None else f'{c[1]:.3f}'}, {c[2]:.2f}"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=Path, default=Path("results/decisions"))
    args = ap.parse_args(argv)
    print("| stream | best right | R(acc) | R at P 0.99, in hindsight | SeqSLAM R(acc), compare | "
          "SeqSLAM online: best right, R(acc) |")
    print("|---|---|---|---|---|---|")
    runs = {}
    for name, key, tolerance in ROWS:
        rows = _frames(args.runs / "localize" / key / "rshosm-seq" / "matches.csv")
        online = _frames(args.runs / "compare_causal" / key / "seqslam" / "matches.csv")
        seq = json.loads((args.runs / "compare" / key / "metrics.json").read_text())["methods"]["seqslam"]
        best, acc, hind = reach(rows)
        o_best, o_acc, _ = reach(online)
        print(f"| {name} | {best:.2f} | {acc:.2f} | {hind:.2f} | {seq['recall_accepted']:.2f} | "
              f"{o_best:.2f}, {o_acc:.2f} |")
        runs[name] = joined(rows, online, tolerance)
    kinds = list(next(iter(runs.values())))
    print("\n`localize` and SeqSLAM online joined, frame by frame (accepted, P(acc), R(acc)):\n")
    print("| stream | " + " | ".join(kinds) + " |")
    print("|---|" + "---|" * len(kinds))
    for name, cells in runs.items():
        print(f"| {name} | " + " | ".join(_cell(cells[k]) for k in kinds) + " |")


if __name__ == "__main__":
    main()
