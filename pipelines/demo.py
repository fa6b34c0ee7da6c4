"""``vpr demo``: the whole pipeline on embedded defaults, no download.

Renders the ``two_seasons`` scene (a street driven on a summer day and on a
winter night, at different speeds), then runs ``vpr compare`` on it: the summer
traverse is the database, the winter traverse the query, ground truth comes
from the rendered positions. Prints the metrics table of rSHOSM, SeqSLAM and
pairwise (and ``rshosm-seq``, our sequence-evidence extension of rSHOSM), with
and without geometric verification, and writes everything
``compare`` writes to ``DIR`` (the render goes to ``DIR/scene`` and is reused by
the next run).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from pipelines import match

__all__ = ["add_arguments", "run_command", "DEFAULTS"]

DEFAULTS = {"scene": "two_seasons", "encoder": "pixel", "encoder_conf": ["k=200", "standardise=fit"],
            "methods": "rshosm,rshosm-seq,seqslam,pairwise", "radius": 3.0, "soft_radius": 10.0, "verify": 5}


def add_arguments(ap: argparse.ArgumentParser, command: str = "demo") -> None:
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--scene", default=DEFAULTS["scene"], help="builtin scene or spec file (default two_seasons)")
    ap.add_argument("--encoder", default=DEFAULTS["encoder"], help=f"encoder (default {DEFAULTS['encoder']})")
    ap.add_argument("--encoder-conf", action="append", metavar="KEY=VALUE",
                    help=f"encoder option, repeatable (default: {' '.join(DEFAULTS['encoder_conf'])}: "
                         "200 of 2048 bits, each traverse standardised on its own frames)")
    ap.add_argument("--methods", default=DEFAULTS["methods"], help=f"default {DEFAULTS['methods']}")
    ap.add_argument("--method-conf", action="append", default=[], metavar="METHOD.KEY=VALUE")
    ap.add_argument("--radius", type=float, default=DEFAULTS["radius"],
                    help="metres within which frames show the same place (default 3)")
    ap.add_argument("--soft-radius", type=float, default=DEFAULTS["soft_radius"],
                    help="pairs within this radius but outside --radius are ignored (default 10)")
    ap.add_argument("--verify", type=int, default=DEFAULTS["verify"],
                    help="geometric verification of the N best candidates (default 5; 0 = off)")
    ap.add_argument("--size", help="render size WxH override (default: the scene's)")
    ap.add_argument("--frames", type=int, help="frames per traverse override (for a quick run)")
    ap.add_argument("--no-progress", action="store_true")


def render_once(scene, out: Path, size=None, n_frames=None, progress=True) -> dict:
    """Render ``scene`` into ``out`` unless the same render is already there."""
    from vpr import render

    spec = render.load_spec(scene)
    stamp = {"spec": spec, "size": size, "n_frames": n_frames}
    marker = out / "demo_render.json"
    if marker.is_file() and (out / "ground_truth.csv").is_file():
        try:
            done = json.loads(marker.read_text())
            if done.get("stamp") == json.loads(json.dumps(stamp)):
                return done["result"]
        except (ValueError, KeyError):
            pass
    result = render.write_scene(spec, out, preview=True, size=size, n_frames=n_frames, progress=progress)
    from vpr import io

    io.save_json(marker, {"stamp": stamp, "result": result})
    return json.loads(json.dumps(result, default=str))


def _size(text):
    if text is None:
        return None
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size: expected WxH, e.g. 320x240, got {text!r}") from None
    return (w, h)


def run_command(args) -> int:
    out = Path(args.out)
    rendered = render_once(args.scene, out / "scene", size=_size(args.size), n_frames=args.frames,
                           progress=not args.no_progress)
    names = list(rendered["traverses"])
    if len(names) < 2:
        raise ValueError(f"scene {args.scene!r} has {len(names)} traverse(s); the demo needs two")
    db, query = (rendered["traverses"][n]["folder"] for n in names[:2])
    argv = [db, query, "--out", str(out), "--methods", args.methods, "--encoder", args.encoder,
            "--gt", rendered["ground_truth"], "--radius", str(args.radius), "--gt-soft", str(args.soft_radius),
            "--verify", str(args.verify)]
    for kv in DEFAULTS["encoder_conf"] if args.encoder_conf is None else args.encoder_conf:
        argv += ["--encoder-conf", kv]
    for kv in args.method_conf:
        argv += ["--method-conf", kv]
    if args.no_progress:
        argv.append("--no-progress")
    ap = argparse.ArgumentParser(prog="vpr compare")
    match.add_arguments(ap, "compare")
    cargs = ap.parse_args(argv)
    cargs.command = "compare"
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    report = match.run_compare(cargs, methods)
    print(f"database: {names[0]} ({report['params']['n_db']} frames), query: {names[1]} "
          f"({report['params']['n_query']} frames), encoder {args.encoder}, ground truth: within "
          f"{args.radius:g} m (pairs within {args.soft_radius:g} m ignored)")
    print(match.metrics_table(report["methods"]))
    if args.verify:
        print(f"'+verify': best of {args.verify} candidates re-ranked by ORB + pycolmap RANSAC inliers; "
              f"P(acc) = precision of the accepted best matches")
    print(f"wrote {out}/metrics.json, pr.png, per-method folders; contact sheet {out}/scene/contact_sheet.png")
    return 0
