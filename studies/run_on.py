"""A revisit that leaves the earlier route: do `vpr loops`' answers stop where the place stops being the earlier one?

One stream each, made of frames of the datasets (or of renders) put one after the other as a robot
would record them: a first pass, a revisit of its first part, then places the first pass never saw
(the robot turned off). Every closure accepted after the turn is false. `vpr loops` of each with
its defaults (geometry on; blind on Nordland's 64 x 32), ground truth by place:

- Nordland every 10th file: summer 0-1190, winter 0-590 (the revisit), winter 2400-2990.
- Gardens Point: day_left 0-99, day_right 0-59 (the revisit, the other side of the path), day_right
  140-199.
- The rendered laps (320 x 240): the first lap, the first 100 frames of the second, then the
  rendered ``speed_change`` fast drive (another street, same renderer and size).

Printed per stream: accepted, P(acc), R(acc), false; the false closures within 30 frames after the
turn (the answers that run on along the earlier route), and those elsewhere. Then the evidence at each
frame's best earlier frame, raw (not standardised), over the 10 frames before the turn and the 10
after, and how a share of its median over the last 20 frames would tell the run-on apart.

A query that leaves a map in its middle (``vpr localize``) is ``studies.localize_decisions``'
``nordland_gap`` case.

Usage: python -m studies.run_on [--data DIR] [--out DIR]
"""
from __future__ import annotations

import argparse
import csv
import json
import os
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from encoders.extract import load_cache
from studies.cells import decisions_cell
from studies.localize_decisions import recent_median
from studies.speed_models import run_quietly
from vpr.shosm import loop_evidence

RUN_ON = 30


def _stream(out: Path, name: str, parts) -> tuple[Path, Path, int]:
    """A list file of the parts' frames one after the other, its positions file (``frame, x, y``), and the frame
    where the last part (the turn) starts. ``parts``: [(frames, [(x, y) per frame])]."""
    listing, positions = out / f"{name}.txt", out / f"{name}.csv"
    turn = sum(len(files) for files, _ in parts[:-1])
    with open(listing, "w") as fl, open(positions, "w", newline="") as fp:
        w = csv.writer(fp)
        w.writerow(["frame", "x", "y"])
        k = 0
        for files, xy in parts:
            for f, (x, y) in zip(files, xy, strict=True):
                fl.write(f"{Path(f).resolve()}\n")
                w.writerow([k, x, y])
                k += 1
    return listing, positions, turn


