"""Command-line pieces that several sub-commands share: common flags, sources, presets, ground truth, confs.

Every sub-command calls :func:`add_common_arguments` (``--no-progress``), so the
same common flags work everywhere; the others are added where they apply.
"""
from __future__ import annotations

import argparse
import math
import re
from pathlib import Path

import encoders
from vpr import methods, presets
from vpr.config import parse_key_values, parse_method_confs
from vpr.evaluate import RECALL_AT
from vpr.groundtruth import NAMES_RADIUS, GroundTruthSpec
from vpr.sources import is_descriptor_file

__all__ = ["add_recall_at_argument", "parse_recall_at", "add_prefix_arguments",
           "add_common_arguments", "add_source_arguments", "add_preset_argument", "add_gt_arguments",
           "gt_spec_from_args", "loop_geometry", "descriptor_inputs", "input_encoder", "input_preset", "method_confs",
           "add_method_conf_argument", "add_run_arguments", "settings_from_args", "options_from_args", "parse_every",
           "parse_size", "add_query_speed_argument", "follows_speed", "DESCRIPTORS"]

_UNITS = {"": 2**30, "b": 1, "k": 2**10, "m": 2**20, "g": 2**30, "t": 2**40}

def add_common_arguments(ap) -> None:
    """The flags every sub-command takes."""
    ap.add_argument("--no-progress", action="store_true", help="no progress bars (none are drawn off a terminal)")


def add_source_arguments(ap) -> None:
    """``--fps``, ``--step``, ``--max-frames``, ``--every`` and ``--topic``: which frames of the sources are read."""
    ap.add_argument("--fps", type=float, help="videos and bags: resample to this frame rate, by the frames' times")
    ap.add_argument("--step", type=int, help="keep every STEP-th frame")
    ap.add_argument("--max-frames", type=int, help="read at most this many frames per source")
    ap.add_argument("--every", metavar="DISTANCE", help="keep one frame per DISTANCE of travel, e.g. 2m (needs the "
                    "frames' positions: --gt-topic, or --gt with --radius)")
    ap.add_argument("--topic", nargs="+", metavar="NAME", help="ROS bags: the camera topic (sensor_msgs/Image or "
                    "CompressedImage; default: the bag's only image topic that is not depth); one for all inputs "
                    "or one per input, in order")


def add_prefix_arguments(ap, db: bool = True, query: bool = True) -> None:
    """``--db-prefix`` / ``--query-prefix`` (hloc's spelling): one ``.h5`` of global features holding the database's
    and the queries' frames, told apart by the beginning of their names."""
    group = ap.add_argument_group("one hloc .h5 for the database and the queries (as hloc's pairs_from_retrieval)")
    if db:
        group.add_argument("--db-prefix", metavar="PREFIX", help="the database's frames: the .h5's names that begin "
                           "with PREFIX (e.g. db/)")
    if query:
        group.add_argument("--query-prefix", metavar="PREFIX", help="the query's frames: the .h5's names that begin "
                           "with PREFIX (e.g. query/)")


def add_preset_argument(ap) -> None:
    """``--preset NAME`` (default ``default``): the settings that flags not given take."""
    ap.add_argument("--preset", default=None, choices=presets.available(),
                    help=f"named settings (encoder, its conf, methods, their confs) that explicit flags override: "
                         f"{presets.describe()} (default: {presets.DEFAULT})")


