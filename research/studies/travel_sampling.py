"""A query one frame per so many metres against a map learned at every frame: how the frames kept by travel are chosen.

`vpr localize MAP QUERY --every D` keeps one query frame per ``D`` metres of
travel and learns the map again at the same sampling
(:func:`vpr.groundtruth.same_sampling`), so that one query frame moves about
one map frame. Two ways of choosing the frames kept, on each stream:

- ``nearest mark`` (:func:`vpr.groundtruth.trajectories.every`): the frame
  nearest each multiple of ``D`` along the path; the k-th frame kept lies
  within half a frame's travel of ``k * D`` in either traverse.
- ``after the last``: the first frame at least ``D`` after the last one kept;
  each gap is ``D`` rounded up to whole frames, so a traverse with longer
  frame steps drifts from one with shorter ones, by a frame or more over a
  few hundred metres.

Each stream: a map and a query traverse of one rendered route (64 x 48,
240 frames at 5 frames/s), written as ROS 1 bags with their GPS, the map
learned with ``--preset PRESET`` at every frame. Printed per stream and ``D``:
the query frames answered, accepted, their precision and recall (right within
5 m), for each way.

Usage: python -m research.studies.travel_sampling [--every 3,4,6,8] [--preset fast] [--out DIR]
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

import numpy as np

from pipelines.cli import main as vpr
from research.studies.cells import decisions_cell
from tests.bags import positions_of, read_folder, write_bag
from vpr.render import write_scene

#: (scene, map traverse, query traverse)
STREAMS = (("speed_change", "slow", "fast"), ("speed_change", "fast", "slow"),
           ("two_seasons", "summer_day", "winter_night"))


def after_the_last(xy, metres: float) -> np.ndarray:
    """The first frame, then each first frame at least ``metres`` of travel after the last one kept."""
    xy = np.asarray(xy, np.float64)
    known = np.flatnonzero(~np.isnan(xy).any(axis=1))
    step = np.r_[0.0, np.linalg.norm(np.diff(xy[known], axis=0), axis=1)]
    keep, since = [known[0]], 0.0
    for k in range(1, known.size):
        since += step[k]
        if since >= metres:
            keep.append(known[k])
            since = 0.0
    return np.asarray(keep, np.int64)


def _vpr(argv: list) -> None:
    with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings(action="ignore"):
        code = vpr([str(a) for a in argv] + ["--no-progress"])
    if code:
        raise SystemExit(f"vpr {argv[0]} exited {code}")


def _bag(scene: Path, traverse: str, path: Path) -> Path:
    if not path.exists():
        folder = next(p for p in scene.iterdir() if p.is_dir() and p.name.endswith(traverse))
        write_bag(path, read_folder(folder), positions_of(scene / "ground_truth.csv", traverse), dt=0.2, odom=False)
    return path


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--every", default="3,4,6,8", help="distances D in metres")
    ap.add_argument("--preset", default="fast", help="the map's preset")
    ap.add_argument("--out", type=Path, default=None, help="work folder (default: a temporary one)")
    args = ap.parse_args(argv)
    distances = [float(d) for d in args.every.split(",")]
    ways = {"nearest mark": None, "after the last": after_the_last}
    with tempfile.TemporaryDirectory() as tmp:
        root = args.out or Path(tmp)
        print(f"map learned with --preset {args.preset}; frames answered, accepted, P(acc), R(acc) within 5 m")
        print(f"| stream (map -> query) | D | {' | '.join(ways)} |")
        print("|---|---:|" + "---|" * len(ways))
        for spec, map_traverse, query_traverse in STREAMS:
            scene = root / spec
            if not (scene / "ground_truth.csv").is_file():
                write_scene(spec, scene, size=(64, 48), n_frames=240, progress=False)
            map_bag = _bag(scene, map_traverse, root / f"{spec}-{map_traverse}.bag")
            query_bag = _bag(scene, query_traverse, root / f"{spec}-{query_traverse}.bag")
            the_map = root / f"{spec}-{map_traverse}-{args.preset}.npz"
            if not the_map.exists():
                _vpr(["learn", map_bag, "--out", the_map, "--gt-topic", "/gps/fix", "--preset", args.preset])
            for d in distances:
                cells = []
                for way, sampler in ways.items():
                    out = root / f"{spec}-{map_traverse}-{query_traverse}-{d:g}-{way.replace(' ', '_')}"
                    with contextlib.ExitStack() as stack:
                        if sampler is not None:
                            stack.enter_context(mock.patch("vpr.groundtruth.trajectories.every", sampler))
                        _vpr(["localize", the_map, query_bag, "--out", out, "--gt-topic", "/gps/fix",
                              "--radius", 5, "--every", f"{d:g}m"])
                    r = json.loads((out / "metrics.json").read_text())["methods"]["rshosm-seq"]
                    cells.append(decisions_cell(r))
                print(f"| {spec} {map_traverse} -> {query_traverse} | {d:g} | {' | '.join(cells)} |", flush=True)


if __name__ == "__main__":
    main()
