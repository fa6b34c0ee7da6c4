"""What ``vpr match`` / ``compare`` accept with rshosm-seq: the path rule of ``vpr localize`` on the batch evidence.

``rshosm-seq``'s ``accepted`` in database x query matching is the decision a
robot localising against the map takes (:func:`vpr.shosm.accept_path`,
:class:`vpr.shosm.PathConf`): the best database frame's margin over the
strongest other place, minus ``drift``, summed while the best frame moves on;
accepted at ``min_score``. This study runs the method as ``vpr match`` does
(each traverse encoded with a preset's encoder, standardised on its own
frames; the evidence of both directions) on every case, keeps the z-score
matrix, and decides under a grid of rules.

Cases (database / query):

- ``nordland_358`` / ``_120`` / ``_3576``: Nordland summer / winter, every 10th,
  30th, every file; hard within 10 source frames, soft within 30 (as
  ``research.studies.localize_decisions``).
- ``nordland_half``: the first half of summer / all of winter (every 10th): half
  the queries are not on the map, every answer there is false.
- ``nordland_gap``: summer every 10th without its middle third / all of winter: the
  query leaves the map in its middle and comes back (reported, not chosen on).
- ``gardens_point``: day_left / day_right (hard 2 frames, soft 8).
- ``two_seasons``: the rendered demo (summer day 476 / winter night 533 frames at
  160 x 120; hard 3 m, soft 10 m), rendered here.
- ``speed_change``: rendered, slow / fast (hard 5 m, soft 10 m).

The rule is chosen as ``research.studies.localize_decisions`` chooses: precision of the
accepted at least ``--min-precision`` (0.99) on every real case with the
``default`` preset, then the largest mean recall; the rendered cases and the
``fast`` preset are reported, and every case is held out in turn.

Usage: python -m research.studies.match_decisions [--cache DIR] [--data DIR] [--presets default,fast]
"""
from __future__ import annotations

import argparse
import itertools
import os
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from research.studies.localize_decisions import best_rule, case_sources, cell, measure, print_held_out, rendered_pair
from vpr import methods, presets
from vpr.shosm import PathConf, accept_path

CASES = ("nordland_358", "nordland_120", "nordland_3576", "nordland_half", "nordland_gap", "gardens_point",
         "two_seasons", "speed_change")
REAL = ("nordland_358", "nordland_120", "nordland_3576", "nordland_half", "gardens_point")
CHOSEN_PRESET = "default"
DRIFTS = (0.25, 0.5, 1.0, 1.5, 2.0, 3.0)
SCORES = (8.0, 12.0, 16.0, 24.0, 32.0, 48.0, 64.0)


def _case_sources(case: str, data: Path, tmp: Path):
    if case != "two_seasons":
        return case_sources(case, data, tmp)
    return rendered_pair("two_seasons", "summer_day", "winter_night", tmp, 3.0, 10.0)


def match_run(case: str, preset: str, data: Path, tmp: Path):
    """``rshosm-seq``'s match of a case as ``vpr match`` runs it (each traverse encoded with ``preset``'s encoder,
    standardised on its own frames): (map SDRs, query SDRs, MatchResult, hard, soft over the frames read)."""
    import encoders
    from pipelines.extract import extract

    m, q, hard, soft = _case_sources(case, data, tmp)
    s = presets.resolve(preset)
    enc = encoders.get(s["encoder"], **s["encoder_conf"])
    feats = [extract(src, enc, ("sdr",), progress=False) for src in (m, q)]  # each fitted on itself, as vpr match
    res = methods.get("rshosm-seq").match(feats[0].features, feats[1].features)
    rows = [{k: r for r, k in enumerate(src.indices())} for src in (m, q)]
    ri = [rows[0][i] for i in feats[0].indices]
    ci = [rows[1][i] for i in feats[1].indices]
    return feats[0].features.sdr, feats[1].features.sdr, res, hard[np.ix_(ri, ci)], soft[np.ix_(ri, ci)]


