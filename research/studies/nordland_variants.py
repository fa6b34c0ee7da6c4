"""Study: the rSHOSM variants of ``research/docs/experiments.md`` on Nordland.

Run ``python -m research.studies.nordland_variants --subset 358 --out DIR [--data PATH]``
(the dataset as for ``vpr nordland``: ``--data`` or ``$VPR_DATASETS``).

Each row changes one thing against the row it names, on the same frames and
ground truth as the benchmark, and is reproducible from this module alone.
Rows:

- SDR density and per-traverse standardisation (pairwise overlap and the paper's rSHOSM);
- the paper's rSHOSM with learning off and the query's minicolumns chosen as the
  ``k`` best-overlapping ones instead of by threshold, optionally with the
  overlaps z-scored against the neighbouring minicolumns (created around the
  same database frames) and a bonus for minicolumns holding predicted cells
  (:func:`binary_topk_query`, pure Python, run on the 358-frame subset only);
- ``rshosm-seq`` built up one part at a time (graded evidence forward only,
  both directions, stay/skip transitions, per-query normalisation), then one
  default changed at a time (minicolumn threshold while learning the database,
  rSHOSM's random connections, decay, standardisation);
- several feed-forward segments per minicolumn, taught on the query traverse by
  the sequence prediction (:mod:`research.studies.ff_segments`, pure Python,
  358-frame subset only): teacher off (= the paper's rSHOSM), when no (or few)
  minicolumns are active, only from confirmed predictions, with a cap; read
  online, or in a second pass after teaching on the query itself (transductive)
  or on the winter frames halfway between the subset's (held out); and an upper
  bound whose teacher is the ground truth.
"""
from __future__ import annotations

import argparse
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from pipelines.nordland.benchmark import encode_sdrs
from pipelines.nordland.data import DatasetError, find_dataset, frame_names, pixel_descriptors
from research.studies.ff_segments import segment_codes
from tests.reference import activate_cells
from vpr import evaluate as E
from vpr import groundtruth
from vpr import io as _io
from vpr.methods import match
from vpr.shosm import SequenceMemory, pad_codes
from vpr.similarity import overlap_similarity
from vpr.types import EncodedTraverse

__all__ = ["binary_topk_query", "grid_rows", "run_grid", "main"]


