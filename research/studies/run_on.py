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

``--confirm FRAMES:Z,...``: also each ``rshosm-seq.confirm_frames`` / ``confirm_z`` given (0: closures decided at
once), a table of false closures after the turn and right ones per setting (with ``research.studies.loop_decisions
--confirm-grid``, the grid the confirmation was chosen on).

A query that leaves a map in its middle (``vpr localize``) is ``research.studies.localize_decisions``'
``nordland_gap`` case.

Usage: python -m research.studies.run_on [--data DIR] [--out DIR] [--confirm 0:2,10:2,20:2]
"""
from __future__ import annotations

import argparse
import csv
import json
import os
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from pipelines.extract import load_cache
from research.studies.cells import decisions_cell
from research.studies.localize_decisions import recent_median
from research.studies.speed_models import run_quietly
from vpr.sdr import RowLog
from vpr.shosm import Confirmation, EvidenceConf, LoopConf, loop_evidence

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
    ap.add_argument("--confirm", default="", help="confirm_frames:confirm_z settings, comma-separated")
    a = ap.parse_args(argv)
    data = Path(a.data or os.environ.get("VPR_DATASETS", "../shared/datasets"))
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"vpr loops of a revisit that leaves the earlier route (defaults): accepted, P(acc), R(acc), false; false "
          f"closures within {RUN_ON} frames after the turn (query -> earlier frame) and elsewhere")
    print("| stream | frames | turn at | decisions | run on after the turn | false elsewhere |")
    print("|---|---|---|---|---|---|")
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
    loop = LoopConf()
    print(f"\nThe look-ahead of the closures accepted at once (`confirm_frames=0`): how far the next "
          f"{loop.confirm_frames} frames single out the answer (z over the other places; kept from "
          f"{loop.confirm_z:g}): right ones (min / median), false after the turn (median / max), false elsewhere (max)")
    print("| stream | right | false after the turn | false elsewhere |")
    print("|---|---|---|---|")
    for name, (listing, positions, turn, radius, soft) in streams(data, out).items():
        print(f"| {name} | {look_aheads(out, name, listing, positions, turn, radius, soft)} |", flush=True)
    if a.confirm:
        confirm_table(out, streams(data, out), [tuple(c.split(":")) for c in a.confirm.split(",")])
    print("\nThe raw evidence at the best earlier frame (mean of the 10 frames before the turn / the 10 after); a "
          f"closure accepted at once (`confirm_frames=0`) refused below a share of its median over the last "
          f"{FADE_WINDOW} frames: right ones lost / false ones left")
    print("| stream | before / after the turn | " + " | ".join(f"share {r:g}" for r in FADES) + " |")
    print("|---|---|" + "---|" * len(FADES))
    for name, (listing, positions, turn, radius, soft) in streams(data, out).items():
        run = _decided_at_once(out, name, listing, positions, radius, soft)
        with open(run / "rshosm-seq" / "matches.csv", newline="") as fh:
            rows = list(csv.DictReader(fh))
        raw = raw_at_best(out / f"{name}-out")
        right = np.array([r["accepted"] == "1" and r["right"] == "1" for r in rows])
        false = np.array([r["accepted"] == "1" and r["right"] == "0" for r in rows])
        ref = recent_median(raw, FADE_WINDOW)
        cells = [f"{int((right & (raw < r * ref)).sum())} / {int((false & (raw >= r * ref)).sum())} of "
                 f"{int(right.sum())} / {int(false.sum())}" for r in FADES]
        print(f"| {name} | {raw[turn - 10:turn].mean():.2f} / {raw[turn:turn + 10].mean():.2f} | " + " | ".join(cells)
              + " |", flush=True)
    return 0


FADES, FADE_WINDOW = (0.5, 0.7, 0.8), 20


def _decided_at_once(out: Path, name: str, listing, positions, radius, soft) -> Path:
    run = out / f"{name}-confirm0-z2"
    if not (run / "metrics.json").exists():
        run_quietly(["loops", listing, "--out", run, "--cache", out / f"{name}-out" / "cache", "--gt", positions,
                     "--radius", radius, "--gt-soft", soft, "--method-conf", "rshosm-seq.confirm_frames=0"])
    return run


def look_aheads(out: Path, name: str, listing, positions, turn: int, radius, soft) -> str:
    """The table cells of one stream's look-ahead z (:meth:`vpr.shosm.Confirmation.look_ahead`, the defaults) of the
    closures accepted at once."""
    run = _decided_at_once(out, name, listing, positions, radius, soft)
    with open(run / "rshosm-seq" / "matches.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["accepted"] == "1"]
    x = load_cache(next((out / f"{name}-out" / "cache").glob("*.npz"))).features.sdr.tocsr()
    x.sort_indices()
    loop = LoopConf()
    c = Confirmation(loop.confirm_frames, loop.confirm_z, 30, *EvidenceConf().costs, x.shape[1])
    log = RowLog(x.indptr, x.indices)
    z = {int(r["query"]): c.look_ahead(log, int(r["query"]), int(r["best_db"]),
                                       min(int(r["query"]) + loop.confirm_frames, x.shape[0])) for r in rows}
    right = [z[int(r["query"])] for r in rows if r["right"] == "1"]
    after = [z[int(r["query"])] for r in rows if r["right"] == "0" and turn <= int(r["query"]) < turn + RUN_ON]
    other = [z[int(r["query"])] for r in rows if r["right"] == "0" and not turn <= int(r["query"]) < turn + RUN_ON]
    return " | ".join([f"{min(right):.1f} / {np.median(right):.1f}" if right else "-",
                       f"{np.median(after):.1f} / {max(after):.1f}" if after else "-",
                       f"{max(other):.1f}" if other else "-"])


def confirm_table(out: Path, runs: dict, settings: list[tuple[str, str]]) -> None:
    """Per confirm_frames:confirm_z setting, each stream's accepted closures: right ones, false ones within
    :data:`RUN_ON` frames after the turn and elsewhere."""
    print("\nClosures confirmed by the frames after them (`--method-conf rshosm-seq.confirm_frames=F "
          "rshosm-seq.confirm_z=Z`; 0: decided at once): right / false after the turn / false elsewhere")
    print("| confirm_frames:confirm_z | " + " | ".join(runs) + " |")
    print("|---|" + "---|" * len(runs))
    for frames, z in settings:
        cells = []
        for name, (listing, positions, turn, radius, soft) in runs.items():
            run = out / f"{name}-confirm{frames}-z{z}"
            if not (run / "metrics.json").exists():
                run_quietly(["loops", listing, "--out", run, "--cache", out / f"{name}-out" / "cache", "--gt",
                             positions, "--radius", radius, "--gt-soft", soft,
                             "--method-conf", f"rshosm-seq.confirm_frames={frames}",
                             "--method-conf", f"rshosm-seq.confirm_z={z}"])
            with open(run / "rshosm-seq" / "matches.csv", newline="") as fh:
                rows = [r for r in csv.DictReader(fh) if r["accepted"] == "1"]
            right = sum(r["right"] == "1" for r in rows)
            false = [int(r["query"]) for r in rows if r["right"] == "0"]
            on = sum(turn <= q < turn + RUN_ON for q in false)
            cells.append(f"{right} / {on} / {len(false) - on}")
        print(f"| {frames}:{z} | " + " | ".join(cells) + " |", flush=True)


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
