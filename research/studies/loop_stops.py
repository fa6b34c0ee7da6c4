"""The stop check of ``vpr loops``: which closures the path accepts does it refuse, and are they stops?

A closure ``b -> j`` within one run is refused as a stop (:func:`vpr.similarity.stationary`, ``LoopConf.stop_ratio``)
when every frame between ``b`` and ``j`` shares at least ``stop_ratio`` times the bits ``b`` shares with ``j``: the
camera never left. Two frames of ``k`` active bits in ``n`` share about ``k * k / n`` by chance (200 of 2,048: about
20); counted raw, where ``b`` shares little more than that with ``j``, the frames in between do too, and the check
reads a stop. The check counts the bits shared beyond chance (each frame's overlap with ``j`` minus
``|row| * |j| / n``; no stop where ``b`` shares none beyond it).

For every stream of ``research.studies.loop_streams`` and both presets: the closures the path rule accepts without
the check
(``stop_ratio`` 0), and those the check refuses counting raw bits (:func:`stop_raw`) and beyond chance
(:func:`vpr.similarity.stationary`): right / soft / false (forward drives: onto an identical copy counted as soft).

Usage: python -m research.studies.loop_stops [--cache DIR] [--data DIR] [--presets default,fast]
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from research.studies.loop_decisions import aliases, evidence
from research.studies.loop_streams import FORWARD, REAL_REVISITS, RENDERED_REVISITS, load_stream
from vpr.shosm import LoopConf, accept_loops
from vpr.similarity import stationary


def _overlaps(x: sp.csr_matrix, b: int, j: int) -> np.ndarray:
    """Overlaps of rows ``b .. j - 1`` with row ``j``."""
    rows = x[b:j + 1].astype(np.int32)
    return np.asarray((rows[:-1] @ rows[-1].T).toarray()).ravel().astype(float)


def stop_raw(x: sp.csr_matrix, b: int, j: int, ratio: float) -> bool:
    """The stop check on raw overlaps (no frame in between shares fewer than ``ratio`` times ``b``'s bits)."""
    o = _overlaps(x, b, j)
    return bool(o[0] > 0 and (o[1:] >= ratio * o[0]).all())


def stop_beyond_chance(x: sp.csr_matrix, b: int, j: int, ratio: float) -> bool:
    """:func:`vpr.similarity.stationary` of ``x``'s rows (bits shared beyond chance)."""
    if not x.has_sorted_indices:
        x = x.copy()
        x.sort_indices()
    return bool(stationary(x.indptr.astype(np.int64), x.indices.astype(np.int64), b, j, ratio, x.shape[1]))


def refused(stream, name: str, accepted_b, ratio: float) -> dict:
    """{check: [right, soft or onto a copy, false]} of the closures ``accepted_b`` ((b, j) pairs) each check
    refuses."""
    x = stream.x.tocsr().copy()
    x.sort_indices()
    copy = aliases(name.split("@")[0]) if stream.forward_only else None
    out = {"raw": [0, 0, 0], "beyond chance": [0, 0, 0]}
    for b, j in accepted_b:
        for key, check in (("raw", stop_raw), ("beyond chance", stop_beyond_chance)):
            if not check(x, b, j, ratio):
                continue
            if stream.forward_only:
                out[key][1 if copy is not None and copy[b, j] else 2] += 1
            else:
                out[key][0 if stream.hard[b, j] else 1 if stream.soft is not None and stream.soft[b, j] else 2] += 1
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cache", default="results/loop_streams")
    ap.add_argument("--data", default=os.environ.get("VPR_DATASETS", "../shared/datasets"))
    ap.add_argument("--presets", default="default,fast")
    a = ap.parse_args(argv)
    cache, ratio = Path(a.cache), LoopConf().stop_ratio
    print(f"The path rule's closures (stop_ratio 0) refused by the stop check at stop_ratio {ratio}: right / soft "
          "(forward: onto a copy) / false")
    print("| stream | accepted by the path | refused counting raw bits | refused beyond chance (the check) |")
    print("|---|---|---|---|")
    for preset in a.presets.split(","):
        for name in (*REAL_REVISITS, *RENDERED_REVISITS, *FORWARD):
            stream = load_stream(name, preset, cache, data=a.data)
            d = accept_loops(evidence(stream, cache, preset), LoopConf(stop_ratio=0.0), sdr=stream.x)
            js = np.flatnonzero(d.accepted & (d.best >= 0))
            r = refused(stream, name, [(int(d.best[j]), int(j)) for j in js], ratio)
            cells = [" / ".join(map(str, r[k])) for k in ("raw", "beyond chance")]
            print(f"| {preset}: {name} | {js.size} | {cells[0]} | {cells[1]} |", flush=True)


if __name__ == "__main__":
    main()
