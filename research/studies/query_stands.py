"""A query that stands: `vpr localize` while the robot stops, and after it drives on.

A robot stops (a traffic light, a station): its camera repeats one observation for many frames. This study takes a
query as it comes and inserts a stop: frame ``k`` repeated ``n`` times (the same image file, so the frames differ
only by the running standardisation), and runs ``vpr localize``'s follower frame by frame against a map learned by
``vpr learn`` (defaults). Printed per stream: accepted, P(acc), R(acc) (soft bands as
``research.studies.speed_models``: hard 1
map frame, soft 3; Gardens Point 2 and 8 frames), the stop's frames answered (right), the 20 frames after it
answered, and the wrong answers; then along the first stop, every 5th frame, the best map frame and the z of the
place's map frame in the localizer's column: how the evidence of a repeated observation goes.

Then, measured and not built, the same with a frame that shares at least ``--hold`` of its bits beyond chance with
the frame before (``(|a & b| - c) / (|a| - c)``, ``c = |a| |b| / n_bits``) taking the frame before's decision
without stepping the follower (the evidence held while the observation repeats), on the same streams and on the
streams without a stop (Nordland winter every 10th file; the first 1,000 files of both seasons at every file, whose
trains stand).

Usage: python -m research.studies.query_stands [--data DIR] [--out DIR] [--hold 0.9]
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

from research.studies.cells import decisions_cell
from research.studies.nordland_stands import kinds, standing_steps
from research.studies.speed_models import followed_frames, linked, position_truth, run_quietly
from vpr.evaluate import accepted_precision

#: (stream name, dataset folder, map subfolder, query subfolder, file step, first files, stop frame, stop frames,
#: hard radius, soft radius): positions are file numbers (Nordland: divided by 10, Gardens Point: the image number)
STREAMS = (
    ("Nordland every 10th, stop at 150", "nordland_trimmed", "summer", "winter", 10, None, 150, 40, 10, 30),
    ("Nordland every 10th, stop at 250", "nordland_trimmed", "summer", "winter", 10, None, 250, 40, 10, 30),
    ("Gardens Point, stop at 100", "gardens_point_day", "day_left", "day_right", 1, None, 100, 40, 2, 8),
    ("Nordland every 10th", "nordland_trimmed", "summer", "winter", 10, None, None, 0, 10, 30),
    ("Nordland every file, first 1,000", "nordland_trimmed", "summer", "winter", 1, 1000, None, 0, 1, 3),
)


def _number(f: Path) -> float:
    digits = "".join(c for c in f.stem.split("-")[-1] if c.isdigit())
    return float(int(digits) // 10 if f.stem.startswith("images") else int(digits))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(os.environ.get("VPR_DATASETS", "../shared/datasets")))
    ap.add_argument("--out", type=Path, default=Path("results/query_stands"))
    ap.add_argument("--hold", type=float, default=0.9, help="share of bits beyond chance a held frame shares")
    a = ap.parse_args(argv)
    print("`vpr localize` (defaults), a stop inserted into the query: accepted, P(acc), R(acc); the stop's frames "
          "answered (right); the 20 frames after it answered; wrong")
    print("| stream | as it comes | stop answered (right) | 20 after answered | wrong | held while the "
          f"observation repeats (share >= {a.hold:g}) | stop answered (right) | 20 after answered | wrong |")
    print("|---|---|---|---|---|---|---|---|---|")
    traces, notes = [], []
    for name, ds, db_sub, q_sub, step, first, at, n, radius, soft in STREAMS:
        db_files = sorted((a.data / ds / db_sub).iterdir())[:first][::step]
        q_files = sorted((a.data / ds / q_sub).iterdir())[:first][::step]
        order = list(range(len(q_files))) if at is None else \
            list(range(at)) + [at] * n + list(range(at + 1, len(q_files)))
        tag = f"{ds}-{step}-{first}"
        db, x_db = linked(a.out, f"map-{tag}", db_files, _number, numbered=True)
        query, x_q = linked(a.out, f"query-{tag}-{at}-{n}", [q_files[i] for i in order], _number, numbered=True)
        the_map = a.out / f"map-{tag}.npz"
        if not the_map.exists():
            run_quietly(["learn", db, "--out", the_map])
        hard, soft_ = position_truth(x_db, x_q, radius, soft)
        stop = slice(at, at + n) if at is not None else slice(0, 0)
        after = slice(at + n, at + n + 20) if at is not None else slice(0, 0)
        cells, runs = [], []
        for hold in (None, a.hold):
            ds_ = followed_frames(the_map, query, hold)[0]
            best = np.array([d.best for d in ds_])
            acc = np.array([d.accepted for d in ds_], bool)
            m = accepted_precision(best, acc, hard, soft_)
            right = acc & (best >= 0) & hard[np.maximum(best, 0), np.arange(best.size)]
            runs.append((best, acc))
            cells += [decisions_cell(m, frames=False),
                      f"{int(acc[stop].sum())} ({int(right[stop].sum())})" if at is not None else "",
                      f"{int(acc[after].sum())}" if at is not None else "", str(m["n_false"])]
            if hold is None and at is not None and not traces:
                traces = [(k, ds_[k], x_q[k]) for k in range(at - 5, at + n + 25, 5)]
                trace_x_db = x_db
        print(f"| {name} | {' | '.join(cells)} |", flush=True)
        if step == 1 and ds == "nordland_trimmed":
            still = standing_steps(db_files), standing_steps(q_files)
            told = [{k: v for k, v in kinds(b, acc_, *still).items() if k != "accepted"} for b, acc_ in runs]
            notes.append(f"{name}: the wrong answers' kinds (`research.studies.nordland_stands`), as it comes / held: "
                         + " / ".join(", ".join(f"{k} {v}" for k, v in t.items()) for t in told))
    for line in notes:
        print(line)
    print("\nAlong the first stop (as it comes): frame, best map frame (accepted), the place's map frame and its z in "
          "the column, the best's z")
    print("| frame | best (accepted) | place | place's z | best's z |")
    print("|---|---|---|---|---|")
    for k, d, x in traces:
        place = int(np.argmin(np.abs(trace_x_db - x)))
        col = d.column
        z = dict(zip(col.rows.tolist(), col.z.tolist(), strict=True)) if col is not None else {}
        print(f"| {k} | {d.best} ({'yes' if d.accepted else 'no'}) | {place} | "
              f"{z.get(place, float('nan')):.2f} | {z.get(int(d.best), float('nan')):.2f} |")


if __name__ == "__main__":
    main()
