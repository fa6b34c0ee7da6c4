"""Would `vpr compare` gain from loop closure's confirmation? The look-ahead of its accepted answers, case by case.

``vpr loops`` keeps a closure only where the frames after it single out its place on their own
(:class:`vpr.shosm.Confirmation`). ``vpr compare`` (``rshosm-seq``, database x query, both
directions) has the same run-on where a query leaves the map in its middle
(``research.studies.match_decisions``' ``nordland_gap``). This study runs ``rshosm-seq``'s match as ``vpr
compare`` does (each traverse encoded with the ``default`` preset, standardised on its own frames) and
scores every accepted answer (query ``j`` onto map frame ``b``) with the look-ahead of the query frames
``j .. j + 19`` against every map frame (:func:`vpr.shosm.confirm.look_ahead_z`, loop closure's
defaults); printed per case: the answers right / wrong / in the soft band, and how many of each a bar
of ``--z`` would keep. Nothing here is decided by ``vpr compare``: it measures the next step.

Cases (``research.studies.localize_decisions``' sources): ``nordland_gap``, ``nordland_358``, ``nordland_half``,
``gardens_point``, ``two_seasons`` (the demo's scene at 160 x 120), ``speed_change``.

Usage: python -m research.studies.compare_ahead [--data DIR] [--out DIR] [--cases ...] [--z 2,2.5,3]
"""
from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import numpy as np
import scipy.sparse as sp

CASES = ("nordland_gap", "nordland_358", "nordland_half", "gardens_point", "two_seasons", "speed_change")


def answers(case: str, data: Path, tmp: Path):
    """(map SDRs, query SDRs, best, accepted, hard, soft) of ``vpr compare``'s rshosm-seq on a case."""
    from research.studies.match_decisions import match_run

    x_map, x_q, res, hard, soft = match_run(case, "default", data, tmp)
    return x_map, x_q, res.best, res.accepted, hard, soft


def look_aheads(x_map, x_q, best, accepted) -> dict[int, float]:
    """Each accepted query frame's look-ahead z of its answer (loop closure's frames, stay and skip)."""
    from vpr.shosm import EvidenceConf, LoopConf
    from vpr.shosm.confirm import look_ahead_z, standardised_overlaps

    n_db, T = x_map.shape[0], x_q.shape[0]
    both = sp.vstack([sp.csr_matrix(x_map), sp.csr_matrix(x_q)]).tocsr()
    both.sort_indices()
    ptr, ind = both.indptr.astype(np.int64), both.indices.astype(np.int64)
    z = [standardised_overlaps(ptr, ind, n_db + k, n_db, both.shape[1]) for k in range(T)]
    stay, skip = EvidenceConf().costs
    frames = LoopConf().confirm_frames
    return {j: look_ahead_z(z[j:min(T, j + frames)], int(best[j]), n_db, stay, skip)
            for j in np.flatnonzero(accepted)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=None, help="datasets folder (default: $VPR_DATASETS or ../shared/datasets)")
    ap.add_argument("--out", default=None, help="work folder (renders, lists; default: a temporary one)")
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES)
    ap.add_argument("--z", default="2,2.5,3", help="look-ahead bars")
    a = ap.parse_args(argv)
    data = Path(a.data or os.environ.get("VPR_DATASETS", "../shared/datasets"))
    bars = [float(v) for v in a.z.split(",")]
    with tempfile.TemporaryDirectory() as t:
        tmp = Path(a.out or t)
        tmp.mkdir(parents=True, exist_ok=True)
        print("`vpr compare`'s rshosm-seq (default preset): accepted answers right / wrong / soft, and those a "
              "look-ahead bar would keep")
        print("| case | accepted: right / wrong / soft | " + " | ".join(f"z >= {b:g}" for b in bars) + " |")
        print("|---|---|" + "---|" * len(bars))
        for case in a.cases:
            x_map, x_q, best, ok, hard, soft = answers(case, data, tmp)
            zs = look_aheads(x_map, x_q, best, ok)
            kind = {j: "right" if hard[best[j], j] else "soft" if soft[best[j], j] else "wrong" for j in zs}
            count = {k: sum(v == k for v in kind.values()) for k in ("right", "wrong", "soft")}
            cells = [" / ".join(str(sum(1 for j in zs if kind[j] == k and zs[j] >= b)) for k in ("right", "wrong",
                                                                                                    "soft"))
                     for b in bars]
            print(f"| {case} | {count['right']} / {count['wrong']} / {count['soft']} | " + " | ".join(cells) + " |",
                  flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