def streams(data: Path, out: Path) -> dict:
    """{name: (list file, positions file, turn frame, radius, soft)}."""
    nl = data / "nordland_trimmed"
    summer, winter = sorted((nl / "summer").glob("*.png")), sorted((nl / "winter").glob("*.png"))

    def nordland(files, positions):
        return [files[p] for p in positions], [(p, 0) for p in positions]

    gp = data / "gardens_point_day"
    left, right = sorted((gp / "day_left").iterdir()), sorted((gp / "day_right").iterdir())
    rendered = out / "renders"
    for scene, only in (("loop_revisits", []), ("speed_change", ["--traverse", "fast"])):
        if not (rendered / scene / "scene.json").exists():
            run_quietly(["render", scene, "--out", rendered / scene, *only])
    with open(rendered / "loop_revisits" / "ground_truth.csv", newline="") as fh:
        laps = [r for r in csv.DictReader(fh) if r["traverse"] == "laps"]
    length = json.loads((rendered / "loop_revisits" / "scene.json").read_text())["world"]["length"]
    lap_files = sorted((rendered / "loop_revisits" / "laps").glob("*.png"))
    first = [j for j, r in enumerate(laps) if float(r["route_pos"]) < length]
    second = [j for j, r in enumerate(laps) if float(r["route_pos"]) >= length][:100]
    fast = sorted((rendered / "speed_change" / "fast").glob("*.png"))
    return {
        "nordland": (*_stream(out, "nordland", [nordland(summer, range(0, 1200, 10)),
                                                nordland(winter, range(0, 600, 10)),
                                                nordland(winter, range(2400, 3000, 10))]), 10, 30),
        "gardens_point": (*_stream(out, "gardens_point", [(left[:100], [(i, 0) for i in range(100)]),
                                                          (right[:60], [(i, 0) for i in range(60)]),
                                                          (right[140:], [(i, 0) for i in range(140, 200)])]), 2, 8),
        "laps": (*_stream(out, "laps", [([lap_files[j] for j in first], [(laps[j]["x"], laps[j]["y"]) for j in first]),
                                        ([lap_files[j] for j in second],
                                         [(laps[j]["x"], laps[j]["y"]) for j in second]),
                                        (fast, [(1e6, 1e6 + i) for i in range(len(fast))])]), 5, 10),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=None, help="datasets folder (default: $VPR_DATASETS or ../shared/datasets)")
    ap.add_argument("--out", default="results/run_on")
    a = ap.parse_args(argv)
    data = Path(a.data or os.environ.get("VPR_DATASETS", "../shared/datasets"))
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"vpr loops of a revisit that leaves the earlier route (defaults): accepted, P(acc), R(acc), false; false "
          f"closures within {RUN_ON} frames after the turn (query -> earlier frame) and elsewhere")
    print("| stream | frames | turn at | decisions | run on after the turn | false elsewhere |")
    print("|---|---|---|---|---|---|")
    fading = {}
    for name, (listing, positions, turn, radius, soft) in streams(data, out).items():
        run = out / f"{name}-out"
        if not (run / "metrics.json").exists():
            run_quietly(["loops", listing, "--out", run, "--gt", positions, "--radius", radius, "--gt-soft", soft])
        m = json.loads((run / "metrics.json").read_text())["methods"]["rshosm-seq"]
        with open(run / "rshosm-seq" / "matches.csv", newline="") as fh:
            rows = list(csv.DictReader(fh))
        false = [(int(r["query"]), int(r["best_db"])) for r in rows if r["accepted"] == "1" and r["right"] == "0"]
        on = [f"{q} -> {b}" for q, b in false if turn <= q < turn + RUN_ON]
        print(f"| {name} | {len(rows)} | {turn} | {decisions_cell(m, frames=False)}, {m['n_false']} | "
              f"{len(on)}: {', '.join(on[:6])}{' ...' if len(on) > 6 else ''} | "
              f"{len(false) - len(on)} |", flush=True)
        fading[name] = (run, rows, turn)
    print("\nThe raw evidence at the best earlier frame (mean of the 10 frames before the turn / the 10 after); an "
          f"accepted closure refused below a share of its median over the last {FADE_WINDOW} frames: right ones "
          "lost / false ones left")
    print("| stream | before / after the turn | " + " | ".join(f"share {r:g}" for r in FADES) + " |")
    print("|---|---|" + "---|" * len(FADES))
    for name, (run, rows, turn) in fading.items():
        raw = raw_at_best(run)
        right = np.array([r["accepted"] == "1" and r["right"] == "1" for r in rows])
        false = np.array([r["accepted"] == "1" and r["right"] == "0" for r in rows])
        ref = recent_median(raw, FADE_WINDOW)
        cells = [f"{int((right & (raw < r * ref)).sum())} / {int((false & (raw >= r * ref)).sum())} of "
                 f"{int(right.sum())} / {int(false.sum())}" for r in FADES]
        print(f"| {name} | {raw[turn - 10:turn].mean():.2f} / {raw[turn:turn + 10].mean():.2f} | " + " | ".join(cells)
              + " |", flush=True)
    return 0


FADES, FADE_WINDOW = (0.5, 0.7, 0.8), 20


def raw_at_best(run: Path) -> np.ndarray:
    """Per frame, the raw evidence (``normalise="none"``) at the best earlier frame of the standardised evidence, as
    ``vpr loops`` scored the run's cached SDRs (exclude 30)."""
    x = load_cache(next((run / "cache").glob("*.npz"))).features.sdr
    best = loop_evidence(x, exclude=30).decision.best
    S = loop_evidence(x, exclude=30, normalise="none").similarity
    S = S.toarray() if sp.issparse(S) else S
    return np.array([S[b, j] if b >= 0 else 0.0 for j, b in enumerate(best)])


if __name__ == "__main__":
    raise SystemExit(main())