def add_gt_arguments(ap, loops: bool = False, title: str = "ground truth (optional; enables metrics and pr.png)"):
    """The ground-truth options (``--gt``, ``--radius``, ``--gt-soft``; ``--tolerance`` between two traverses)."""
    gt = ap.add_argument_group(title)
    if loops:
        gt.add_argument("--gt", nargs="+", metavar="FILE",
                        help="positions CSV (frame,x,y or traverse,frame,x,y) with --radius; a CSV of frame,earlier "
                             "pairs; or a frame x frame matrix: .npy, .png/.bmp (nonzero = loop) or .mat[:VARIABLE] "
                             "(a second matrix: the soft ground truth)")
    else:
        gt.add_argument("--tolerance", type=int, metavar="K",
                        help="frame-aligned traverses: |i - j| <= K, in frames kept (after --step, --fps, --every): "
                             "at --step 10, --tolerance 1 is 10 input frames")
        gt.add_argument("--gt", nargs="+", metavar="FILE",
                        help="CSV of query,db pairs; a db x query matrix (GThard.npy [GTsoft.npy]) or VPR-Bench's "
                             "ground_truth_new.npy; or with --radius: one positions CSV per traverse "
                             "(frame,x,y), or one CSV with traverse,frame,x,y rows for both; one TUM trajectory or "
                             "KITTI poses file per traverse; or the word names (UTM in the file names) or exif")
    if not loops:
        gt.add_argument("--gt-tolerance-unit", type=int, metavar="N",
                        help="--gt of query,db,tolerance rows (OpenSeqSLAM's ground truth, frames counted from 1): "
                             "the frames its tolerance counts per frame of the file; a query matches the database "
                             "frames within tolerance // N of its reference (10 for OpenSeqSLAM's Nordland sample)")
    gt.add_argument("--gt-topic", nargs="+", metavar="TOPIC", help="ROS bags: positions from this topic (NavSatFix in "
                    "metres from the first fix, Odometry, PoseStamped), interpolated at each frame's time, not across "
                    "an outage; with --radius; one for all inputs or one per input, in order")
    gt.add_argument("--radius", type=float, help="match radius for position ground truth (same unit as x, y)")
    gt.add_argument("--gt-soft", type=float, metavar="R2",
                    help="also ignore pairs within this larger radius/tolerance (soft ground truth; a tolerance in "
                         "frames kept, as --tolerance)")
    return gt


def add_recall_at_argument(ap: argparse.ArgumentParser) -> None:
    """``--recall-at``: the N of Recall@N (:func:`parse_recall_at`)."""
    ap.add_argument("--recall-at", default=None, metavar="N1,N2,...",
                    help="the N of Recall@N, over every query (the field's) and over the queries with a true match "
                         f"(default {','.join(map(str, RECALL_AT))}; needs ground truth)")


def parse_recall_at(args) -> tuple:
    """``--recall-at 1,5,10,20`` -> (1, 5, 10, 20) (refused: not positive integers, or without ground truth)."""
    if args.recall_at is None:
        return RECALL_AT
    try:
        ns = tuple(int(n) for n in args.recall_at.split(","))
    except ValueError:
        ns = ()
    if not ns or any(n < 1 for n in ns):
        raise ValueError(f"--recall-at {args.recall_at}: positive integers separated by commas, e.g. 1,5,10,20")
    gt = gt_spec_from_args(args)
    if not (gt.files or gt.tolerance is not None or gt.topic is not None):
        raise ValueError("--recall-at needs ground truth (--gt, --tolerance or --gt-topic) to score recall")
    return ns


def gt_spec_from_args(args) -> GroundTruthSpec:
    """The :class:`GroundTruthSpec` of the options added by :func:`add_gt_arguments` (``--gt names`` without
    ``--radius``: :data:`vpr.groundtruth.NAMES_RADIUS`, the field's)."""
    files = tuple(args.gt or ())
    radius = NAMES_RADIUS if args.radius is None and files == ("names",) else args.radius
    return GroundTruthSpec(tolerance=getattr(args, "tolerance", None), files=files, radius=radius, soft=args.gt_soft,
                           topic=topic_arg(getattr(args, "gt_topic", None)),
                           file_unit=getattr(args, "gt_tolerance_unit", None))


def topic_arg(values):
    """``--topic`` / ``--gt-topic`` as given: None, one topic (str) or one per input (tuple)."""
    return None if not values else values[0] if len(values) == 1 else tuple(values)


def method_confs(items) -> dict:
    """Per-method conf (strings) from ``--method-conf METHOD.key=value`` items (repeatable)."""
    return parse_method_confs(items, methods.available())


def add_query_speed_argument(ap: argparse.ArgumentParser, sessions: bool = False) -> None:
    """``--query-speed follow|as-is``: whether a query driven at another speed than its database or map at the same
    frame rate (``sessions``: a later session than the earlier ones) is followed (:func:`follows_speed`)."""
    query, db = ("a later session's", "the earlier sessions'") if sessions else ("the query's", "the database's")
    ap.add_argument("--query-speed", choices=("follow", "as-is"), default=None,
                    help=f"follow (default): while {query} best frames move 1.5 or more times faster or slower than "
                         f"one of {db} a frame, match it against {db} maps of one frame in k, or as k queries of one "
                         "frame in k, and say it; as-is: its frames as they come (the speed is said)")


def follows_speed(args) -> bool:
    """Whether the command's ``--query-speed`` follows the query's speed (commands without the option: no)."""
    return getattr(args, "query_speed", "as-is") in (None, "follow")


