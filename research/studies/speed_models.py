"""A query driven faster or slower than the map at the same frame rate: speed models of rSHOSM-seq's evidence.

The evidence follows a query that moves one map frame per frame, and admits
a repeated (``stay``) or a skipped (``skip``) map frame at a cost of 0.05
each (:class:`vpr.shosm.EvidenceConf`). A query driven twice as fast skips
at every frame; half as fast, it stays at every other. Compared, per stream:

- ``same``: today's evidence (stay 0.05, skip 0.05);
- ``free``: one evidence with both transitions free (stay 0, skip 0);
- ``same+faster``, ``same+faster+slower``: the evidence of each model
  (``faster``: skip 0; ``slower``: stay 0) computed apart and merged by the
  largest z-score per pair, as SeqSLAM searches several velocities.

Streams (no stamps, no positions: the query's frames are taken as they come):
Gardens Point day_left (map) against day_right, every frame (1x), every 2nd
(2x) and the map every 2nd against every query frame (0.5x); Nordland summer
every 10th file against winter every 10th (1x), 20th (2x) and 5th (0.5x);
and queries driven at a speed that changes every 10-40 frames, 1.5-2.5 map
frames a frame (day_right, winter every 10th file taken so) and 0.4-0.6
(day_right and winter at 0.8-1.25 against a map of every 2nd frame).
Right: within 2 frames (Gardens Point) or one map frame (10 files) of the
query's own frame. Printed per stream and model: AP, accepted, P(acc),
R(acc) of ``accept_path`` (the localisation decision, `vpr compare`'s) on
the merged z-scores. Default preset, ``rshosm-seq``, one run (deterministic).

Then the setting as users give it, ``--method-conf rshosm-seq.speeds=S``,
through the commands on Gardens Point (right within 2 frames; accepted,
P(acc), R(acc)): ``vpr loops`` of day_left then day_right (every frame, and
every 2nd), ``vpr localize`` of day_right's every 2nd frame against a map of
day_left; and :class:`vpr.shosm.Localizer` on
:func:`vpr.simulate.aliased_traverses` (400 places, 40 appearances, a query
at 2x; right within one place).

Then ``vpr compare`` and ``vpr localize`` (against a map of ``vpr learn``) with
their defaults on the first table's streams, the query's frames as they come
(``--query-speed as-is``) and followed (the default:
:func:`vpr.methods.match_at_speed`, :class:`vpr.shosm.SpeedFollower`); and
the phase of the sampling: a map
from one frame in 2 starting at the query's first frame or one later, a
slower query's answers copied from one frame in 2 or each frame its own (and
so, with the frames not accepted placed between accepted ones); and
the two ways a frame picks one of the maps of one frame in 2, chosen with
each dataset held out in turn.

Each table also prints the query's speed along the accepted paths, in map frames per query frame
(:func:`vpr.evaluate.path_speed`, no ground truth): a measure a run could say.

Then ``vpr loops`` of each stream's map and query as two sessions of one
stream, as they come and followed (:func:`vpr.methods.loops_at_speed`).

Then both, ``vpr loops`` and ``vpr localize``, as the goal measures them: the
best matches in the datasets' usual soft bands neither right nor wrong.

Then, where a faster query's two maps of one frame in 2 both accept a frame, how far
apart they place it, and the decisions with frames placed apart left undecided
(:func:`vpr.shosm.disagree`).

Then ``vpr localize``'s follower frame by frame on the streams off the map's speed: the frame it first reads
another speed, its answers before and after, and the wrong answers at a slower speed that contradict the frame
before's (``--online``: only that table).

With ``--loops``: only those two tables; with ``--apart``: only the table of frames placed apart. With
``--one-run``: only ``vpr loops`` of one folder holding a revisit at 2x (Gardens Point) and of forward-only
renders, and the runs of best earlier frames in each that read another speed, and what a re-match from them
would decide; then one rendered run
with loops in it, its later laps driven at 2x or its first lap at 2x (the later at 0.5x),
with ground truth, geometry on and off. With ``--cases``: only
the cases the localisation rule was chosen on (:mod:`research.studies.localize_decisions`),
answered as they come and followed.

Usage: python -m research.studies.speed_models [--data DIR] [--out DIR] [--cases | --loops | --one-run | --apart |
--online]
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import io
import json
import tempfile
import warnings
from pathlib import Path

import numpy as np

from pipelines.cli import main as vpr
from research.studies.cells import decisions_cell
from vpr import simulate
from vpr.evaluate import average_precision, path_run_speeds, path_speed
from vpr.shosm import Localizer, LoopConf, RshosmSeqConf
from vpr.shosm.decide import accept_path

#: model -> (stay, skip)
MODELS = {"same": (0.05, 0.05), "faster": (0.05, 0.0), "slower": (0.0, 0.05), "free": (0.0, 0.0)}
COMBOS = ("same", "free", "same+faster", "same+faster+slower")


def _speed_cell(best, accepted) -> str:
    v, n = path_speed(best, accepted)
    return "-" if v is None else f"{v:.2f} ({n})"


def linked(root: Path, name: str, files: list[Path], number, numbered: bool = False) -> tuple[Path, np.ndarray]:
    """A folder of links to ``files`` and each file's position along the route (``number(file)``); ``numbered``: each
    link named by its place in the list (a file may come several times)."""
    out = root / name
    out.mkdir(parents=True, exist_ok=True)
    for k, f in enumerate(files):
        link = out / (f"{k:05d}{f.suffix}" if numbered else f.name)
        if not link.exists():
            link.symlink_to(f.resolve())
    return out, np.array([number(f) for f in files], np.float64)


def _varying(files: list[Path], lo: float, hi: float, seed: int, unit: int = 1) -> list[Path]:
    """The frames a camera at the files' frame rate records driving ``lo`` to ``hi`` files a frame (a speed drawn for
    every 10 to 40 frames), ``unit`` files making one step."""
    rng, pos, out = np.random.default_rng(seed), 0.0, []
    while True:
        v = rng.uniform(lo, hi)
        for _ in range(int(rng.integers(10, 41))):
            if int(pos) * unit >= len(files):
                return out
            out.append(files[int(pos) * unit])
            pos += v


def _streams(data: Path, root: Path):
    gp, nl = data / "gardens_point_day", data / "nordland_trimmed"
    left, right = sorted((gp / "day_left").iterdir()), sorted((gp / "day_right").iterdir())
    summer, winter = sorted((nl / "summer").iterdir()), sorted((nl / "winter").iterdir())
    gp_n = lambda f: int(f.stem.removeprefix("Image"))  # noqa: E731
    nl_n = lambda f: int(f.stem.split("-")[-1]) // 10  # noqa: E731
    yield "Gardens Point 1x", linked(root, "gp_left", left, gp_n), linked(root, "gp_right", right, gp_n), 2
    yield "Gardens Point 2x", linked(root, "gp_left", left, gp_n), linked(root, "gp_right2", right[::2], gp_n), 2
    yield "Gardens Point 0.5x", linked(root, "gp_left2", left[::2], gp_n), linked(root, "gp_right", right, gp_n), 2
    s10 = linked(root, "nl_summer10", summer[::10], nl_n)
    yield "Nordland 1x", s10, linked(root, "nl_winter10", winter[::10], nl_n), 10
    yield "Nordland 2x", s10, linked(root, "nl_winter20", winter[::20], nl_n), 10
    yield "Nordland 0.5x", s10, linked(root, "nl_winter5", winter[::5], nl_n), 10
    # driven at a speed that changes every 10-40 frames: the sampled frames fall on the map's in every phase
    yield ("Gardens Point 1.5-2.5x", linked(root, "gp_left", left, gp_n),
           linked(root, "gp_right_1.5-2.5", _varying(right, 1.5, 2.5, 0), gp_n, True), 2)
    yield ("Gardens Point 0.4-0.6x", linked(root, "gp_left2", left[::2], gp_n),
           linked(root, "gp_right_0.8-1.25", _varying(right, 0.8, 1.25, 0), gp_n, True), 2)
    yield ("Nordland 1.5-2.5x", s10,
           linked(root, "nl_winter_1.5-2.5", _varying(winter, 1.5, 2.5, 0, 10), nl_n, True), 10)
    yield ("Nordland 0.4-0.6x", linked(root, "nl_summer20", summer[::20], nl_n),
           linked(root, "nl_winter_0.8-1.25", _varying(winter, 0.8, 1.25, 0, 10), nl_n, True), 10)


def _similarity(db: Path, query: Path, model: str, root: Path) -> np.ndarray:
    out = root / "runs" / f"{db.name}-{query.name}-{model}"
    if not (out / "rshosm-seq" / "similarity.npy").exists():
        stay, skip = MODELS[model]
        argv = ["compare", db, query, "--out", out, "--cache", root / "cache", "--methods", "rshosm-seq",
                "--method-conf", f"rshosm-seq.stay={stay}", "--method-conf", f"rshosm-seq.skip={skip}",
                "--query-speed", "as-is", "--no-progress"]
        with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings(action="ignore"):
            if vpr([str(a) for a in argv]):
                raise SystemExit(f"vpr compare {db} {query} failed")
    return np.load(out / "rshosm-seq" / "similarity.npy")


SETTINGS = ("same", "faster", "same+faster", "same+faster+slower")


def positions_csv(path: Path, x) -> Path:
    path.write_text("frame,x,y\n" + "".join(f"{i},{v:g},0\n" for i, v in enumerate(x)))
    return path


def run_quietly(argv: list) -> Path:
    """Run ``vpr ARGV`` without its output; returns its ``--out``."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()), \
            warnings.catch_warnings(action="ignore"):
        if vpr([str(a) for a in argv] + ["--no-progress"]):
            raise SystemExit(f"vpr {argv[0]} failed")
    return Path(argv[argv.index("--out") + 1])


