"""What answering a few frames late would give ``localize``: rSHOSM-seq's decisions on the evidence a robot has
``L`` frames after each query frame, on the decision benchmark's database -> query rows.

``vpr compare`` scores each query frame by the evidence of the whole query (``direction="both"``: the causal pass
plus one from the last frame back); ``vpr localize`` by the causal pass alone. In between, a frame answered ``L``
frames late has the causal pass and the backward pass from ``L`` frames after it: the evidence here is exactly
that (the dense kernel of :mod:`vpr.shosm.kernels.evidence`, the backward pass started afresh at frame ``t + L``
for each ``t``), standardised per frame and decided by ``vpr compare``'s rule (:meth:`RshosmSeq.decisions`, the
stands of map and query; not the direction check, which on these forward rows refuses a few frames more: with the
whole query Nordland every 10th 328 -> 323 accepted, Gardens Point 197 -> 189, all right ones). The query is
encoded as ``vpr compare`` encodes it (the default preset, ``standardise=fit``): ``L = 0`` is the causal evidence
on those SDRs, ``L`` = the query's length is ``compare``'s evidence. Printed per row:
accepted, P(acc), R(acc) for each ``L`` (ground truth as the benchmark's: Nordland within 1 file, soft 3; Gardens
Point within 2 frames, soft 8), and SeqSLAM's R(acc) (``compare`` and online) from the benchmark's runs.

Usage: VPR_DATASETS=../shared/datasets python -m research.studies.localize_lag [--runs results/decisions]
    [--lags 0,5,10,20] [--rows s300-w300,s1000-w1000]
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import encoders
from pipelines.extract import extract
from vpr import evaluate, methods, presets, sdr
from vpr.groundtruth import gt_from_frames
from vpr.shosm import UNMOVED_SHARE, map_places, standing
from vpr.shosm.graph import Graph
from vpr.shosm.kernels import evidence as KE
from vpr.sources import open_source

#: (name, run key, database folder, query folder, tolerance, soft band) in frames of the streams
ROWS = (("Nordland every file, first 300", "s300-w300", "s300", "w300", 1, 3),
        ("Nordland every file, first 1,000", "s1000-w1000", "s1000", "w1000", 1, 3),
        ("Nordland every file, all 3,576", "s_all-w_all", "s_all", "w_all", 1, 3),
        ("Nordland every 10th, 1x", "s10-w10", "s10", "w10", 1, 3),
        ("Gardens Point, 1x", "left-right", "left", "right", 2, 8))


def lagged_evidence(mem, db_codes, q, conf, lag: int) -> np.ndarray:
    """Raw evidence (n_db x n_q) of each query frame ``t`` from the causal pass and the backward pass started at frame
    ``min(t + lag, n_q - 1)``, as ``direction="both"`` adds them."""
    rel, (bit_cols, bit_len, col_size, rel_col, rs, rd, db_ptr, db_ind, db_norm) = Graph.of(mem, db_codes).dense()
    stay, skip = conf.costs
    n_q = q.shape[0]
    q_ptr, q_ind = q.indptr.astype(np.int64), q.indices.astype(np.int64)
    args = (bit_cols, bit_len, col_size, rel_col)
    tail = (db_ptr, db_ind, db_norm, float(conf.decay), stay, skip, 0.5)
    out = np.zeros((db_ptr.size - 1, n_q), np.float32)
    KE.evidence_frames(q_ptr, q_ind, np.arange(n_q), *args, rs, rd, *tail, out, np.zeros(rel.size), True)
    for t in range(n_q):  # the backward pass from frame t + lag down to t, on those frames alone
        w = q[t:min(t + lag, n_q - 1) + 1]
        part = np.zeros((out.shape[0], w.shape[0]), np.float32)
        KE.evidence_frames(w.indptr.astype(np.int64), w.indices.astype(np.int64), np.arange(w.shape[0])[::-1].copy(),
                           *args, rd, rs, *tail, part, np.zeros(rel.size), True)
        out[:, t] += part[:, 0]
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=Path, default=Path("results/decisions"))
    ap.add_argument("--lags", default="0,5,10,20")
    ap.add_argument("--rows", default=None, help="run keys, comma-separated (default: all)")
    args = ap.parse_args(argv)
    lags = [int(x) for x in args.lags.split(",")]
    keys = None if args.rows is None else set(args.rows.split(","))
    s = presets.resolve("default", methods=["rshosm-seq"])
    enc = encoders.get(s["encoder"], **s["encoder_conf"])
    method = methods.get("rshosm-seq", **s["method_conf"].get("rshosm-seq", {}))
    conf = method.seq.evidence.split()[0]
    print("| stream | " + " | ".join(f"L = {lag}" for lag in lags) + " | SeqSLAM compare / online |")
    print("|---|" + "---|" * (len(lags) + 1))
    for name, key, db_name, q_name, tol, soft in ROWS:
        if keys is not None and key not in keys:
            continue
        t0 = time.perf_counter()
        streams = args.runs / "streams"
        db, q = (extract(open_source(streams / n), enc, ("sdr",), cache_dir=args.runs / "cache", progress=False)
                 for n in (db_name, q_name))
        mem, db_codes = method.fit(db.features).state
        q_sdr = q.features.sdr
        stands = (standing(map_places(db_codes, mem.cells_per_column)), sdr.unmoved(q_sdr, UNMOVED_SHARE))
        hard = gt_from_frames(db.indices, q.indices, tol)
        soft_gt = gt_from_frames(db.indices, q.indices, soft)
        cells = []
        for lag in lags:
            S = lagged_evidence(mem, db_codes, q_sdr, conf, lag)
            KE.zscore_dense(S)
            best, z = S.argmax(axis=0), S.max(axis=0)
            d = method.decisions(S, best, z, stands=stands)
            m = evaluate.accepted_precision(d.best, d.accepted, hard, soft_gt)
            p = m["precision_accepted"]
            cells.append(f"{m['n_accepted']}, {'-' if p is None else f'{p:.3f}'}, {m['recall_accepted']:.2f}")
        seq = [json.loads((args.runs / sub / key / "metrics.json").read_text())["methods"]["seqslam"]
               for sub in ("compare", "compare_causal")]
        seqslam = " / ".join(f"{m['recall_accepted']:.2f}" for m in seq)
        print(f"| {name} | " + " | ".join(cells) + f" | {seqslam} |  ({time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
