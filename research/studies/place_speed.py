"""A revisit driven faster than the evidence follows: where do `vpr loops` answers land, and what places them?

One run with loops in it (the rendered ``loop_revisits`` laps at 320 x 240,
:func:`research.studies.speed_models.laps_streams`:
every frame, the later laps every 2nd frame (2x), the first lap every 2nd frame (the later at 0.5x); hard 5 m,
soft 10 m) and Gardens Point day_left then day_right in one folder (frame numbers as positions; hard 2, soft 8).

1. ``vpr loops`` (defaults, geometry on) under each ``rshosm-seq.place_frames`` of ``--frames`` (0: the evidence's
   answer): accepted, P(acc), R(acc), false.
2. The accepted closures of ``place_frames=0`` placed by :class:`vpr.shosm.Placement` (the default frames) gated
   by the path's speed (``RATE_RATIO``, the default) and ungated (every closure answered by the best path):
   right / soft / false, and how many answers moved.

Usage: python -m research.studies.place_speed [--data DIR] [--out DIR] [--frames 0,5,10,15,20,30,40]
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from pipelines.extract import load_cache
from research.studies.speed_models import LAPS_RADIUS, LAPS_SOFT, laps_streams, run_quietly
from vpr.sdr import RowLog
from vpr.shosm import LoopConf, Placement
from vpr.types import RATE_RATIO, Decision

GP_RADIUS, GP_SOFT = 2, 8


def streams(data: Path, root: Path) -> dict:
    """{key: (name, folder, positions file, hard, soft)}: the laps and Gardens Point in one folder."""
    out = {k: (name, folder, pos, LAPS_RADIUS, LAPS_SOFT) for k, (name, folder, pos) in laps_streams(root).items()}
    gp = data / "gardens_point_day"
    files = sorted((gp / "day_left").iterdir()) + sorted((gp / "day_right").iterdir())
    folder, positions = root / "one_run" / "gp_1x", root / "one_run" / "gp_1x.csv"
    if not folder.exists():
        folder.mkdir(parents=True)
        for i, f in enumerate(files):
            (folder / f"{i:05d}{f.suffix}").symlink_to(f.resolve())
    positions.write_text("frame,x,y\n" + "".join(f"{i},{i % 200},0\n" for i in range(len(files))))
    out["gp_1x"] = ("Gardens Point day_left + day_right, one folder", folder, positions, GP_RADIUS, GP_SOFT)
    return out


def loops(key, stream, root: Path, frames: int) -> Path:
    """``vpr loops`` of a stream with ``place_frames=frames`` (run once, its SDRs cached); its output folder."""
    _, folder, positions, hard, soft = stream
    out = root / "place" / f"{key}-{frames}"
    if not (out / "metrics.json").exists():
        run_quietly(["loops", folder, "--out", out, "--gt", positions, "--radius", hard, "--gt-soft", soft,
                     "--cache", root / "place" / "cache", "--method-conf", f"rshosm-seq.place_frames={frames}"])
    return out


def placed(key, stream, root: Path, speed: float) -> tuple[list[int], list[int], int]:
    """The closures of ``place_frames=0`` placed with the default frames, gated from ``speed`` (0: ungated): right /
    soft / false before and after, and how many answers moved."""
    _, folder, positions, hard, soft = stream
    run = loops(key, stream, root, 0)
    x = load_cache(next((root / "place" / "cache").glob(f"{folder.name}-*.npz"))).features.sdr.tocsr()
    with open(positions, newline="") as fh:
        xy = np.array([[float(r["x"]), float(r["y"])] for r in csv.DictReader(fh)])
    with open(run / "rshosm-seq" / "matches.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["accepted"] == "1"]
    loop = LoopConf()
    p = Placement(loop.place_frames, 30, loop.back, loop.ahead, x.shape[1], speed=speed)
    log = RowLog(x.indptr, x.indices)
    before, after, moved = [0, 0, 0], [0, 0, 0], 0

    def kind(j: int, b: int) -> int:
        d = float(np.linalg.norm(xy[j] - xy[b]))
        return 0 if d <= hard else 1 if d <= soft else 2

    for r in rows:
        j, b = int(r["query"]), int(r["best_db"])
        c = p([Decision(b, 0.0, True, 0.0, j)], log, [0])[0].best
        before[kind(j, b)] += 1
        after[kind(j, c)] += 1
        moved += c != b
    return before, after, moved


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=None, help="datasets folder (default: $VPR_DATASETS or ../shared/datasets)")
    ap.add_argument("--out", default=None, help="work folder (renders, runs; default: a temporary one)")
    ap.add_argument("--frames", default="0,5,10,15,20,30,40", help="place_frames settings")
    a = ap.parse_args(argv)
    data = Path(a.data or os.environ.get("VPR_DATASETS", "../shared/datasets"))
    settings = [int(v) for v in a.frames.split(",")]
    with tempfile.TemporaryDirectory() as t:
        root = Path(a.out or t)
        all_streams = streams(data, root)
        print("vpr loops (defaults, geometry on) by rshosm-seq.place_frames: accepted, P(acc), R(acc), false")
        print("| place_frames | " + " | ".join(s[0] for s in all_streams.values()) + " |")
        print("|---|" + "---|" * len(all_streams))
        for frames in settings:
            cells = []
            for key, stream in all_streams.items():
                m = json.loads((loops(key, stream, root, frames) / "metrics.json").read_text())["methods"]["rshosm-seq"]
                prec = "-" if m["precision_accepted"] is None else f"{m['precision_accepted']:.3f}"
                cells.append(f"{m['n_accepted']}, {prec}, {m['recall_accepted']:.3f}, {m['n_false']}")
            print(f"| {frames} | " + " | ".join(cells) + " |", flush=True)
        print(f"\nThe closures of place_frames=0 placed by the {LoopConf().place_frames} frames up to them: right / "
              "soft / false before -> after (answers moved), gated by the path's speed (the default) and ungated")
        print("| stream | gated | ungated |")
        print("|---|---|---|")
        for key, stream in all_streams.items():
            cells = []
            for speed in (RATE_RATIO, 0.0):
                b, c, moved = placed(key, stream, root, speed)
                cells.append(f"{' / '.join(map(str, b))} -> {' / '.join(map(str, c))} ({moved})")
            print(f"| {stream[0]} | {' | '.join(cells)} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