def evidence(case: str, preset: str, data: Path, cache: Path):
    """(S: the z-score matrix of ``vpr match``, hard, soft) of a case, cached."""
    path = cache / f"match-{case}-{preset}.npz"
    if path.is_file():
        with np.load(path) as z:
            S = sp.csr_matrix((z["val"], z["idx"], z["ptr"]), shape=tuple(z["shape"])) if "ptr" in z else z["S"]
            return S, z["hard"], z["soft"]
    _, _, res, hard, soft = match_run(case, preset, data, cache)
    S = res.similarity
    if sp.issparse(S):
        S = sp.csr_matrix(S)
        np.savez(path, val=S.data, idx=S.indices, ptr=S.indptr, shape=S.shape, hard=hard, soft=soft)
    else:
        np.savez(path, S=np.asarray(S, np.float32), hard=hard, soft=soft)
    return S, hard, soft


def decide(S, conf: PathConf):
    d = accept_path(S, conf)
    best, ok = d.best, d.accepted
    return best, ok


def choose(results: dict, keys: list[str], min_precision: float):
    keys = [k for k in keys if k.split(": ")[-1] in REAL and k.split(": ")[0] == CHOSEN_PRESET]
    return best_rule(results, keys, min_precision, lambda rule: rule[1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", default="results/match_decisions", help="evidence matrices are cached here")
    ap.add_argument("--data", default=None, help="datasets folder (default: $VPR_DATASETS or ../shared/datasets)")
    ap.add_argument("--presets", default="default,fast")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--min-precision", type=float, default=0.99)
    a = ap.parse_args(argv)
    cache = Path(a.cache)
    cache.mkdir(parents=True, exist_ok=True)
    data = Path(a.data or os.environ.get("VPR_DATASETS", "../shared/datasets"))
    cases = [c for c in a.cases.split(",") if c]
    keys, ev = [], {}
    for preset in [p.strip() for p in a.presets.split(",") if p.strip()]:
        for case in cases:
            t = time.perf_counter()
            k = f"{preset}: {case}"
            ev[k] = evidence(case, preset, data, cache)
            keys.append(k)
            print(f"{k}: {ev[k][0].shape[0]} x {ev[k][0].shape[1]} ({time.perf_counter() - t:.0f} s)", flush=True)
    results = {}
    for drift, score in itertools.product(DRIFTS, SCORES):
        conf = PathConf(drift=drift, min_score=score)
        results[(drift, score)] = {k: measure(*decide(S, conf), h, s) for k, (S, h, s) in ev.items()}
    print("\nPer case: recall of the accepted (their precision, how many accepted).\n")
    print("| rule | " + " | ".join(keys) + " |")
    print("|---|" + "---|" * len(keys))
    for rule, per in results.items():
        print(f"| drift {rule[0]:g}, min_score {rule[1]:g} | " + " | ".join(cell(per[k]) for k in keys) + " |")
    chosen = choose(results, keys, a.min_precision)
    print("\nchosen: " + ("none reaches the precision" if chosen is None else
                          f"drift {chosen[0]:g}, min_score {chosen[1]:g}"))
    print_held_out(results, keys, cases, lambda ks: choose(results, ks, a.min_precision),
                   lambda rule: f"drift {rule[0]:g}, min_score {rule[1]:g}")
    conf = PathConf()
    print(f"\nWith the defaults (PathConf, those of vpr localize: drift {conf.drift:g}, min_score "
          f"{conf.min_score:g}):\n")
    print("| case | database | query | R@1 | accepted | precision of accepted | recall of accepted |")
    print("|---|---|---|---|---|---|---|")
    for k, (S, h, s) in ev.items():
        r = measure(*decide(S, conf), h, s)
        p = "-" if r["precision"] is None else f"{r['precision']:.3f} ({r['false']} wrong)"
        print(f"| {k} | {S.shape[0]:,} | {S.shape[1]:,} | {r['r1']:.2f} | {r['accepted']} | {p} | {r['recall']:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
