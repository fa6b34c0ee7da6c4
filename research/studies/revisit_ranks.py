"""Where the right place ranks when a stream comes back in another condition: can a bounded beam keep it?

A beam that carries a bounded number of hypotheses (the ``max_beam`` cells of
largest evidence, or the cells of the N best places) costs the same per frame
at any length, but keeps the right place only if it ranks among those it
keeps at every frame, from the first frame of the revisit on. This study
runs ``vpr.shosm.loop_evidence`` uncapped (every cell with evidence carried)
on the loop streams of ``research.studies.loop_streams`` with a change of condition
(Gardens Point day_left -> day_right, Nordland summer -> winter every 10th file
and every file) and prints, for the frames after the revisit begins, the rank
of the best right earlier frame among all earlier frames with evidence
(0: it is the best), as a count and as a fraction of them.

Usage: VPR_DATASETS=../shared/datasets python -m research.studies.revisit_ranks [--preset fast] [--cache DIR]
"""
from __future__ import annotations

import argparse

import numpy as np

from research.studies.loop_streams import load_stream
from vpr.shosm import loop_evidence

EXCLUDE = 30
STREAMS = ("gardens_point", "nordland_stream", "nordland_full")
#: frames after the revisit begins, printed one by one
SHOWN = (0, 1, 2, 5, 10, 15, 20, 30, 50, 100)


def ranks(stream) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(revisit frames, rank of the best right earlier frame, earlier frames with evidence) per revisit frame."""
    ev = loop_evidence(stream.x, exclude=EXCLUDE, top_k=None, dense_max=10**6, caps=False)
    S = np.asarray(ev.similarity)
    hard = np.triu(stream.hard, EXCLUDE)
    frames = np.flatnonzero(hard.any(axis=0))
    rank, live = np.zeros(frames.size, np.int64), np.zeros(frames.size, np.int64)
    for k, j in enumerate(frames):
        col = S[: j - EXCLUDE + 1, j]
        live[k] = int((col > ev.fill[j]).sum())
        rank[k] = int((col > col[hard[: j - EXCLUDE + 1, j]].max()).sum())
    return frames, rank, live


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="fast", help="the preset whose loop encoder encodes the streams")
    ap.add_argument("--cache", default="results/loop_streams", help="encoded streams are cached here")
    ap.add_argument("--data", default=None, help="datasets folder (default: $VPR_DATASETS or ../shared/datasets)")
    a = ap.parse_args(argv)
    print(f"preset {a.preset}; rank of the right place among the earlier frames with evidence (uncapped beam), "
          "frames counted from the first revisit frame\n")
    print("| stream | earlier frames with evidence | " + " | ".join(f"+{s}" for s in SHOWN)
          + " | largest rank before the first rank 0 | frames rank < 800 |")
    print("|---|---|" + "---|" * (len(SHOWN) + 2))
    for name in STREAMS:
        st = load_stream(name, a.preset, cache=a.cache, data=a.data)
        frames, rank, live = ranks(st)
        cells = [f"{rank[s]:,} ({rank[s] / max(live[s], 1):.0%})" if s < rank.size else "-" for s in SHOWN]
        first = int(np.argmax(rank == 0)) if (rank == 0).any() else rank.size
        before = f"{rank[:first].max():,} (frame +{int(np.argmax(rank[:first]))})" if first else "-"
        print(f"| {name} ({len(st):,} frames) | {int(np.median(live)):,} (median) | " + " | ".join(cells)
              + f" | {before} | {np.mean(rank < 800):.0%} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