def add_field_files_arguments(ap: argparse.ArgumentParser, pairs: bool = True) -> None:
    """``--top``, ``--pairs`` (where the command has no pairs of its own) and ``--mat``: the files the field's tools
    read (:func:`pipelines.outputs.write_ranked`)."""
    files = ap.add_argument_group("files the field's tools read")
    files.add_argument("--top", type=int, default=20, metavar="N",
                       help="each query's N best database frames with their scores, METHOD/top.csv (default 20; 0: "
                            "none)")
    if pairs:
        files.add_argument("--pairs", type=int, default=0, metavar="N",
                           help="hloc's retrieval pairs file of each query's N best, METHOD/pairs-query-METHODN.txt")
    files.add_argument("--mat", action="store_true",
                       help="METHOD/similarity.mat for MATLAB (S database x query, best counted from 1, score, "
                            "accepted)")


def field_files(args, pairs: bool = True) -> dict:
    """``top``, ``pairs`` (0 where the command's ``--pairs`` is its own: ``pairs`` False) and ``mat`` of
    :func:`add_field_files_arguments`, checked."""
    counts = {"--top": args.top, **({"--pairs": args.pairs} if pairs else {})}
    for flag, n in counts.items():
        if n < 0:
            raise ValueError(f"{flag} {n}: a number of database frames per query, 0 or more")
    return {"top": args.top, "pairs": args.pairs if pairs else 0, "mat": args.mat}


def add_method_conf_argument(ap: argparse.ArgumentParser) -> None:
    """``--method-conf METHOD.KEY=VALUE`` (repeatable)."""
    ap.add_argument("--method-conf", action="append", default=[], metavar="METHOD.KEY=VALUE",
                    help=f"method option, repeatable, e.g. {' or '.join(presets.CONF_EXAMPLES)}")


def add_run_arguments(ap: argparse.ArgumentParser, method_help: str) -> None:
    """The settings every run over traverses takes: ``--out``, the preset, methods and their confs, the encoder,
    the sources' frames, the cache (``vpr match``, ``compare``, ``loops``)."""
    ap.add_argument("--out", required=True, help="output folder")
    # defaults None: a flag not given takes the preset's value (vpr.presets.resolve)
    add_preset_argument(ap)
    if method_help == "methods":
        ap.add_argument("--methods", metavar="M1,M2,...",
                        help=f"comma-separated methods, of {{{','.join(methods.available())}}} (default: the preset's)")
    else:
        ap.add_argument("--method", choices=methods.available(), help=f"method (default: the preset's {method_help})")
    add_method_conf_argument(ap)
    encoders.add_arguments(ap, default=None)
    add_source_arguments(ap)
    ap.add_argument("--cache", metavar="DIR", help="encoding cache folder, e.g. one filled by `vpr encode` "
                    "(default: OUT/cache)")
    ap.add_argument("--memory-budget", metavar="SIZE", help="memory the run's dense matrices may take, e.g. 4GB; "
                    "beyond it they are top-K (default: an eighth of this machine's memory)")


def settings_from_args(args) -> dict:
    """The run's settings, resolved once: :func:`vpr.presets.resolve` of ``--preset`` with the flags given.

    ``methods``: ``--methods`` / ``--method``, else the preset's (``compare``:
    all of them; ``loops``: its loop method; others: its headline); ``images``: whether the inputs are images (not
    descriptor files, whose preset is ``descriptors``).
    """
    given = descriptor_inputs(args)
    encoder, preset = input_encoder(args, given), input_preset(args, given)
    if getattr(args, "methods", None) is not None:
        names = [m.strip() for m in args.methods.split(",") if m.strip()]
    else:
        names = [args.method] if getattr(args, "method", None) else None
    enc_conf = parse_key_values(args.encoder_conf, "--encoder-conf")
    confs = parse_method_confs(args.method_conf, methods.available())
    s = presets.resolve(preset, encoder=encoder, encoder_conf=enc_conf, methods=names, method_conf=confs,
                        loops=args.command == "loops")
    if names is None and args.command != "compare":  # one method: the preset's headline or loop method
        s["methods"] = [s["loop_method"] if args.command == "loops" else s["methods"][0]]
        # the preset's confs of the methods not run are not the user's: only a --method-conf given is said unused
        s["method_conf"] = {m: c for m, c in s["method_conf"].items() if m in s["methods"] or m in confs}
    s["images"] = not given  # the inputs are images, not descriptor files
    return s


#: the encoder of descriptor files (:mod:`encoders.descriptors`)
DESCRIPTORS = "descriptors"


