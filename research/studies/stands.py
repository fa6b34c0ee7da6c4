"""Stands and direction: what the map setting's refusals do to the decisions of ``vpr compare``, each on and off and
under the settings around the defaults (answers onto a stand of the map, ``vpr.shosm.standing``; a query frame that
did not move, ``vpr.sdr.unmoved``; a query that runs the map backwards, ``vpr.shosm.reversed_frames``).

Reads the decision benchmark's kept runs (``research.studies.decisions --out DIR``): each database -> query row's
rshosm-seq similarity (``compare/KEY/rshosm-seq/similarity.npy``, the evidence of both directions, which no
decision changes), the traverses' SDRs as the run encoded them (``cache/``) and their positions (``streams/``).
The memory is learned again from the database SDRs (deterministic: the run's own). Each variant decides every row
with the path rule (``accept_path``, the defaults) and refuses:

- ``map N``: answers onto a stand of the map (N or more frames of one place, ``map_places``; ``STAND_FRAMES``);
- ``query``: frames that kept ``UNMOVED_SHARE`` or more of the frame before's bits (``vpr.sdr.unmoved``);
- ``direction``: frames read running the map backwards (``reversed_frames`` of the forward and reversed evidence).

Printed per row: accepted, P(acc), R(acc) (right within the row's radius, wrong beyond its soft band), as the
benchmark scores them. Rows matched again at another speed by the benchmark (0.5x) are left out: their similarity is
the first pass's.

Usage: python -m research.studies.stands [--runs results/decisions] [--frames 2,3,4] [--shares 0.5,0.6,0.75]
"""
from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from vpr import methods, sdr
from vpr.evaluate import accepted_precision
from vpr.shosm import STAND_FRAMES, UNMOVED_SHARE, PathConf, accept_path, map_places, reversed_frames, standing
from vpr.types import EncodedTraverse

#: (row, compare key, database stream, query stream, radius, soft) of the benchmark's rows read here
ROWS = (("Nordland every file, first 300", "s300-w300", "s300", "w300", 1, 3),
        ("Nordland every file, first 1,000", "s1000-w1000", "s1000", "w1000", 1, 3),
        ("Nordland every file, all 3,576", "s_all-w_all", "s_all", "w_all", 1, 3),
        ("Nordland every 10th, 1x", "s10-w10", "s10", "w10", 1, 3),
        ("Nordland every 10th, query 2x", "s10-w20", "s10", "w20", 1, 3),
        ("Nordland every 10th, reversed", "s10-w10_rev", "s10", "w10_rev", 1, 3),
        ("Gardens Point, 1x", "left-right", "left", "right", 2, 8),
        ("Gardens Point, query 2x", "left-right2", "left", "right2", 2, 8),
        ("Gardens Point, reversed", "left-right_rev", "left", "right_rev", 2, 8))


def cached_sdr(runs: Path, stream: str) -> sp.csr_matrix:
    """The SDRs the benchmark's run encoded ``stream`` to (its feature cache)."""
    found = sorted((runs / "cache").glob(f"{stream}-*.npz"))
    if not found:
        raise SystemExit(f"{runs / 'cache'}: no cached SDRs of {stream}; run research.studies.decisions first")
    z = np.load(found[0], allow_pickle=False)
    idx = z["sdr_indices"]
    return sp.csr_matrix((np.ones(idx.size, bool), idx, z["sdr_indptr"]), shape=tuple(z["sdr_shape"]))


def positions(runs: Path, stream: str) -> np.ndarray:
    with open(runs / "streams" / f"{stream}.csv") as f:
        return np.array([float(r["x"]) for r in csv.DictReader(f)])


def row_inputs(runs: Path, key: str, db_name: str, q_name: str):
    """(S, map places, query SDRs, (forward z, reversed z, reversed accepted)) of one row."""
    S = np.load(runs / "compare" / key / "rshosm-seq" / "similarity.npy", allow_pickle=False)
    db, q = cached_sdr(runs, db_name), cached_sdr(runs, q_name)
    m = methods.get("rshosm-seq")
    enc = [EncodedTraverse(names=[str(i) for i in range(x.shape[0])], sdr=x) for x in (db, q)]
    state = m.fit(enc[0]).state
    inputs = m.decision_inputs(state, *enc)
    mem, codes = state
    return S, map_places(codes, mem.cells_per_column), q, inputs["direction"]


def cell(best, accepted, hard, soft) -> str:
    a = accepted_precision(best, accepted, hard, soft)
    p, r = a["precision_accepted"], a["recall_accepted"]
    return f"{int(accepted.sum())}, {'-' if p is None else f'{p:.3f}'}, {'-' if r is None else f'{r:.2f}'}"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=Path, default=Path("results/decisions"))
    ap.add_argument("--frames", default="2,3,4", help="stand lengths (map) to try")
    ap.add_argument("--shares", default="0.5,0.6,0.75", help="kept shares (query) to try")
    args = ap.parse_args(argv)
    frames = [int(x) for x in args.frames.split(",")]
    shares = [float(x) for x in args.shares.split(",")]
    variants = [("none", None, None, False), ("direction", None, None, True),
                *((f"map {f}", f, None, False) for f in frames),
                *((f"query {s}", None, s, False) for s in shares),
                ("defaults", STAND_FRAMES, UNMOVED_SHARE, True)]
    print("| stream | " + " | ".join(v[0] for v in variants) + " |")
    print("|---|" + "---|" * len(variants))
    for name, key, db_name, q_name, radius, soft in ROWS:
        S, places, q, direction = row_inputs(args.runs, key, db_name, q_name)
        pd, pq = positions(args.runs, db_name), positions(args.runs, q_name)
        d = np.abs(pd[:, None] - pq[None, :])
        hard, gsoft = d <= radius, d <= soft
        base = accept_path(S, PathConf())
        best = np.argmax(S, axis=0)
        cells = []
        for _, f, s, rev in variants:
            acc = base.accepted.copy()
            if f is not None:
                acc &= ~standing(places, f)[best]
            if s is not None:
                acc &= ~sdr.unmoved(q, s)
            if rev:  # read on the frames that moved, as the method reads it
                acc &= ~reversed_frames(*direction[:2], causal=False, moved=~sdr.unmoved(q, UNMOVED_SHARE))
            cells.append(cell(best, acc, hard, gsoft))
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