def binary_topk_query(mem: SequenceMemory, q_sdr, k_active: int = 30, window: int = 0,
                      bias: float = 0.0) -> sp.csr_matrix:
    """Query winner codes (learning off) with top-k minicolumn selection; a variant, not the paper's.

    Every query frame activates the ``k_active`` minicolumns with the highest
    score: the fraction of the minicolumn's connections that are on, z-scored
    against minicolumns ``c - window//2 .. c + window//2`` when ``window > 0``,
    plus ``bias`` if the minicolumn holds a predicted cell. Winners and
    predictions then follow Algorithm 1 lines 5-11 as the test oracle writes
    them (:func:`tests.reference.activate_cells`, no learning, no random draws).
    """
    con = mem.connections
    cpc, nc = con.cells_per_column, con.n_columns
    C = con.feedforward.astype(np.float32)
    size = np.maximum(con.column_sizes(), 1)
    lat = con.lateral
    forward = defaultdict(set, {s: set(lat.indices[lat.indptr[s]:lat.indptr[s + 1]].tolist())
                                for s in np.flatnonzero(np.diff(lat.indptr)).tolist()})
    h = window // 2
    i = np.arange(nc)
    lo, hi = np.maximum(i - h, 0), np.minimum(i + h + 1, nc)
    predicted: set[int] = set()
    codes = []
    for t in range(q_sdr.shape[0]):
        x = (C @ q_sdr[t].T.astype(np.float32)).toarray().ravel() / size
        if window:
            cs, cs2 = np.r_[0, np.cumsum(x)], np.r_[0, np.cumsum(x * x)]
            m = (cs[hi] - cs[lo]) / (hi - lo)
            x = (x - m) / np.sqrt(np.maximum((cs2[hi] - cs2[lo]) / (hi - lo) - m * m, 1e-12))
        has_pred = np.zeros(nc, bool)
        has_pred[[c // cpc for c in predicted]] = True
        score = x + bias * has_pred
        active = np.argsort(-score, kind="stable")[:k_active].tolist()
        win, predicted, _ = activate_cells(active, predicted, forward, cpc, None, learn=False)
        codes.append(sorted(set(win)))
    ptr = np.cumsum([0] + [len(w) for w in codes])
    idx = np.concatenate([np.asarray(w, np.int64) for w in codes]) if ptr[-1] else np.zeros(0, np.int64)
    return sp.csr_matrix((np.ones(idx.size, bool), idx, ptr), shape=(q_sdr.shape[0], nc * cpc))


def grid_rows(subset: str) -> list[tuple]:
    """(label, kind, k, standardise, conf) of every row of the study for ``subset``."""
    rows = []
    for k in (40, 200):
        for st in ("none", "fit"):
            rows.append((f"pairwise SDR overlap, k={k}, standardise={st}", "pairwise", k, st, {}))
            rows.append((f"rSHOSM paper (threshold + k_active fallback), k={k}, standardise={st}", "rshosm", k, st, {}))
    if subset == "358":
        for k_act, window, bias in ((10, 0, 0.0), (30, 0, 0.0), (30, 100, 0.0), (30, 100, 3.0), (10, 100, 3.0)):
            rows.append((f"rSHOSM binary, top-{k_act} query minicolumns, window={window}, bias={bias}, k=200",
                         "topk", 200, "fit", {"k_active": k_act, "window": window, "bias": bias}))
    base = {"stay": None, "skip": None, "direction": "forward", "normalise": "none"}
    steps = [
        ("graded evidence, forward only", {}),
        ("+ both directions", {"direction": "both"}),
        ("+ stay/skip 0.05", {"direction": "both", "stay": 0.05, "skip": 0.05}),
        ("+ per-query normalisation (= rshosm-seq defaults)", {"direction": "both", "stay": 0.05, "skip": 0.05,
                                                               "normalise": "query"}),
    ]
    for k in (40, 200):
        for label, c in steps:
            rows.append((f"rshosm-seq {label}, k={k}", "rshosm-seq", k, "fit", {**base, **c}))
    for k in (40, 200):
        for thr in (0.25, 0.5):
            rows.append((f"rshosm-seq defaults but threshold={thr} (paper: 0.25), k={k}", "rshosm-seq", k, "fit",
                         {"threshold": thr}))
    rows.append(("rSHOSM paper but threshold=0.75, k=200", "rshosm", 200, "fit", {"threshold": 0.75}))
    rows.append(("rshosm-seq defaults but p_extra=0 (SHOSM), k=200", "rshosm-seq", 200, "fit", {"p_extra": 0.0}))
    rows.append(("rshosm-seq defaults but decay=0.8, k=200", "rshosm-seq", 200, "fit", {"decay": 0.8}))
    rows.append(("rshosm-seq defaults but decay=0.95, k=200", "rshosm-seq", 200, "fit", {"decay": 0.95}))
    rows.append(("rshosm-seq defaults but standardise=none, k=200", "rshosm-seq", 200, "none", {}))
    if subset == "358":
        rows += segment_rows()
    return rows


def segment_rows() -> list[tuple]:
    """Rows of the feed-forward segment study (:func:`research.studies.ff_segments.segment_codes`), k = 200.

    ``teach_on``: ``"query"`` teaches on the query traverse itself (online, or
    transductive for a second pass); ``"shifted"`` on the winter frames halfway
    between the subset's (full list ``[5::10]``), which are not query frames.
    """
    spec = [
        ("teacher off (= paper rSHOSM, literal)", {"teach_below": 0}),
        ("teacher when no minicolumn is active, online", {"teach_below": 1}),
        ("teacher when none active, 2nd pass after teaching on the query (transductive)",
         {"teach_below": 1, "read": "after"}),
        ("teacher when none active, at most 2 segments, online", {"teach_below": 1, "max_segments": 2}),
        ("confirmed-prediction teacher when none active, online", {"teach_below": 1, "confirmed_only": True}),
        ("confirmed teacher when fewer than 3 active, online", {"teach_below": 3, "confirmed_only": True}),
        ("confirmed teacher always, at most 2 segments, online",
         {"teach_below": 10**9, "confirmed_only": True, "max_segments": 2}),
        ("confirmed teacher when none active, 2nd pass after teaching on the query (transductive)",
         {"teach_below": 1, "confirmed_only": True, "read": "after"}),
        ("confirmed teacher when none active, 2nd pass after teaching on held-out winter frames",
         {"teach_below": 1, "confirmed_only": True, "read": "after", "teach_on": "shifted"}),
        ("upper bound: ground truth teaches held-out winter frames, 2nd pass",
         {"teacher": "labels", "read": "after", "teach_on": "shifted"}),
        ("sanity check: ground truth teaches the query itself, 2nd pass (transductive)",
         {"teacher": "labels", "read": "after"}),
    ]
    return [(f"segments: {label}, k=200", "segments", 200, "fit", conf) for label, conf in spec]


def _segment_similarity(a, b, conf, teach_sdrs):
    """Overlap of database and query winner codes of one segment row, and the row's counts."""
    conf = dict(conf)
    teach_sdr = teach_sdrs() if conf.pop("teach_on", "query") == "shifted" else None
    db_codes, q_codes, stats = segment_codes(a, b, teach_sdr=teach_sdr, **conf)
    return overlap_similarity(db_codes, q_codes), stats


def _fmt(stats: dict) -> str:
    p = stats["teacher_precision"]
    return "n/a" if p is None else f"{p:.2f}"


def run_grid(subset: str, out, data=None, progress: bool = True) -> str:
    """Run every :func:`grid_rows` row; write ``grid.json`` and ``grid.md`` to ``out``; return the table."""
    out = Path(out)
    root = find_dataset(data)
    names = frame_names(root, subset)
    db_desc = pixel_descriptors(root, "summer", names, out / "cache", progress)
    q_desc = pixel_descriptors(root, "winter", names, out / "cache", progress)
    n = len(names)
    gh, gs = groundtruth.gt_from_tolerance(n, n, 1), groundtruth.gt_from_tolerance(n, n, 3)
    sdrs, results, shifted = {}, [], {}

    def teach_sdrs():
        # winter frames halfway between the subset's: a second winter traverse that is not the query
        if not shifted:
            s_names = frame_names(root, "full")[5::10]
            s_desc = pixel_descriptors(root, "winter", s_names, out / "cache", progress)
            shifted["sdr"] = encode_sdrs(db_desc, s_desc, k=200, standardise="fit")[1]
        return shifted["sdr"]

    rows = grid_rows(subset)
    it = rows
    if progress:
        from tqdm import tqdm

        it = tqdm(rows, desc="variants", unit="row")
    for label, kind, k, st, conf in it:
        if (k, st) not in sdrs:
            sdrs[k, st] = encode_sdrs(db_desc, q_desc, k=k, standardise=st)
        a, b = sdrs[k, st]
        if kind == "segments" and conf.get("teach_on") == "shifted":
            teach_sdrs()  # load and encode outside the timed region: CPU s is the method's alone
        c0 = time.process_time()
        extra = None
        if kind == "topk":
            mem = SequenceMemory(seed=0)
            db_codes = mem.run(a)
            mem.reset()
            S = overlap_similarity(*pad_codes(db_codes, binary_topk_query(mem, b, **conf)))
        elif kind == "segments":
            S, extra = _segment_similarity(a, b, conf, teach_sdrs)
        else:
            method = "pairwise" if kind == "pairwise" else kind
            S = match(method, EncodedTraverse(names, sdr=a), EncodedTraverse(names, sdr=b), conf).similarity
        cpu = time.process_time() - c0
        m = E.evaluate(S, gh, gs)
        results.append({"variant": label, "method": kind, "k": k, "standardise": st, "conf": conf,
                        "auc_pr": m["auc_pr"], "recall_at_100p": m["recall_at_100p"],
                        "recall_at_1": m["recall_at_1"], "cpu_seconds": cpu, **({"segments": extra} if extra else {})})
    out.mkdir(parents=True, exist_ok=True)
    _io.save_json(out / "grid.json", {"subset": subset, "frames": n, "rows": results})
    lines = [f"**rSHOSM variants, Nordland {n} frames (subset {subset})**", "",
             "| variant | AUC | R@100P | R@1 | CPU s |", "|---|---:|---:|---:|---:|"]
    lines += [f"| {r['variant']} | {r['auc_pr']:.3f} | {r['recall_at_100p']:.3f} | {r['recall_at_1']:.3f} | "
              f"{r['cpu_seconds']:.1f} |" for r in results]
    seg = [r for r in results if "segments" in r]
    if seg:
        lines += ["", "Segment rows: database minicolumns, query frames on which the teacher added segments, "
                  "segments added, fraction of them on a minicolumn of the right place (|i - t| <= 1; "
                  "only when the query itself is taught)", ""]
        lines += [f"- {r['variant']}: {r['segments']['columns']} minicolumns, {r['segments']['taught_frames']} "
                  f"frames, {r['segments']['taught_segments']} segments, precision {_fmt(r['segments'])}"
                  for r in seg]
    table = "\n".join(lines) + "\n"
    with _io.atomic_open(out / "grid.md", "w", encoding="utf-8") as fh:
        fh.write(table)
    return table


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m research.studies.nordland_variants",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--subset", choices=["358", "full"], default="358")
    ap.add_argument("--out", required=True, help="output folder (grid.json, grid.md, cache/)")
    ap.add_argument("--data", default=None, help="folder holding summer/ and winter/ (default: as vpr nordland)")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    try:
        print(run_grid(a.subset, a.out, data=a.data, progress=not a.no_progress), end="")
    except (DatasetError, ValueError) as e:
        print(f"{ap.prog}: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