def _command(argv: list) -> str | None:
    out = run_quietly(argv)
    if argv[0] == "learn":
        return None
    with open(out / "rshosm-seq" / "matches.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    speed = _speed_cell([int(x["best_db"]) for x in rows], [x["accepted"] == "1" for x in rows])
    m = json.loads((out / "metrics.json").read_text())["methods"]["rshosm-seq"]
    later = "".join(f"; session 2 read {v:.2f}" for v in m.get("session_speeds") or [] if v is not None)
    return decisions_cell(m, frames=False) + f"; speed {speed}{later}"


def _encoded(folders: list[Path], names: list[str], root: Path) -> list:
    """The default preset's SDRs of ``folders`` as ``vpr compare`` encodes them (each standardised on its own
    frames; cached under ``root``): their features, in order."""
    import encoders
    from pipelines.extract import extract_all
    from vpr import presets
    from vpr.sources import open_sources

    s = presets.resolve(None)
    enc = encoders.get(s["encoder"], **s["encoder_conf"])
    with warnings.catch_warnings(action="ignore"):
        return [e.features for e in extract_all(open_sources(folders), names, enc, {"sdr"}, root / "cache", False,
                                                 False)]


def _learned(root: Path, db: Path, positions: Path) -> Path:
    """The map ``vpr learn`` writes of ``db`` (with its frames' ``positions``), learned once under ``root``."""
    the_map = root / "followed" / f"{db.name}.npz"
    if not the_map.exists():
        _command(["learn", db, "--out", the_map, "--gt", positions])
    return the_map


def _simulated(speeds: str) -> str:
    db, q, _, q_place = simulate.aliased_traverses(400, 40, speed=(1.8, 2.2), seed=1)
    loc = Localizer.from_database(db, [str(i) for i in range(db.shape[0])], conf=RshosmSeqConf.of(speeds=speeds))
    acc = right = 0
    for j in range(q.shape[0]):
        d = loc.update(q[j])
        acc += d.accepted
        right += d.accepted and abs(d.best - q_place[j]) <= 1
    return f"{acc}, {right / acc:.3f}, {right / q.shape[0]:.2f}" if acc else "0, -, 0.00"


def commands(data: Path, root: Path) -> None:
    """The second table: the setting through the commands."""
    gp = data / "gardens_point_day"
    left, right = gp / "day_left", gp / "day_right"
    right2 = linked(root, "gp_right2", sorted(right.iterdir())[::2], lambda f: 0)[0]
    n = len(list(left.iterdir()))
    p_left, p_right = positions_csv(root / "left.csv", range(n)), positions_csv(root / "right.csv", range(n))
    p_right2 = positions_csv(root / "right2.csv", range(0, n, 2))
    the_map = root / "gp_left_map.npz"
    if not the_map.exists():
        _command(["learn", left, "--out", the_map, "--gt", p_left])
    print("\naccepted, P(acc), R(acc) with --method-conf rshosm-seq.speeds=S (Gardens Point: right within 2 frames)")
    print(f"| run | {' | '.join(SETTINGS)} |")
    print("|---|" + "---|" * len(SETTINGS))
    runs = {"loops day_left day_right (1x)": ["loops", left, right, "--gt", p_left, p_right, "--radius", 2,
                                              "--query-speed", "as-is"],
            "loops day_left day_right every 2nd (2x)": ["loops", left, right2, "--gt", p_left, p_right2,
                                                        "--radius", 2, "--query-speed", "as-is"],
            "localize map of day_left, day_right every 2nd (2x)": ["localize", the_map, right2, "--gt", p_right2,
                                                                   "--radius", 2, "--query-speed", "as-is"]}
    for name, argv in runs.items():
        cells = [_command([*argv, "--out", root / f"cmd-{k}-{s}", "--method-conf", f"rshosm-seq.speeds={s}"])
                 for s in SETTINGS for k in [list(runs).index(name)]]
        print(f"| {name} | {' | '.join(cells)} |", flush=True)
    print(f"| Localizer, aliased_traverses 400 places, query 2x (within one place) | "
          f"{' | '.join(_simulated(s) for s in SETTINGS)} |")
    sampled(data, root)


def sampled(data: Path, root: Path) -> None:
    """The third table: a 2x query localised against a map learned from one frame in two (what a run that reads
    the speed says to do), against the map of every frame; default settings."""
    gp, nl = data / "gardens_point_day", data / "nordland_trimmed"
    left, right = gp / "day_left", gp / "day_right"
    right2 = linked(root, "gp_right2", sorted(right.iterdir())[::2], lambda f: 0)[0]
    n = len(list(left.iterdir()))
    p_left, p_right2 = positions_csv(root / "left.csv", range(n)), positions_csv(root / "right2.csv", range(0, n, 2))
    nl_n = lambda f: int(f.stem.split("-")[-1]) // 10  # noqa: E731
    s10, x10 = linked(root, "nl_summer10", sorted((nl / "summer").iterdir())[::10], nl_n)
    w20, x20 = linked(root, "nl_winter20", sorted((nl / "winter").iterdir())[::20], nl_n)
    p_s10, p_w20 = positions_csv(root / "s10.csv", x10), positions_csv(root / "w20.csv", x20)
    print("\nlocalize, a query driven twice as fast: accepted, P(acc), R(acc); speed along the accepted paths")
    print("| stream | map of every frame, --query-speed as-is | map of every frame, follow (default) | map from one "
          "frame in 2 (vpr learn --step 2) |")
    print("|---|---|---|---|")
    for name, (db, p_db, q, p_q, radius) in {
            "Gardens Point day_left -> day_right every 2nd (within 2 frames)": (left, p_left, right2, p_right2, 2),
            "Nordland summer every 10th -> winter every 20th (within 10 files)": (s10, p_s10, w20, p_w20, 10)}.items():
        cells = []
        for step, how in ((1, "as-is"), (1, "follow"), (2, "as-is")):
            the_map = root / f"sampled-{db.name}-{step}.npz"
            if not the_map.exists():
                _command(["learn", db, "--out", the_map, "--gt", p_db, "--step", step])
            cells.append(_command(["localize", the_map, q, "--gt", p_q, "--radius", radius, "--query-speed", how,
                                   "--out", root / f"sampled-{db.name}-{q.name}-{step}-{how}"]))
        print(f"| {name} | {' | '.join(cells)} |", flush=True)


def _as_is_or_followed(data: Path, root: Path, title: str):
    """Print ``title`` and the head of a table of the streams as they come and followed; yield each stream's
    (name, db, query, radius, db positions, query positions)."""
    print(f"\n{title}")
    print("| stream | --query-speed as-is | follow (default) |")
    print("|---|---|---|")
    for name, (db, x_db), (query, x_q), radius in _streams(data, root):
        yield (name, db, query, radius, positions_csv(root / f"{db.name}.csv", x_db),
               positions_csv(root / f"{query.name}.csv", x_q))


def _pair(command: str, db: Path, query: Path, root: Path, p_db: Path, p_q: Path, radius, how: str) -> dict:
    """``vpr COMMAND DB QUERY`` with the defaults and ``--query-speed how`` (run once into ``root``): its methods'
    metrics."""
    out = root / ("followed" if command == "compare" else command) / f"{db.name}-{query.name}-{how}"
    if not (out / "metrics.json").exists():
        with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings(action="ignore"):
            if vpr([str(a) for a in [command, db, query, "--out", out, "--cache", root / "cache", "--gt", p_db, p_q,
                                     "--radius", radius, "--query-speed", how, "--no-progress"]]):
                raise SystemExit(f"vpr {command} {db} {query} failed")
    return json.loads((out / "metrics.json").read_text())["methods"]


def followed(data: Path, root: Path) -> None:
    """The fourth table: ``vpr compare`` with its defaults on every stream of the first, the query's frames as they
    come (``--query-speed as-is``) and followed (the default: matched again at the sampling its speed asks for)."""
    print("\nvpr compare, defaults: accepted, P(acc), R(acc); speed along the accepted paths; what was matched again")
    print("| stream | method | --query-speed as-is | follow (default) |")
    print("|---|---|---|---|")
    for name, (db, x_db), (query, x_q), radius in _streams(data, root):
        p_db, p_q = positions_csv(root / f"{db.name}.csv", x_db), positions_csv(root / f"{query.name}.csv", x_q)
        reports = {how: _pair("compare", db, query, root, p_db, p_q, radius, how) for how in ("as-is", "follow")}
        for method in reports["as-is"]:
            cells = []
            for how in ("as-is", "follow"):
                m = reports[how][method]
                v, sampling = m["path_speed"], m.get("sampling")
                again = (f"; one {'database' if 'db_step' in sampling else 'query'} frame in "
                         f"{sampling.get('db_step') or sampling.get('query_step')}{_decided(sampling)}") \
                    if sampling else ""
                cells.append(f"{decisions_cell(m, frames=False)}; speed {'-' if v is None else f'{v:.2f}'}{again}")
            print(f"| {name} | {method} | {' | '.join(cells)} |", flush=True)
    for name, db, query, radius, p_db, p_q in _as_is_or_followed(
            data, root, "vpr localize (learned map, defaults): accepted, P(acc), R(acc); speed along the accepted "
            "paths; the frames answered at another sampling"):
        the_map = _learned(root, db, p_db)
        cells = []
        for how in ("as-is", "follow"):
            out = root / "followed" / f"localize-{db.name}-{query.name}-{how}"
            cell = _command(["localize", the_map, query, "--gt", p_q, "--radius", radius, "--query-speed", how,
                             "--out", out])
            sampling = json.loads((out / "metrics.json").read_text())["methods"]["rshosm-seq"].get("sampling")
            how_said = {"db_step": "by the maps of one frame in", "query_step": "as queries of one frame in"}
            cells.append(cell + "".join(f"; {sampling[k + '_frames']} frames {said} {sampling[k]}"
                                        for k, said in how_said.items() if sampling and k in sampling)
                         + _decided(sampling or {}))
        print(f"| {name} | {' | '.join(cells)} |", flush=True)


def _decided(sampling: dict) -> str:
    """What a followed speed decided otherwise: frames the maps of one frame in k placed apart (left undecided), or a
    slower query's frames placed between accepted ones."""
    return "".join(f", {sampling[k]} {said}" for k, said in (("db_apart", "placed apart"),
                                                               ("query_filled", "placed between"))
                   if sampling.get(k))


def loops(data: Path, root: Path) -> None:
    """The loops table: ``vpr loops MAP QUERY`` (two sessions of one stream) with its defaults on every stream of the
    first table, the later session's frames as they come (``--query-speed as-is``) and followed (the default:
    :func:`vpr.methods.loops_at_speed`)."""
    for name, db, query, radius, p_db, p_q in _as_is_or_followed(
            data, root, "vpr loops DB QUERY (two sessions), defaults: accepted, P(acc), R(acc); the later session's "
            "speed onto the earlier one along the loop's paths, and along the match's (follow); what was matched "
            "again"):
        cells = []
        for how in ("as-is", "follow"):
            m = _pair("loops", db, query, root, p_db, p_q, radius, how)["rshosm-seq"]
            v = (m.get("session_speeds") or [None])[0]
            again = ""
            for f in (m.get("sampling") or {}).get("sessions", []):
                step = f.get("db_step") or f.get("query_step")
                again += f"; matched {f['speed']:.2f}" + (
                    f"; one {'earlier' if 'db_step' in f else 'later'} frame in {step}{_decided(f)}" if step else "")
            cells.append(f"{decisions_cell(m, frames=False)}; speed {'-' if v is None else f'{v:.2f}'}{again}")
        print(f"| {name} | {' | '.join(cells)} |", flush=True)


def _runs(best) -> list[tuple[int, int, float]]:
    """Every run of best earlier frames :func:`vpr.evaluate.path_runs` reads, accepted or not: (first frame, last
    frame, speed)."""
    best = np.asarray(best, np.int64)
    return [(int(a), int(b), float(v)) for a, b, v in zip(*path_run_speeds(best, best >= 0), strict=True)]


#: the forward-only renders of the one-run table: scene, its traverses
RENDERED_ONE_RUN = {"two_seasons": ("summer_day", "winter_night"), "aliased_corridor": ("lights_on", "night"),
                    "speed_change": ("slow", "fast")}


def one_run(data: Path, root: Path) -> None:
    """A loop within one run: ``vpr loops`` of one folder on a revisit at 2x and on forward-only drives, as it comes
    (``--query-speed as-is``) and by default (the stretches whose best earlier frames read another speed matched
    again: :func:`vpr.methods.loops_in_run_at_speed`), each closure judged (:func:`_judged`); the runs of best earlier
    frames that read another speed; then how the re-match's rule and start were chosen (:func:`rematched`)."""
    from vpr.groundtruth import speed_step

    gp = data / "gardens_point_day"
    left, right = sorted((gp / "day_left").iterdir()), sorted((gp / "day_right").iterdir())
    streams = {"gp_1x": ("Gardens Point day_left + day_right, one folder (1x)", left + right),
               "gp_2x": ("Gardens Point day_left + day_right every 2nd, one folder (2x)", left + right[::2])}
    for scene, names in RENDERED_ONE_RUN.items():
        rendered = root / "renders" / scene
        if not (rendered / "scene.json").exists():
            run_quietly(["render", scene, "--out", rendered, "--size", "160x120"])
        for t in names:
            streams[f"{scene}_{t}"] = (f"rendered {scene} {t} (forward only)", sorted((rendered / t).glob("*.png")))
    print("\nvpr loops of one folder: frames; runs of 10 or more best earlier frames, those reading 1.5 or more, or "
          "1/1.5 or less (as it comes); closures accepted as it comes and by default (Gardens Point: right within 2, "
          "false beyond 8 frames; renders: onto an identical copy, false), the default's stretches matched again")
    print("| stream | frames | runs | off speed | --query-speed as-is | default | matched again |")
    print("|---|---|---|---|---|---|---|")
    for key, (name, files) in streams.items():
        folder = root / "one_run" / key
        if not folder.exists():
            folder.mkdir(parents=True)
            for i, f in enumerate(files):
                (folder / f"{i:05d}{f.suffix}").symlink_to(f.resolve())
        cells, rows = [], {}
        for how in ("as-is", "follow"):
            out = root / "one_run" / f"{key}-{how}"
            if not (out / "metrics.json").exists():
                run_quietly(["loops", folder, "--query-speed", how, "--out", out])
            with open(out / "rshosm-seq" / "matches.csv", newline="") as fh:
                rows[how] = list(csv.DictReader(fh))
            best = np.array([int(r["best_db"]) for r in rows[how]])
            cells.append(_judged(key, best, np.array([r["accepted"] == "1" for r in rows[how]])))
        runs = _runs([int(r["best_db"]) for r in rows["as-is"]])
        off = [f"{a}-{b} ({v:.2f})" for a, b, v in runs if speed_step(v)]
        sampling = json.loads((root / "one_run" / f"{key}-follow" / "metrics.json").read_text())["methods"][
            "rshosm-seq"].get("sampling") or {}
        again = "; ".join(f"{r['frames'][0]}-{r['frames'][1]}, {r['closures']} taken" for r in sampling.get("runs", []))
        print(f"| {name} | {len(rows['as-is'])} | {len(runs)} | {', '.join(off) or '-'} | {cells[0]} | {cells[1]} | "
              f"{again or '-'} |", flush=True)
    rematched(streams, root)
    laps_at_speed(root)


def _copies(key: str):
    """The pairs of a forward-only render of the one-run table that see an identical copy of each other (None: not
    a render)."""
    from research.studies.loop_decisions import aliases

    scene = next((sc for sc in RENDERED_ONE_RUN if key.startswith(sc + "_")), None)
    return None if scene is None else aliases(f"{scene}/{key[len(scene) + 1:]}")


def _judged(key: str, best, accepted) -> str:
    """The accepted closures of a one-run stream: on Gardens Point (day_left's 200 frames, then day_right, every
    frame or every 2nd) right within 2 frames and false beyond 8; on a render, onto an identical copy or false."""
    j = np.flatnonzero(accepted)
    copy = _copies(key)
    if copy is None:
        truth = np.where(j >= 200, (2 if key == "gp_2x" else 1) * (j - 200), -99)
        err = np.abs(best[j] - truth)
        return f"{j.size}: {int((err <= 2).sum())} right, {int((err > 8).sum())} false"
    on = copy[best[j], j]
    return f"{j.size}: {int(on.sum())} copy, {int((~on).sum())} false"


#: the rules a stretch of one run re-matched at another speed is decided by: the localisation's path rule
#: (rshosm-seq's defaults against a map) and the loop rule's path (LoopConf's drift and min_score)
REMATCH_RULES = {"localisation rule": {}, "loop rule": {"drift": LoopConf.drift, "min_score": LoopConf.min_score}}


def rematched(streams: dict, root: Path) -> None:
    """How a re-match within one run decides, by rule and start (``vpr loops`` of one run,
    :func:`vpr.methods.loops_in_run_at_speed`, takes the loop rule from ``exclude`` frames before, and of those only
    the faster stretches and the closures on a run of closures that reads a faster speed too): from each run of best
    earlier frames that reads another speed (``vpr loops --query-speed as-is`` of the folder; the runs after it at the
    same step continue it) to the next such stretch or the stream's end, its frames matched against the frames before
    it (the loop's ``exclude`` back) at the sampling of that speed
    (:func:`vpr.methods.match_at_speed`, the speed read given), decided by each of :data:`REMATCH_RULES`, then
    confirmed by the frames after each closure (:func:`vpr.shosm.confirm_closures`, the defaults); starting at the
    run's first frame, or ``exclude`` frames before it. Closures: right / false on Gardens Point (within 2 / beyond 8
    frames), onto an identical copy / false on the renders (:func:`research.studies.loop_decisions.aliases`)."""
    from vpr import methods
    from vpr.groundtruth import speed_step
    from vpr.methods import match_at_speed
    from vpr.shosm import LOOP_EXCLUDE, confirm_closures
    from vpr.types import Decision, EncodedTraverse

    print("\na re-match within one run: from each run that reads another speed to the next or the end, against the "
          "frames before it, decided by a path rule, then confirmed by the frames after each closure; accepted "
          "(Gardens Point: right, false; renders: onto the copy, false)")
    print(f"| stream | from | {' | '.join(f'{r} | confirmed' for r in REMATCH_RULES)} |")
    print("|---|---|" + "---|---|" * len(REMATCH_RULES))
    for key, (name, _) in streams.items():
        with open(root / "one_run" / f"{key}-as-is" / "rshosm-seq" / "matches.csv", newline="") as fh:
            best = [int(r["best_db"]) for r in csv.DictReader(fh)]
        runs = [(a, v) for a, _, v in _runs(best) if speed_step(v)]
        runs = [r for i, r in enumerate(runs) if not i or speed_step(r[1]) != speed_step(runs[i - 1][1])]
        if not runs:
            continue
        (x,) = _encoded([root / "one_run" / key], ["stream"], root)
        seq, n = EncodedTraverse(x.names, sdr=x.sdr), len(x.names)
        for back, label in ((0, "the run's first frame"), (LOOP_EXCLUDE, f"{LOOP_EXCLUDE} frames before it")):
            cells = []
            for conf in REMATCH_RULES.values():
                best_, score, acc = np.full(n, -1), np.zeros(n), np.zeros(n, bool)
                for i, (a, v) in enumerate(runs):
                    lo = max(a - back, LOOP_EXCLUDE + 1)
                    hi = max(runs[i + 1][0] - back, lo) if i + 1 < len(runs) else n
                    fitted = methods.get("rshosm-seq", **conf).fit(seq.take(np.arange(lo - LOOP_EXCLUDE)))
                    with warnings.catch_warnings(action="ignore"):
                        r = match_at_speed(fitted, seq.take(np.arange(lo, hi)), speed=v)
                    best_[lo:hi], score[lo:hi], acc[lo:hi] = r.best, r.score, r.accepted
                d = Decision(best_, score, acc, np.ones(n))
                kept = np.asarray(confirm_closures(d, x.sdr, LOOP_EXCLUDE, RshosmSeqConf.of({})).accepted, bool)
                cells += [_judged(key, best_, acc), _judged(key, best_, kept)]
            print(f"| {name} | {label} | {' | '.join(cells)} |", flush=True)


#: the rendered laps' ground truth (metres): right within, neither right nor wrong within
LAPS_RADIUS, LAPS_SOFT = 5, 10


def laps_streams(root: Path) -> dict:
    """The rendered ``loop_revisits`` laps at the scene's own size (320 x 240) as one run with loops in it: every
    frame; the later laps every 2nd frame (2x); the first lap every 2nd frame (the later ones at 0.5x). Rendered and
    linked into ``root`` once; returns {key: (name, folder, positions file)}."""
    rendered = root / "renders" / "loop_revisits"
    if not (rendered / "scene.json").exists():
        run_quietly(["render", "loop_revisits", "--out", rendered])
    with open(rendered / "ground_truth.csv", newline="") as fh:
        gt = [r for r in csv.DictReader(fh) if r["traverse"] == "laps"]
    files = sorted((rendered / "laps").glob("*.png"))
    scene = json.loads((rendered / "scene.json").read_text())
    lap = np.array([float(r["route_pos"]) for r in gt]) // scene["world"]["length"]
    every, first, later = np.arange(len(files)), np.flatnonzero(lap == 0), np.flatnonzero(lap > 0)
    streams = {"laps_1x": ("laps, every frame", every), "laps_2x": ("laps, the later laps every 2nd frame (2x)",
                                                                    np.r_[first, later[::2]]),
               "laps_half": ("laps, the first lap every 2nd frame (later laps 0.5x)", np.r_[first[::2], later])}
    out = {}
    for key, (name, keep) in streams.items():
        folder, positions = root / "one_run" / key, root / "one_run" / f"{key}.csv"
        if not folder.exists():
            folder.mkdir(parents=True)
            for i, j in enumerate(keep):
                (folder / f"{i:05d}.png").symlink_to(files[j].resolve())
            with open(positions, "w", newline="") as fh:
                w = csv.writer(fh)
                w.writerow(["frame", "x", "y"])
                w.writerows([i, gt[j]["x"], gt[j]["y"]] for i, j in enumerate(keep))
        out[key] = (name, folder, positions)
    return out


def laps_at_speed(root: Path) -> None:
    """``vpr loops`` of one run with loops in it, driven at another speed on the way back (:func:`laps_streams`).
    Defaults, with ``--geometry off`` beside; hard :data:`LAPS_RADIUS` m, soft :data:`LAPS_SOFT` m."""
    print(f"\nvpr loops of one run with loops, rendered at 320 x 240 (hard {LAPS_RADIUS} m, soft {LAPS_SOFT} m): "
          "frames; accepted, P(acc), R(acc), false; geometry off, then on (the default): accepted by it, refused by it")
    print("| stream | frames | --geometry off | default | by geometry | refused |")
    print("|---|---|---|---|---|---|")
    for key, (name, folder, positions) in laps_streams(root).items():
        cells = []
        for geometry in ("off", "on"):
            out = root / "one_run" / f"{key}-geometry-{geometry}"
            if not (out / "metrics.json").exists():
                run_quietly(["loops", folder, "--out", out, "--gt", positions, "--radius", LAPS_RADIUS, "--gt-soft",
                        LAPS_SOFT, "--geometry", geometry])
            m = json.loads((out / "metrics.json").read_text())["methods"]["rshosm-seq"]
            cells.append(f"{decisions_cell(m, frames=False)}, {m['n_false']}")
        g = m["geometry"]
        print(f"| {name} | {len(list(folder.iterdir()))} | {cells[0]} | {cells[1]} | {g['accepted_by_geometry']} | "
              f"{g['refused_by_geometry']} |", flush=True)


#: the datasets' usual soft bands, by the hard radius of their streams (Gardens Point: 2 frames, 8 ignored;
#: Nordland: one map frame of 10 files, three ignored)
SOFT = {2: 8, 10: 30}


def soft(data: Path, root: Path) -> None:
    """The goal's measure: ``vpr loops MAP QUERY`` and ``vpr localize`` with the defaults, as they come and followed,
    the best matches in the datasets' usual soft bands neither right nor wrong (:data:`SOFT`)."""
    print("\nwith the soft bands (Gardens Point hard 2 frames, soft 8; Nordland hard 1 map frame, soft 3): accepted, "
          "P(acc), R(acc)")
    print("| stream | loops as-is | loops follow (default) | localize as-is | localize follow (default) |")
    print("|---|---|---|---|---|")
    for name, (db, x_db), (query, x_q), radius in _streams(data, root):
        p_db, p_q = positions_csv(root / f"{db.name}.csv", x_db), positions_csv(root / f"{query.name}.csv", x_q)
        the_map = _learned(root, db, p_db)
        cells = []
        for command in ("loops", "localize"):
            for how in ("as-is", "follow"):
                out = root / "soft" / f"{command}-{db.name}-{query.name}-{how}"
                if not (out / "metrics.json").exists():
                    _command([command, *([db, query, "--gt", p_db, p_q] if command == "loops" else
                                         [the_map, query, "--gt", p_q]),
                              "--radius", radius, "--gt-soft", SOFT[radius], "--query-speed", how, "--out", out])
                m = json.loads((out / "metrics.json").read_text())["methods"]["rshosm-seq"]
                cells.append(decisions_cell(m, frames=False))
        print(f"| {name} | {' | '.join(cells)} |", flush=True)


def _as_is(db: Path, x_db, query: Path, x_q, radius, out: Path) -> tuple[dict, list]:
    """``vpr compare --methods rshosm-seq --query-speed as-is``: its metrics and its (best_db, accepted) rows."""
    if not (out / "metrics.json").exists():
        p_db = positions_csv(out.parent / f"{db.name}.csv", x_db)
        p_q = positions_csv(out.parent / f"{query.name}.csv", x_q)
        with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings(action="ignore"):
            if vpr([str(a) for a in ["compare", db, query, "--out", out, "--cache", out.parent.parent / "cache",
                                     "--gt", p_db, p_q, "--radius", radius, "--methods", "rshosm-seq",
                                     "--query-speed", "as-is", "--no-progress"]]):
                raise SystemExit(f"vpr compare {db} {query} failed")
    with open(out / "rshosm-seq" / "matches.csv", newline="") as f:
        rows = [(int(r["best_db"]), r["accepted"] == "1") for r in csv.DictReader(f)]
    return json.loads((out / "metrics.json").read_text())["methods"]["rshosm-seq"], rows


def phases(data: Path, root: Path) -> None:
    """The fifth table: why ``follow`` matches every phase. A 2x query against a map from one frame in two that
    starts at the query's first frame (phase 0) or one frame later (phase 1); a 0.5x query as one query of one frame
    in two whose answers the frames between take (copied), or as two queries, every frame its own, and so with the
    frames not accepted placed between the accepted frames around them (:func:`vpr.shosm.fill_between`)."""
    from vpr.shosm import fill_between

    gp, nl = data / "gardens_point_day", data / "nordland_trimmed"
    gp_n = lambda f: int(f.stem.removeprefix("Image"))  # noqa: E731
    nl_n = lambda f: int(f.stem.split("-")[-1]) // 10  # noqa: E731
    left, right = sorted((gp / "day_left").iterdir()), sorted((gp / "day_right").iterdir())
    summer, winter = sorted((nl / "summer").iterdir()), sorted((nl / "winter").iterdir())
    work = root / "phases"
    work.mkdir(parents=True, exist_ok=True)
    print("\nthe phase of the sampling, rshosm-seq alone, --query-speed as-is: accepted, P(acc), R(acc)")
    print("| stream | map from one frame in 2 starting at frame 0 | at frame 1 |")
    print("|---|---|---|")
    faster = {"Gardens Point 2x": (left, right[::2], gp_n, 2), "Nordland 2x": (summer[::10], winter[::20], nl_n, 10)}
    for name, (db, query, number, radius) in faster.items():
        q, x_q = linked(work, f"{name}-q".replace(" ", "_"), query, number)
        cells = []
        for a in (0, 1):
            d, x_d = linked(work, f"{name}-map{a}".replace(" ", "_"), db[a::2], number)
            cells.append(decisions_cell(_as_is(d, x_d, q, x_q, radius, work / f"{d.name}-run")[0], frames=False))
        print(f"| {name} | {' | '.join(cells)} |")
    print("\n| stream | a query of one frame in 2, its answers copied to the frames between | every frame its "
          "own (two queries of one frame in 2) | every frame its own, those not accepted placed between the accepted "
          "frames around them (fill_between, the default) |")
    print("|---|---|---|---|")
    slower = {"Gardens Point 0.5x": (left[::2], right, gp_n, 2), "Nordland 0.5x": (summer[::10], winter[::5], nl_n, 10)}
    for name, (db, query, number, radius) in slower.items():
        d, x_d = linked(work, f"{name}-map".replace(" ", "_"), db, number)
        x_all = np.array([number(f) for f in query], np.float64)
        rows = []
        for a in (0, 1):
            q, x_q = linked(work, f"{name}-q{a}".replace(" ", "_"), query[a::2], number)
            rows.append(_as_is(d, x_d, q, x_q, radius, work / f"{q.name}-run")[1])
        cells = []
        for how in ("copied", "own", "filled"):
            answers = [rows[0][j // 2] if how == "copied" or j % 2 == 0 else rows[1][j // 2]
                       for j in range(len(query))]
            best, acc = np.array([b for b, _ in answers]), np.array([a for _, a in answers], bool)
            if how == "filled":
                best, _, filled = fill_between(best, np.zeros(best.size), acc, 2)
                acc = acc | filled
            right_ = acc & (best >= 0) & (np.abs(x_d[np.maximum(best, 0)] - x_all) <= radius)
            cells.append(f"{acc.sum()}, {right_.sum() / max(acc.sum(), 1):.3f}, {right_.sum() / len(query):.2f}")
        print(f"| {name} | {' | '.join(cells)} |", flush=True)


def cases(data: Path, root: Path) -> None:
    """The cases the localisation rule was chosen on (:mod:`research.studies.localize_decisions`), each query frame
    encoded as
    ``vpr localize`` does and answered by the map's localizer and by the :class:`vpr.shosm.SpeedFollower` around
    it: what following costs where the query is not driven at another speed (and the rendered ``speed_change``,
    where it is)."""
    import encoders
    from pipelines.extract import extract
    from pipelines.stream import StreamEncoder
    from research.studies.localize_decisions import CASES, case_sources
    from vpr import presets
    from vpr.evaluate import accepted_precision
    from vpr.shosm import SpeedFollower

    s = presets.resolve(None)
    print("\nthe localisation cases (research.studies.localize_decisions, default preset): accepted, P(acc), "
          "R(acc); frames "
          "answered at another sampling")
    print("| case | map | query | as they come | followed |")
    print("|---|---|---|---|---|")
    for case in CASES:
        m, q, hard, soft = case_sources(case, data, root)
        enc = encoders.get(s["encoder"], **s["encoder_conf"])
        ex = extract(m, enc, ("sdr",), progress=False)  # fitted on the map, as `vpr learn`
        qenc = StreamEncoder(enc)
        rows = [qenc.encode(f.image) for f in q]
        cells = []
        for follow in (False, True):
            loc = Localizer.from_database(ex.features.sdr, ex.features.names)
            run = SpeedFollower(loc, ex.features.sdr) if follow else loc
            ds = [run.update(r) for r in rows]
            a = accepted_precision(np.array([d.best for d in ds]), np.array([d.accepted for d in ds]), hard, soft)
            p = "-" if a["precision_accepted"] is None else f"{a['precision_accepted']:.3f}"
            cells.append(f"{a['n_accepted']}, {p}, {a['recall_accepted']:.2f}"
                         + (f"; {run.sampling()}" if follow and run.sampling() else ""))
        print(f"| {case} | {hard.shape[0]} | {hard.shape[1]} | {' | '.join(cells)} |", flush=True)


def picks(data: Path, root: Path) -> None:
    """How a frame picks one of the maps of one frame in 2 (:data:`vpr.shosm.PICKS`), batch and online, on every
    stream off the map's speed, and the choice made with each dataset held out in turn: the pick with the larger mean
    precision (then recall) on the other dataset's streams, reported on the held-out one. SDRs as ``vpr compare``
    encodes (each traverse standardised on its own frames), the same for both picks."""
    from vpr import methods
    from vpr.shosm import PICKS, SpeedFollower
    from vpr.types import EncodedTraverse

    rows: dict = {}
    print("\nthe map of one frame in 2 a frame is answered by: accepted, P(acc), R(acc), batch (match_at_speed) and "
          "online (SpeedFollower)")
    print(f"| stream | {' | '.join(f'batch, {k}' for k in PICKS)} | {' | '.join(f'online, {k}' for k in PICKS)} |")
    print("|---|" + "---|" * (2 * len(PICKS)))
    for name, (db, x_db), (query, x_q), radius in _streams(data, root):
        if name.endswith(" 1x"):
            continue
        D, Q = _encoded([db, query], ["database", "query"], root)
        with warnings.catch_warnings(action="ignore"):
            cells = []
            for online in (False, True):
                for pick in PICKS:
                    if online:
                        follower = SpeedFollower(Localizer.from_database(D.sdr, D.names), D.sdr, pick=pick)
                        ds = [follower.update(Q.sdr[j]) for j in range(len(Q))]
                        best, acc = np.array([d.best for d in ds]), np.array([d.accepted for d in ds], bool)
                    else:
                        r = methods.match_at_speed(methods.get("rshosm-seq").fit(EncodedTraverse(D.names, sdr=D.sdr)),
                                                   EncodedTraverse(Q.names, sdr=Q.sdr), pick=pick)
                        best, acc = r.best, r.accepted
                    right = acc & (best >= 0) & (np.abs(x_db[np.maximum(best, 0)] - x_q) <= radius)
                    n, tp = int(acc.sum()), int(right.sum())
                    rows[name, online, pick] = (tp / n if n else 0.0, tp / len(x_q))
                    cells.append(f"{n}, {'-' if not n else f'{tp / n:.3f}'}, {tp / len(x_q):.2f}")
        print(f"| {name} | {' | '.join(cells)} |", flush=True)
    print("\n| held out | pick chosen on the other dataset | on the held-out streams: mean P, mean R (batch; online) |")
    print("|---|---|---|")
    def mean(pick: str, online: bool, held: str, inside: bool) -> tuple[float, float]:
        """Mean precision and recall of ``pick`` over the streams of dataset ``held`` (``inside``) or the others."""
        vals = [v for (n, o, k), v in rows.items() if k == pick and o == online and n.startswith(held) == inside]
        return float(np.mean([p for p, _ in vals])), float(np.mean([r for _, r in vals]))

    for held in ("Gardens Point", "Nordland"):
        chosen = max(PICKS, key=lambda k: tuple(a + b for a, b in zip(mean(k, False, held, False),  # noqa: B023
                                                                     mean(k, True, held, False), strict=True)))
        (pb, rb), (po, ro) = mean(chosen, False, held, True), mean(chosen, True, held, True)
        print(f"| {held} | {chosen} | {pb:.3f}, {rb:.2f}; {po:.3f}, {ro:.2f} |", flush=True)


#: The bounds :func:`apart` compares (None: never undecided; 3: ``disagree``'s k + 1 at k = 2).
BOUNDS = (None, 5, 3)


def apart(data: Path, root: Path) -> None:
    """Where a faster query's two maps of one frame in 2 both accept a frame: how far apart they place it, how many
    of those frames one of them answers wrong (beyond the soft band), and the batch decisions (``match_at_speed``'s
    pick, between the two answers where they agree: :func:`vpr.shosm.between_maps`) with such frames left
    undecided beyond a bound of 3 (:func:`vpr.shosm.disagree`, the default) or 5 map frames, or never; then the
    bounds the larger mean precision, then recall, picks on one dataset's streams,
    reported on the other's. SDRs as ``vpr compare`` encodes them."""
    from vpr import methods
    from vpr.shosm import between_maps, pick_maps
    from vpr.types import EncodedTraverse

    rows: dict = {}
    print("\na faster query's two maps of one frame in 2, where both accept a frame: frames by how far apart they "
          "place it (map frames; with a wrong answer among them); the decisions with frames placed farther apart "
          "than a bound left undecided: accepted, P(acc), R(acc) (soft bands as above)")
    print("| stream | both accept | 1 apart | 3 apart | 5 apart | 7 or more | never undecided | bound 5 | bound 3 "
          "(default) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, (db, x_db), (query, x_q), radius in _streams(data, root):
        if not ("2x" in name or "1.5-2.5x" in name):
            continue
        D, Q = _encoded([db, query], ["database", "query"], root)
        with warnings.catch_warnings(action="ignore"):
            m = methods.get("rshosm-seq")
            dbt = EncodedTraverse(D.names, sdr=D.sdr)
            parts = [m.fit(dbt.take(np.arange(a, len(dbt), 2))).match(EncodedTraverse(Q.names, sdr=Q.sdr))
                     for a in (0, 1)]
        best = np.stack([np.where(p.best >= 0, 2 * p.best + a, -1) for a, p in enumerate(parts)])
        acc = np.stack([p.accepted for p in parts]) & (best >= 0)
        n_q = best.shape[1]
        chosen = pick_maps(np.stack([p.best for p in parts]), acc, np.stack([p.score for p in parts]))
        b, a = between_maps(best, acc, best[chosen, np.arange(n_q)], 2), acc[chosen, np.arange(n_q)]
        soft = SOFT[radius]
        err = np.abs(x_db[np.maximum(best, 0)] - x_q[None])
        wrong_one = (acc & (err > soft)).any(axis=0)
        both, diff = acc.all(axis=0), np.abs(best[0] - best[1])
        cells = [str(int(both.sum()))]
        for lo, hi in ((1, 1), (3, 3), (5, 5), (7, 10**9)):
            at = both & (diff >= lo) & (diff <= hi)
            cells.append(f"{int(at.sum())} ({int((at & wrong_one).sum())})")
        for bound in BOUNDS:
            keep = a & ~(both & (diff > bound)) if bound else a
            e = np.abs(x_db[np.maximum(b, 0)] - x_q)
            right, wrong = keep & (e <= radius), keep & (e > soft)
            n = int((right | wrong).sum())
            rows[name, bound] = (right.sum() / n if n else None, right.sum() / n_q)
            cells.append(f"{int(keep.sum())}, {'-' if not n else f'{right.sum() / n:.3f}'}, {right.sum() / n_q:.2f}")
        print(f"| {name} | {' | '.join(cells)} |", flush=True)
    print("\n| held out | bounds best on the other dataset (mean P, then mean R) | on the held-out streams: mean P, "
          "mean R of each |")
    print("|---|---|---|")
    for held in ("Gardens Point", "Nordland"):
        def mean(bound, inside, held=held):
            vals = [v for (n, k), v in rows.items() if k == bound and n.startswith(held) == inside]
            return (float(np.mean([p for p, _ in vals if p is not None] or [0.0])),
                    float(np.mean([r for _, r in vals])))
        top = max(mean(k, False) for k in BOUNDS)
        best = [k for k in BOUNDS if mean(k, False) == top]
        print(f"| {held} | {', '.join('never' if k is None else str(k) for k in best)} | "
              + "; ".join(f"{'never' if k is None else k}: {mean(k, True)[0]:.3f}, {mean(k, True)[1]:.2f}"
                          for k in best) + " |", flush=True)


def _contradicts(best, accepted, slower, j: int) -> bool:
    """Whether frame ``j``, answered at a slower speed, has an accepted answer more than one map frame behind, or more
    than two ahead of, the accepted answer of the frame before (a query moving less than a map frame a frame, each
    answer within a frame of its place)."""
    return bool(slower[j] and accepted[j] and accepted[j - 1] and not -1 <= best[j] - best[j - 1] <= 2)


def contradicting(best, accepted, slower) -> np.ndarray:
    """Per frame, :func:`_contradicts` (the first frame: False)."""
    return np.array([j > 0 and _contradicts(best, accepted, slower, j) for j in range(best.size)], bool)


def refusing(best, accepted, slower) -> np.ndarray:
    """``accepted`` with each contradicting frame (:func:`_contradicts`) refused, frame by frame as online (a refused
    frame's answer is no longer the one the next frame is held against)."""
    acc = np.array(accepted, bool)
    for j in range(1, best.size):
        if _contradicts(best, acc, slower, j):
            acc[j] = False
    return acc


def followed_frames(the_map: Path, query: Path, hold: float | None = None) -> tuple[list, np.ndarray, object]:
    """``vpr localize``'s follower (:class:`vpr.shosm.SpeedFollower`, the query encoded with running statistics)
    over ``query`` frame by frame against ``the_map`` (a ``vpr learn`` file): (decisions, the follower's mode after
    each frame, the follower). ``hold``: a frame sharing at least that share of its bits beyond chance with the frame
    before (:func:`shared_beyond_chance`) takes its decision without stepping the follower (the evidence held while
    the observation repeats; None: never)."""
    from pipelines.maps import load_map
    from pipelines.stream import StreamEncoder
    from vpr.shosm import SpeedFollower
    from vpr.sources import open_source

    m, enc = load_map(the_map)
    qenc, follower = StreamEncoder(enc, "running"), SpeedFollower(m.localizer, m.sdr)
    follower.warm_up()
    n_bits = m.localizer.memory.n_inputs
    out, modes, prev = [], [], None
    with warnings.catch_warnings(action="ignore"):
        for k, frame in enumerate(open_source(query)):
            row = qenc.encode(frame.image)
            bits = np.sort(row.indices.astype(np.int64))
            if hold is not None and out and shared_beyond_chance(bits, prev, n_bits) >= hold:
                out.append(dataclasses.replace(out[-1], frame=k))
            else:
                out.append(follower.update(row))
            modes.append(follower.mode)
            prev = bits
    return out, np.array(modes), follower


def shared_beyond_chance(a: np.ndarray, b: np.ndarray, n_bits: int) -> float:
    """The share of ``a``'s bits ``b`` has beyond chance (1: all of them, 0: as many as chance gives)."""
    chance = a.size * b.size / n_bits
    if a.size <= chance:
        return 0.0
    return (np.intersect1d(a, b, assume_unique=True).size - chance) / (a.size - chance)


def position_truth(x_db, x_q, radius: float, soft: float) -> tuple[np.ndarray, np.ndarray]:
    """(gt_hard, gt_soft), database x query, of frames at positions ``x_db`` and ``x_q`` within ``radius`` /
    ``soft``."""
    d = np.abs(np.asarray(x_db, float)[:, None] - np.asarray(x_q, float)[None, :])
    return d <= radius, d <= soft


def online(data: Path, root: Path) -> None:
    """Why ``vpr localize`` follows a query at another speed less well than ``vpr loops MAP QUERY`` does: the
    follower stepped frame by frame (:func:`followed_frames`), the frame it first reads another speed, what it
    answers before and after, and the wrong answers at a slower speed that contradict the frame before's
    (:func:`contradicting`) with what refusing them would give (measured, not built). The goal's measure (soft
    bands)."""
    from vpr.evaluate import accepted_precision

    print("\n`vpr localize` (follow) frame by frame, soft bands: accepted, P(acc), R(acc); the frame another speed is "
          "first read (and answers right before it); R(acc) over the frames from it; wrong answers before / after it, "
          "of them at a slower speed contradicting the frame before's, and of the others those in the replay's frames "
          "after the read (the engines of the speed started from those kept); those contradicting refused")
    print("| stream | frames | accepted, P, R | speed read at (right before) | R from it | wrong before / after "
          "(contradicting; others in the replay after) | contradicting refused: accepted, P, R |")
    print("|---|---|---|---|---|---|---|")
    for name, (db, x_db), (query, x_q), radius in _streams(data, root):
        if name.endswith(" 1x"):
            continue
        ds, mode, follower = followed_frames(_learned(root, db, positions_csv(root / f"{db.name}.csv", x_db)), query)
        best, acc = np.array([d.best for d in ds]), np.array([d.accepted for d in ds], bool)
        hard, soft = position_truth(x_db, x_q, radius, SOFT[radius])
        frames = np.arange(best.size)
        on = best >= 0
        right = on & hard[np.maximum(best, 0), frames]
        wrong = acc & on & ~soft[np.maximum(best, 0), frames]
        read = int(np.argmax(mode != 0)) if (mode != 0).any() else best.size
        after = accepted_precision(best[read:], acc[read:], hard[:, read:], soft[:, read:])
        contra = contradicting(best, acc, mode < 0)
        replay = (wrong & ~contra)[read:read + follower.replay]
        given, refused = (decisions_cell(accepted_precision(best, a, hard, soft), frames=False)
                          for a in (acc, refusing(best, acc, mode < 0)))
        print(f"| {name} | {best.size} | {given} | {read} ({int((acc & right)[:read].sum())}) | "
              f"{after['recall_accepted']:.2f} | {int(wrong[:read].sum())} / {int(wrong[read:].sum())} "
              f"({int((contra & wrong).sum())}; {int(replay.sum())}) | {refused} |",
              flush=True)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[3] / "shared" / "datasets",
                    help="the folder holding gardens_point_day/ and nordland_trimmed/")
    ap.add_argument("--out", type=Path, default=None, help="work folder (default: a temporary one)")
    ap.add_argument("--cases", action="store_true", help="only the localisation cases (several minutes: Nordland "
                    "at every file)")
    ap.add_argument("--one-run", action="store_true", help="only the table of loops within one folder")
    ap.add_argument("--apart", action="store_true", help="only the table of a faster query's maps that place a "
                    "frame apart")
    ap.add_argument("--online", action="store_true", help="only the table of vpr localize's follower frame by frame")
    ap.add_argument("--loops", action="store_true", help="only the loops table (vpr loops MAP QUERY) and the table of "
                    "the goal's measure (soft bands)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        root = args.out or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        only = {"cases": (cases,), "one_run": (one_run,), "loops": (loops, soft), "apart": (apart,),
                "online": (online,)}
        chosen = next((tables for flag, tables in only.items() if getattr(args, flag)), None)
        if chosen:
            for table in chosen:
                table(args.data, root)
            return
        print("AP, accepted, P(acc), R(acc) of rshosm-seq (default preset), query frames as they come; speed along "
              "the accepted paths, map frames per query frame (query frames counted)")
        print(f"| stream | {' | '.join(COMBOS)} |")
        print("|---|" + "---|" * len(COMBOS))
        for name, (db, x_db), (query, x_q), radius in _streams(args.data, root):
            gt = np.abs(x_db[:, None] - x_q[None, :]) <= radius
            cells = []
            for combo in COMBOS:
                S = None
                for model in combo.split("+"):
                    M = _similarity(db, query, model, root)
                    S = M if S is None else np.maximum(S, M)
                d = accept_path(S)
                best, acc = np.asarray(d.best), np.asarray(d.accepted, bool)
                right = gt[best, np.arange(best.size)] & (best >= 0)
                n, tp = int(acc.sum()), int((acc & right).sum())
                p = f"{tp / n:.3f}" if n else "-"
                cells.append(f"{average_precision(S, gt):.3f}, {n}, {p}, {tp / best.size:.2f}; speed "
                             f"{_speed_cell(best, acc)}")
            print(f"| {name} | {' | '.join(cells)} |", flush=True)
        commands(args.data, root)
        followed(args.data, root)
        loops(args.data, root)
        soft(args.data, root)
        phases(args.data, root)
        picks(args.data, root)
        apart(args.data, root)
        online(args.data, root)


if __name__ == "__main__":
    main()
