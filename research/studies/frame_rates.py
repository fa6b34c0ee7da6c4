"""A map and a query recorded at different frame rates: what `vpr localize` decides, with and without making them agree.

Each stream is one rendered traverse (64 x 48, 240 frames at 5 frames/s),
written as ROS 1 bags with its GPS: the map from every ``k``-th frame at
5 / ``k`` frames/s and the query from every frame from the second on, at 5 (the
query faster), or the map from every frame and the query from every
``k``-th from the second (the query slower). The same drive, so the query's
frames are not the map's. Printed per stream, direction and ``k``: the
frames answered, accepted, their precision and recall (within 5 m), with
:func:`vpr.groundtruth.same_rate` (the map learned again at the query's rate,
or the query read at the map's) from rates 2.5 apart, with it from rates
:data:`~vpr.groundtruth.RATE_RATIO` apart (the default), and without it (each
frame as it comes).
Streams: ``speed_change`` slow (4 m/s, stops) and fast (10 m/s), and
``two_seasons`` summer day.

Usage: python -m research.studies.frame_rates [--ks 2,3,4] [--out DIR]
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
import warnings
from pathlib import Path
from unittest import mock

from pipelines.cli import main as vpr
from research.studies.cells import decisions_cell
from tests.bags import positions_of, read_folder, write_bag
from vpr.groundtruth import RATE_RATIO
from vpr.render import write_scene

STREAMS = (("speed_change", "slow"), ("speed_change", "fast"), ("two_seasons", "summer_day"))


def _localize(map_bag: Path, query_bag: Path, out: Path, how: str) -> dict:
    argv = [str(a) for a in ("localize", map_bag, query_bag, "--out", out, "--gt-topic", "/gps/fix", "--radius", 5,
                             "--no-progress")]
    with contextlib.ExitStack() as stack:
        stack.enter_context(contextlib.redirect_stdout(io.StringIO()))  # the answers' JSON lines
        stack.enter_context(warnings.catch_warnings(action="ignore"))
        if how == "as is":
            stack.enter_context(mock.patch("pipelines.localize.same_rate", lambda the_map, *a, **k: (the_map, None)))
        elif how == "from 2.5":
            stack.enter_context(mock.patch("vpr.groundtruth.positions.RATE_RATIO", 2.5))
        code = vpr(argv)
    if code:
        raise SystemExit(f"vpr localize exited {code}")
    return json.loads((out / "metrics.json").read_text())["methods"]["rshosm-seq"]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ks", default="2,3,4", help="rate ratios")
    ap.add_argument("--out", type=Path, default=None, help="work folder (default: a temporary one)")
    args = ap.parse_args(argv)
    ks = [int(k) for k in args.ks.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        root = args.out or Path(tmp)
        print("| stream | query | k | frames, accepted, P(acc), R(acc): made to agree from a ratio of 2.5 | made to "
              f"agree from a ratio of {RATE_RATIO:g} (the default) | each frame as it comes |")
        print("|---|---|---:|---|---|---|")
        for spec, traverse in STREAMS:
            scene = root / spec
            if not (scene / "ground_truth.csv").is_file():
                write_scene(spec, scene, size=(64, 48), n_frames=240, progress=False)
            folder = next(p for p in scene.iterdir() if p.is_dir() and p.name.endswith(traverse))
            img, xy = read_folder(folder), positions_of(scene / "ground_truth.csv", traverse)
            for k in ks:
                cases = {"slower": ((img, xy, 0.2), (img[1::k], xy[1::k], 0.2 * k)),
                         "faster": ((img[::k], xy[::k], 0.2 * k), (img[1:], xy[1:], 0.2))}
                for direction, ((mi, mx, mdt), (qi, qx, qdt)) in cases.items():
                    run = root / f"{spec}-{traverse}-{direction}-{k}"
                    run.mkdir(parents=True, exist_ok=True)
                    m = run / "map.bag"
                    q = run / "query.bag"
                    if not m.exists():
                        write_bag(m, mi, mx, dt=mdt, odom=False)
                        write_bag(q, qi, qx, dt=qdt, odom=False)
                    cells = []
                    for how in ("from 2.5", "default", "as is"):
                        r = _localize(m, q, run / how.replace(" ", "_"), how)
                        cells.append(decisions_cell(r, 2))
                    print(f"| {spec} {traverse} | {direction} | {k} | {' | '.join(cells)} |", flush=True)


if __name__ == "__main__":
    main()
