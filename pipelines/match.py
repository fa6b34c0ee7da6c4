"""``vpr match``, ``vpr compare`` and ``vpr loops`` on the command line: arguments in, a run, the table out.

The runs themselves are :func:`pipelines.runs.run_compare` and
:func:`pipelines.runs.run_loops`; what they write is :mod:`pipelines.outputs`.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import encoders
from pipelines.args import (
    add_common_arguments,
    add_gt_arguments,
    add_method_conf_argument,
    add_preset_argument,
    add_source_arguments,
    gt_spec_from_args,
    method_confs,
)
from pipelines.detect import ONLINE_METHOD, detect_loops, make_detector
from pipelines.outputs import metrics_table
from pipelines.runs import RunOptions, exclude_frames, run_compare, run_loops
from vpr import methods, presets
from vpr.shosm import LOOP_EXCLUDE

__all__ = ["COMMANDS", "add_arguments", "settings_from_args", "options_from_args", "run_command"]

COMMANDS = {
    "match": "match a query traverse against a database traverse (folders, videos, lists)",
    "compare": "run several methods on the same database/query and tabulate their metrics",
    "loops": "loop closures within one traverse (the paper's setting)",
}


def add_arguments(ap: argparse.ArgumentParser, command: str) -> None:
    if command == "loops":
        ap.add_argument("seq", metavar="SEQ", help="image folder, video or image list; or - for image paths on stdin, "
                        "decided online one frame at a time (a JSON line per frame on stdout)")
    else:
        ap.add_argument("db", metavar="DB", help="database traverse: image folder, video or image list")
        ap.add_argument("query", metavar="QUERY", nargs="+",
                        help="query traverse(s): image folder, video or image list; several: a fleet, one folder "
                             "OUT/<query name> each, on Dask (--workers, --scheduler)")
    ap.add_argument("--out", required=True, help="output folder")
    # defaults None: a flag not given takes the preset's value (vpr.presets.resolve)
    add_preset_argument(ap)
    if command == "compare":
        ap.add_argument("--methods", help="comma-separated methods (default: the preset's)")
    else:
        ap.add_argument("--method", choices=methods.available(),
                        help="method (default: the preset's " + ("loop method" if command == "loops" else
                                                                 "first method") + ")")
    add_method_conf_argument(ap)
    encoders.add_arguments(ap, default=None)
    add_source_arguments(ap)
    if command == "loops":
        ap.add_argument("--exclude", default=None, metavar="W",
                        help="ignore matches fewer than W frames back, or W seconds for videos with 'Ws' "
                             f"(e.g. 5s; default {LOOP_EXCLUDE} frames)")
    add_gt_arguments(ap, loops=command == "loops")
    if command != "loops":
        fleet = ap.add_argument_group("several query traverses (a fleet)")
        fleet.add_argument("--workers", type=int, metavar="N",
                           help="run the query traverses on a local Dask cluster of N processes (default: the "
                                "cores); 0 runs them one after the other in this process")
        fleet.add_argument("--scheduler", metavar="ADDRESS",
                           help="run the query traverses on a running Dask cluster, e.g. tcp://host:8786")
    if command == "loops":
        online = ap.add_argument_group("online (SEQ is -)")
        online.add_argument("--state-out", metavar="FILE.npz", help="save the loop detector after the last frame")
        online.add_argument("--resume", metavar="FILE.npz", help="continue a loop detector saved with --state-out")
    if command != "loops":
        ap.add_argument("--verify", type=int, default=0, metavar="N",
                        help="geometric verification of each query's N best candidates (ORB + pycolmap)")
        ap.add_argument("--min-inliers", type=int, default=15, help="inliers needed to accept a verified match")
    ap.add_argument("--cache", metavar="DIR", help="encoding cache folder, e.g. one filled by `vpr encode` "
                    "(default: OUT/cache)")
    add_common_arguments(ap)


def settings_from_args(args) -> dict:
    """:func:`vpr.presets.resolve` of ``--preset`` with the flags given (``--methods`` / ``--method``)."""
    if getattr(args, "methods", None) is not None:
        names = [m.strip() for m in args.methods.split(",") if m.strip()]
    else:
        names = [args.method] if getattr(args, "method", None) else None
    s = presets.resolve(args.preset, encoder=args.encoder, encoder_conf=encoders.parse_conf(args.encoder_conf),
                        methods=names, method_conf=method_confs(args.method_conf), loops=args.command == "loops")
    if names is None and args.command != "compare":  # one method: the preset's headline or loop method
        s["methods"] = [s["loop_method"] if args.command == "loops" else s["methods"][0]]
    return s


def options_from_args(args) -> RunOptions:
    """The :class:`RunOptions` of parsed ``match`` / ``compare`` / ``loops`` arguments."""
    s = settings_from_args(args)
    return RunOptions(
        out=Path(args.out), preset=s["preset"], encoder=s["encoder"], encoder_conf=s["encoder_conf"],
        method_conf=s["method_conf"], fps=args.fps, step=args.step, max_frames=args.max_frames,
        gt=gt_spec_from_args(args),
        verify=getattr(args, "verify", 0), min_inliers=getattr(args, "min_inliers", 15),
        progress=not args.no_progress, cache=Path(args.cache) if args.cache else None)


def _run_online(args) -> int:
    """``vpr loops -``: refuse what does not apply to a stream on stdin, then decide it frame by frame."""
    given = [f for f, v in (("--fps", args.fps), ("--step", args.step), ("--max-frames", args.max_frames),
                            ("--cache", args.cache)) if v is not None]
    if given:
        raise ValueError(f"vpr loops -: {', '.join(given)} apply to a folder or video, not to image paths on stdin")
    if args.exclude is not None and str(args.exclude).strip().lower().endswith("s"):
        raise ValueError(f"vpr loops -: --exclude {args.exclude} in seconds needs a video's frame rate; give frames")
    exclude = exclude_frames(LOOP_EXCLUDE if args.exclude is None else args.exclude, None)
    if args.resume is None:
        method = settings_from_args(args)["methods"][0]
        if method != ONLINE_METHOD:
            raise ValueError(f"vpr loops -: online loop closure is {ONLINE_METHOD}'s, not {method}'s "
                             f"(--method {ONLINE_METHOD}, or a folder or video for {method})")
    elif args.exclude is not None:
        raise ValueError("vpr loops -: --exclude is the saved detector's with --resume")
    det = make_detector(args.preset, args.encoder, encoders.parse_conf(args.encoder_conf),
                        method_confs(args.method_conf), exclude=exclude, resume=args.resume)
    report = detect_loops(det, args.out, gt=gt_spec_from_args(args), state_out=args.state_out)
    m = report["methods"][ONLINE_METHOD]
    lat = m["latency_ms"]
    print(f"vpr loops: {m['frames']} frames, {m['n_accepted']} loop closures accepted, latency median "
          f"{lat['with_encoding']['median']:.2f} ms ({lat['without_encoding']['median']:.2f} ms without encoding); "
          f"wrote {args.out}/metrics.json", file=sys.stderr)
    return 0


def run_command(args) -> int:
    if args.command == "loops" and args.seq == "-":
        return _run_online(args)
    if args.command == "loops" and (args.state_out or args.resume):
        raise ValueError("--state-out and --resume are for online loop closure: SEQ - (image paths on stdin)")
    opts = options_from_args(args)
    names = settings_from_args(args)["methods"]
    if args.command != "loops" and len(args.query) > 1:
        from pipelines.fleet import run_fleet, summary_table

        def said(name, done, total):
            print(f"vpr {args.command}: query {name} done ({done} of {total})", file=sys.stderr, flush=True)

        summary = run_fleet(args.db, args.query, names, opts, command=args.command, workers=args.workers,
                            scheduler=args.scheduler, progress=said)
        print(summary_table(summary))
        print(f"wrote {args.out}/metrics.json and a folder per query")
        return 0
    if args.command != "loops" and (args.workers is not None or args.scheduler is not None):
        raise ValueError("--workers and --scheduler run several query traverses in parallel; give more than one "
                         "QUERY (one query runs in this process)")
    if args.command == "loops":
        report = run_loops(args.seq, names[0], opts, exclude=LOOP_EXCLUDE if args.exclude is None else args.exclude)
    else:
        report = run_compare(args.db, args.query[0], names, opts, command=args.command)
    print(metrics_table(report["methods"], "loops" if args.command == "loops" else "match"))
    print(f"wrote {args.out}/metrics.json")
    return 0