def input_encoder(args, given: list[str]) -> str | None:
    """``--encoder``, or for descriptor files (``given``: :func:`descriptor_inputs`) their sparsifier (another encoder
    refused)."""
    if given and args.encoder not in (None, DESCRIPTORS):
        raise ValueError(f"{given[0]} holds descriptors: --encoder {DESCRIPTORS} (their random-projection top-k) "
                         f"reads them, not --encoder {args.encoder}")
    return DESCRIPTORS if given else args.encoder


def input_preset(args, given: list[str]) -> str | None:
    """``--preset``, or for descriptor files (``given``: :func:`descriptor_inputs`) their own, ``descriptors``."""
    return args.preset if args.preset is not None or not given else DESCRIPTORS


def descriptor_inputs(args) -> list[str]:
    """The command's inputs if they are descriptor files (a mix with images refused), else []."""
    paths = [str(p) for a in ("db", "query", "seq", "sources") for p in _listed(getattr(args, a, None))]
    found = [p for p in paths if is_descriptor_file(p)]
    if found and len(found) < len(paths):
        other = next(p for p in paths if not is_descriptor_file(p))
        raise ValueError(f"{found[0]} holds descriptors and {other} does not: give every traverse as descriptors "
                         "(.npy, .h5) or every one as images")
    return found


def _listed(value) -> list:
    return [] if value is None else list(value) if isinstance(value, (list, tuple)) else [value]


def options_from_args(args, settings: dict | None = None, **own):
    """The :class:`pipelines.runs.RunOptions` of parsed run arguments: the settings (:func:`settings_from_args`, or
    those given), the sources' frames, the ground truth and where the run goes; ``own``: the command's own options
    (``vpr loops``: ``exclude``, ``geometry``)."""
    from pipelines.runs import RunOptions  # the runs' module loads the methods: only once a run is under way

    every = parse_every(args.every) if args.every else None
    budget = None if args.memory_budget is None else parse_size(args.memory_budget)
    gt = gt_spec_from_args(args)
    s = settings_from_args(args) if settings is None else settings
    return RunOptions(**own, images=s["images"],
        out=Path(args.out), methods=tuple(s["methods"]), preset=s["preset"], encoder=s["encoder"],
        encoder_conf=s["encoder_conf"], method_conf=s["method_conf"], fps=args.fps, step=args.step,
        max_frames=args.max_frames, gt=gt, topic=topic_arg(args.topic),
        every=every,
        verify=getattr(args, "verify", 0), min_inliers=getattr(args, "min_inliers", 15),
        workers=getattr(args, "workers", None), scheduler=getattr(args, "scheduler", None),
        progress=not args.no_progress, cache=Path(args.cache) if args.cache else None,
        memory_budget=budget, follow_speed=follows_speed(args), db_prefix=getattr(args, "db_prefix", None),
        query_prefix=getattr(args, "query_prefix", None))


def loop_geometry(method: str, given: str | None, images: bool = True) -> bool:
    """Whether ``method``'s loop closures get the geometric second opinion: ``--geometry`` (``on`` refused for a method
    that does not decide them frame by frame, or without ``images``: descriptor files), by default where it does."""
    decides = methods.get_class(method).decides_frames
    if given == "on" and not decides:
        raise ValueError(f"--geometry on: a second opinion on the closures of a method that decides them frame by "
                         f"frame, not on {method}'s")
    if given == "on" and not images:
        raise ValueError("--geometry on matches the images' keypoints: descriptor files hold no images")
    return decides and images and given != "off"


def parse_every(text) -> float:
    """``--every 2m`` (or ``2``, metres) -> 2.0; ValueError naming the option otherwise."""
    s = str(text).strip().lower()
    s = s[:-1] if s.endswith("m") else s
    try:
        v = float(s)
    except ValueError:
        v = float("nan")
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"--every must be a distance in metres like 2m, got {text!r}")
    return v


def parse_size(text, option: str = "--memory-budget") -> int:
    """Bytes of a size such as ``4GB``, ``512MB``, ``2g``, ``100B`` or ``1.5`` (GiB without a unit; units are
    powers of 1024). Raises ValueError naming ``option``."""
    m = re.fullmatch(r"\s*(\d*\.?\d+)\s*([kmgt]?)(i?b)?\s*", str(text).lower())
    if not m or float(m.group(1)) <= 0:
        raise ValueError(f"{option}: a size such as 4GB or 512MB, got {text!r}")
    unit = m.group(2) or ("b" if m.group(3) else "")
    return int(float(m.group(1)) * _UNITS[unit])
