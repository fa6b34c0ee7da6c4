"""``vpr demo``: the whole pipeline on embedded defaults, no download.

Renders the ``two_seasons`` scene (a street driven on a summer day and on a
winter night, at different speeds), then runs ``vpr compare`` on it: the summer
traverse is the database, the winter traverse the query, ground truth comes
from the rendered positions. Prints the metrics table of the default preset's
methods (the headline method also with geometric verification of its best
candidates: :data:`vpr.presets.DEMO`), and writes everything
``compare`` writes to ``DIR`` (the render goes to ``DIR/scene`` and is reused by
the next run).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from pipelines.args import add_common_arguments, add_preset_argument, method_confs
from pipelines.render import parse_size
from pipelines.runs import RunOptions, run_compare
from vpr import io, presets, render
from vpr.config import parse_key_values
from vpr.groundtruth import GroundTruthSpec
from vpr.report import metrics_table

__all__ = ["COMMANDS", "add_arguments", "run_command", "run_demo", "render_once", "DEFAULTS"]

COMMANDS = {"demo": "render the two_seasons scene and compare the default preset's methods on it (no download)"}

#: Most frames per traverse ``--frames`` may ask for: the dense limit of the methods' matrices.
MAX_FRAMES = 20_000
#: Fewest frames per traverse ``--frames`` may ask for.
MIN_FRAMES = 20

#: every setting of the demo, in one place (:data:`vpr.presets.DEMO`)
DEFAULTS = presets.DEMO


def add_arguments(ap: argparse.ArgumentParser, command: str = "demo") -> None:
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--scene", default=DEFAULTS["scene"], help="builtin scene or spec file (default two_seasons)")
    add_preset_argument(ap)
    ap.add_argument("--encoder", help="encoder (default: the preset's)")
    ap.add_argument("--encoder-conf", action="append", metavar="KEY=VALUE",
                    help="encoder option, repeatable, merged over the preset's conf of the same encoder")
    ap.add_argument("--methods", help="comma-separated methods (default: the preset's)")
    ap.add_argument("--method-conf", action="append", default=[], metavar="METHOD.KEY=VALUE")
    ap.add_argument("--radius", type=float, default=DEFAULTS["radius"],
                    help="metres within which frames show the same place (default 3)")
    ap.add_argument("--soft-radius", type=float, default=DEFAULTS["soft_radius"],
                    help="pairs within this radius but outside --radius are ignored (default 10)")
    ap.add_argument("--verify", type=int, default=DEFAULTS["verify"],
                    help=f"geometric verification of the N best candidates of "
                         f"{', '.join(DEFAULTS['verify_methods'])} (default {DEFAULTS['verify']}; 0 = off)")
    ap.add_argument("--size", type=parse_size, metavar="WxH", help="render size override (default: the scene's)")
    ap.add_argument("--frames", type=int, help="frames per traverse override (for a quick run)")
    add_common_arguments(ap)


def render_once(scene, out: Path, size=None, n_frames=None, progress=True) -> dict:
    """Render ``scene`` into ``out`` unless the same render is already there."""
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
    io.save_json(marker, {"stamp": stamp, "result": result})
    return json.loads(json.dumps(result, default=str))


def run_demo(out, scene=DEFAULTS["scene"], radius=DEFAULTS["radius"], soft_radius=DEFAULTS["soft_radius"],
             verify=DEFAULTS["verify"], size=None, n_frames=None, progress=True, **settings) -> dict:
    """Render ``scene`` (once) and compare the methods on its first two traverses; print the table.

    ``settings``: ``preset`` (default ``DEFAULTS["preset"]``), ``encoder``, ``encoder_conf``, ``methods`` (a
    comma-separated string or a list) and ``method_conf`` (method -> dict), as :func:`vpr.presets.resolve` takes them;
    conf values may be strings. Returns :func:`pipelines.runs.run_compare`'s report.
    """
    out = Path(out)
    methods = settings.pop("methods", None)
    preset = settings.pop("preset", DEFAULTS["preset"])
    if isinstance(methods, str):
        methods = [m.strip() for m in methods.split(",") if m.strip()]
    # checked before rendering: a refused demo writes nothing
    if n_frames is not None and (isinstance(n_frames, bool) or int(n_frames) < MIN_FRAMES):
        raise ValueError(f"--frames {n_frames}: the demo needs at least {MIN_FRAMES} frames per traverse (sequence "
                         "methods compare stretches of frames)")
    if n_frames is not None and int(n_frames) > MAX_FRAMES:
        raise ValueError(f"--frames {n_frames}: the demo renders at most {MAX_FRAMES} frames per traverse (its "
                         "methods keep dense matrices); a longer drive: vpr render, then vpr compare")
    GroundTruthSpec(radius=radius, soft=soft_radius, files=("ground_truth.csv",)).check(files=False)
    s = presets.resolve(preset, methods=methods, **settings)
    encoder, methods = s["encoder"], s["methods"]
    t0 = time.perf_counter()
    rendered = render_once(scene, out / "scene", size=size, n_frames=n_frames, progress=progress)
    names = list(rendered["traverses"])
    if len(names) < 2:
        raise ValueError(f"scene {scene!r} has {len(names)} traverse(s); the demo needs two")
    db, query = (rendered["traverses"][n]["folder"] for n in names[:2])
    opts = RunOptions(out=out, methods=tuple(methods), preset=s["preset"], encoder=encoder,
                      encoder_conf=s["encoder_conf"],
                            method_conf=s["method_conf"],
                            gt=GroundTruthSpec(files=(rendered["ground_truth"],), radius=radius, soft=soft_radius),
                            verify=verify, progress=progress,
                            verify_methods=tuple(m for m in DEFAULTS["verify_methods"] if m in methods) or None,
                            verify_conf=dict(DEFAULTS["verify_conf"]))
    t_render = time.perf_counter() - t0
    report = run_compare(db, query, opts, command="demo")
    ms = report["methods"]
    t_verify = sum(v["seconds"] - ms[k[:-len("+verify")]]["seconds"] for k, v in ms.items() if k.endswith("+verify"))
    t_methods = sum(v["seconds"] for k, v in ms.items() if not k.endswith("+verify"))
    report["params"]["demo_seconds"] = {"render": t_render, "encode": sum(report["params"]["encode_seconds"].values()),
                                        "methods": t_methods, "verify": t_verify,
                                        "total": time.perf_counter() - t0}
    print(f"database: {names[0]} ({report['params']['n_db']} frames), query: {names[1]} "
          f"({report['params']['n_query']} frames), encoder {encoder}, ground truth: within "
          f"{radius:g} m (pairs within {soft_radius:g} m ignored)")
    print(metrics_table(report["methods"]))
    if verify:
        print(f"'+verify': each query's {verify} best candidates re-ordered by ORB + pycolmap RANSAC inliers "
              f"(other pairs keep their scores, so AP compares); P(acc) = precision of the accepted best matches")
    print("seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in report["params"]["demo_seconds"].items()))
    print(f"wrote {out}/report.html (open it: the table, the plots and the frames side by side), metrics.json, "
          f"pr.png, per-method folders; contact sheet {out}/scene/contact_sheet.png")
    return report


def run_command(args) -> int:
    run_demo(args.out, scene=args.scene, preset=args.preset, encoder=args.encoder,
             encoder_conf=None if args.encoder_conf is None else parse_key_values(args.encoder_conf, "--encoder-conf"),
             methods=args.methods, method_conf=method_confs(args.method_conf), radius=args.radius,
             soft_radius=args.soft_radius, verify=args.verify, size=args.size, n_frames=args.frames,
             progress=not args.no_progress)
    return 0
