"""``vpr match``, ``vpr compare`` and ``vpr loops``: image folders, videos or lists in,
similarity matrices, matches, metrics and plots out.

Outputs in ``out`` (one method: in it; several: one sub-folder per method):
``similarity.npy`` (float32 db x query; a top-K sparse ``similarity_topk.npz`` for
large inputs), ``matches.csv`` (query, best_db, score, accepted, ...),
``similarity.png``; and in ``out`` ``pr.png`` (with ground truth), ``metrics.json``
and ``config.json`` (everything needed to repeat the run). Encodings are cached
in ``out/cache``.

:func:`run_compare` and :func:`run_loops` do the work from explicit parameters
(:class:`RunOptions`); :func:`run_command` only adapts the parsed command line.
"""
from __future__ import annotations

import argparse
import csv
import platform
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp

import encoders
from pipelines.extract import extract
from vpr import evaluate, io, methods, plots
from vpr.config import parse_key_values
from vpr.groundtruth import GroundTruthSpec, build_gt, positions_of_frames
from vpr.methods import MatchResult
from vpr.sources import open_source

__all__ = ["COMMANDS", "add_arguments", "run_command", "RunOptions", "run_compare", "run_loops", "method_confs",
           "metrics_table", "method_metrics", "write_similarity", "write_matches", "versions"]

COMMANDS = {
    "match": "match a query traverse against a database traverse (folders, videos, lists)",
    "compare": "run several methods on the same database/query and tabulate their metrics",
    "loops": "loop closures within one traverse (the paper's setting)",
}


@dataclass
class RunOptions:
    """Everything but the inputs and the methods of a ``match`` / ``compare`` / ``loops`` run.

    ``encoder_conf`` and ``method_conf`` (method -> conf) values may be strings
    (from the command line): they are read as the defaults' types.
    ``fps``, ``step`` and ``max_frames`` are passed to :func:`vpr.sources.open_source`.
    """

    out: Path
    encoder: str = "pixel"
    encoder_conf: dict = field(default_factory=dict)
    method_conf: dict = field(default_factory=dict)
    fps: float | None = None
    step: int | None = None
    max_frames: int | None = None
    gt: GroundTruthSpec = field(default_factory=GroundTruthSpec)
    verify: int = 0
    min_inliers: int = 15
    progress: bool = True
    cache: Path | None = None


# ------------------------------------------------------------------ arguments
def method_confs(items) -> dict:
    """Per-method conf (strings) from ``--method-conf METHOD.key=value`` items (repeatable)."""
    confs: dict = {}
    for head, value in parse_key_values(items, "--method-conf").items():
        method, dot, key = head.partition(".")
        if not dot or not key:
            raise ValueError(f"--method-conf: expected METHOD.key=value, got {head}={value!r}")
        if method not in methods.available():
            raise ValueError(f"--method-conf: unknown method {method!r}; available: {', '.join(methods.available())}")
        confs.setdefault(method, {})[key] = value
    return confs


def _add_source_args(ap):
    ap.add_argument("--fps", type=float, help="videos: resample to this frame rate")
    ap.add_argument("--step", type=int, help="keep every STEP-th frame")
    ap.add_argument("--max-frames", type=int, help="read at most this many frames per source")


def add_arguments(ap: argparse.ArgumentParser, command: str) -> None:
    if command == "loops":
        ap.add_argument("seq", metavar="SEQ", help="image folder, video or image list")
    else:
        ap.add_argument("db", metavar="DB", help="database traverse: image folder, video or image list")
        ap.add_argument("query", metavar="QUERY", help="query traverse: image folder, video or image list")
    ap.add_argument("--out", required=True, help="output folder")
    if command == "compare":
        ap.add_argument("--methods", default="rshosm,seqslam,pairwise",
                        help="comma-separated methods (default: rshosm,seqslam,pairwise)")
    else:
        default = "rshosm-seq" if command == "loops" else "rshosm"  # issue 12: loops default (presets may own it)
        ap.add_argument("--method", default=default, choices=methods.available(),
                        help=f"method (default: {default})")
    ap.add_argument("--method-conf", action="append", default=[], metavar="METHOD.KEY=VALUE",
                    help="method option, repeatable, e.g. seqslam.ds=20 or rshosm.p_extra=0.01")
    encoders.add_arguments(ap)
    _add_source_args(ap)
    gt = ap.add_argument_group("ground truth (optional; enables metrics and pr.png)")
    if command == "loops":
        ap.add_argument("--exclude", default="30", metavar="W",
                        help="ignore matches fewer than W frames back, or W seconds for videos with 'Ws' "
                             "(e.g. 5s; default 30 frames)")
        gt.add_argument("--gt", nargs="+", metavar="FILE",
                        help="positions CSV (frame,x,y or traverse,frame,x,y) with --radius")
    else:
        gt.add_argument("--tolerance", type=int, metavar="K", help="frame-aligned traverses: |i - j| <= K")
        gt.add_argument("--gt", nargs="+", metavar="FILE",
                        help="CSV of query,db pairs; or with --radius: one positions CSV per traverse "
                             "(frame,x,y), or one CSV with traverse,frame,x,y rows for both")
    gt.add_argument("--radius", type=float, help="match radius for position ground truth (same unit as x, y)")
    gt.add_argument("--gt-soft", type=float, metavar="R2",
                    help="also ignore pairs within this larger radius/tolerance (soft ground truth)")
    ap.add_argument("--verify", type=int, default=0, metavar="N",
                    help="geometric verification of each query's N best candidates (ORB + pycolmap)")
    ap.add_argument("--min-inliers", type=int, default=15, help="inliers needed to accept a verified match")
    ap.add_argument("--cache", metavar="DIR", help="encoding cache folder, e.g. one filled by `vpr encode` "
                    "(default: OUT/cache)")
    ap.add_argument("--no-progress", action="store_true", help="no progress bars")


def options_from_args(args) -> RunOptions:
    """The :class:`RunOptions` of parsed ``match`` / ``compare`` / ``loops`` arguments."""
    return RunOptions(
        out=Path(args.out), encoder=args.encoder, encoder_conf=encoders.parse_conf(args.encoder_conf),
        method_conf=method_confs(args.method_conf), fps=args.fps, step=args.step, max_frames=args.max_frames,
        gt=GroundTruthSpec(tolerance=getattr(args, "tolerance", None), files=tuple(args.gt or ()),
                           radius=args.radius, soft=args.gt_soft),
        verify=getattr(args, "verify", 0), min_inliers=getattr(args, "min_inliers", 15),
        progress=not args.no_progress, cache=Path(args.cache) if args.cache else None)


def run_command(args) -> int:
    opts = options_from_args(args)
    if args.command == "loops":
        report = run_loops(args.seq, args.method, opts, exclude=args.exclude)
    else:
        names = args.methods.split(",") if args.command == "compare" else [args.method]
        report = run_compare(args.db, args.query, [m.strip() for m in names if m.strip()], opts,
                             command=args.command)
    print(metrics_table(report["methods"]))
    print(f"wrote {args.out}/metrics.json")
    return 0


# ------------------------------------------------------------------- outputs
def versions() -> dict:
    import cv2
    import scipy

    import vpr

    return {"vpr": vpr.__version__, "python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "opencv": cv2.__version__}


def write_similarity(folder: Path, S) -> str:
    """Write ``S`` as ``similarity.npy`` (dense) or ``similarity_topk.npz`` (sparse); returns the file name."""
    if sp.issparse(S):
        with io.atomic_path(folder / "similarity_topk.npz") as tmp:
            sp.save_npz(tmp, sp.csr_matrix(S, dtype=np.float32))
        return "similarity_topk.npz"
    io.save_npy(folder / "similarity.npy", np.asarray(S, dtype=np.float32))
    return "similarity.npy"


def write_matches(folder: Path, res: MatchResult, db_names, q_names, extra: dict | None = None) -> None:
    """``matches.csv``: one row per query with its best database frame, score, decision and ``extra`` columns."""
    extra = extra or {}
    with io.atomic_open(folder / "matches.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["query", "query_name", "best_db", "db_name", "score", "accepted", *extra])
        for j in range(len(q_names)):
            b = int(res.best_db[j])
            w.writerow([j, q_names[j], b, db_names[b] if b >= 0 else "", f"{res.score[j]:.6g}",
                        int(bool(res.accepted[j])), *(v[j] for v in extra.values())])


def method_metrics(res: MatchResult, gt_hard, gt_soft, mask=None):
    """(metrics dict, (precision, recall) or None without ground truth)."""
    m = {"seconds": round(res.seconds, 4)}
    if gt_hard is None:
        return m, None
    ev, (prec, rec, _) = evaluate.evaluate(res.similarity, gt_hard, gt_soft, mask=mask, return_curve=True)
    m.update({k: float(v) for k, v in ev.items()})
    if mask is None:
        m.update(evaluate.accepted_precision(res.best_db, res.accepted, gt_hard, gt_soft))
    return m, (prec, rec)


def metrics_table(table: dict) -> str:
    """The printed table: one row per method of ``{method: metrics}``."""
    keys = [("auc_pr", "AUC"), ("recall_at_100p", "R@100P"), ("recall_at_1", "R@1"),
            ("precision_accepted", "P(acc)"), ("seconds", "seconds")]
    lines = [f"{'method':<22}" + "".join(f"{h:>10}" for _, h in keys)]
    for name, m in table.items():
        cells = "".join(f"{m[k]:10.3f}" if isinstance(m.get(k), (int, float)) else f"{'-':>10}" for k, _ in keys)
        lines.append(f"{name:<22}{cells}")
    return "\n".join(lines)


def _config(opts: RunOptions, **inputs) -> dict:
    return {"argv": sys.argv[1:], **inputs, **asdict(opts)}


# ----------------------------------------------------------------- pipeline
def _extract_all(paths, runners: dict, opts: RunOptions):
    """Open the sources and encode them once with what every method needs."""
    srcs = [open_source(p, fps=opts.fps, step=opts.step, max_frames=opts.max_frames) for p in paths]
    encoder = encoders.get(opts.encoder, **opts.encoder_conf)
    needed = set().union(*(r.inputs() for r in runners.values()))
    exs = [extract(s, encoder, need_sdr="sdr" in needed, need_desc="desc" in needed,
                   need_pixels="pixels" in needed, thumbs=opts.verify > 0, cache_dir=opts.cache or Path(opts.out) / "cache",
                   progress=opts.progress) for s in srcs]
    return srcs, encoder, exs


def _runners(names: list[str], opts: RunOptions) -> dict:
    """Configured methods by name, built before any work so that a bad conf fails at once."""
    if not names:
        raise ValueError("--methods is empty")
    # a conf for a method this run does not use is still checked: a typo should not pass silently
    built = {m: methods.get(m, **c) for m, c in opts.method_conf.items()}
    return {m: built.get(m) or methods.get(m) for m in names}


def run_compare(db, query, method_names: list[str], opts: RunOptions, command: str = "compare") -> dict:
    """Encode ``db`` and ``query`` once, run every method, write the outputs; return metrics.json's content.

    Parameters
    ----------
    db, query : str or Path
        Image folders, videos or image lists (see :func:`vpr.sources.open_source`).
    method_names : list of str
        Methods (see :func:`vpr.methods.available`); one writes its outputs in
        ``opts.out``, several one sub-folder each.
    opts : RunOptions
        Encoder, method confs, sources, ground truth, verification, output.
    command : str
        Recorded in ``metrics.json``.
    """
    if opts.verify < 0:
        raise ValueError(f"--verify must be >= 0, got {opts.verify}")
    runners = _runners(method_names, opts)
    out = Path(opts.out)
    (db_src, q_src), encoder, (db_ex, q_ex) = _extract_all([db, query], runners, opts)
    gt_hard, gt_soft = build_gt(opts.gt, db_ex.features.names, q_ex.features.names, db_ex.indices, q_ex.indices,
                                db_src.name, q_src.name)
    single = len(runners) == 1
    results, metrics, curves = {}, {}, {}
    verifier = None
    if opts.verify:
        from vpr.verify import Verifier  # pycolmap: loaded only when verifying

        # one verifier for all methods: features and pair inliers are computed once
        verifier = Verifier(db_ex.thumbs, q_ex.thumbs, min_inliers=opts.min_inliers)
    for m, runner in runners.items():
        res = runner.match(db_ex.features, q_ex.features, progress=opts.progress)
        results[m] = res
        folder = out if single else out / m
        folder.mkdir(parents=True, exist_ok=True)
        sim_file = write_similarity(folder, res.similarity)
        metrics[m], curve = method_metrics(res, gt_hard, gt_soft)
        if curve is not None:
            curves[m] = curve
        metrics[m]["similarity_file"] = str(Path(folder.name if not single else ".") / sim_file)
        extra = {}
        if opts.verify:
            t0 = time.perf_counter()
            vr = verifier.verify(res.similarity, opts.verify, progress=opts.progress)
            # seconds: the method's plus verification (pairs shared with earlier methods are cached)
            verified = MatchResult(m + "+verify", vr.similarity(), vr.best_db, vr.score, vr.accepted,
                                   res.seconds + time.perf_counter() - t0, res.conf)
            extra = {"verified_db": vr.best_db.tolist(), "inliers": vr.score.astype(int).tolist(),
                     "verified": vr.accepted.astype(int).tolist()}
            metrics[m + "+verify"], curve = method_metrics(verified, gt_hard, gt_soft)
            if curve is not None:
                curves[m + "+verify"] = curve
        write_matches(folder, res, db_ex.features.names, q_ex.features.names, extra)
        plots.plot_similarity(res.similarity, folder / "similarity.png", best_db=res.best_db,
                              accepted=res.accepted, gt_hard=gt_hard, title=f"{m}: database x query")
    if curves:
        plots.plot_pr(curves, out / "pr.png", title=f"{db_src.name} vs {q_src.name} ({encoder.name})")
    report = {
        "methods": metrics,
        "params": {"command": command, "db": str(db), "query": str(query),
                   "encoder": encoder.name, "encoder_conf": encoder.conf,
                   "method_conf": {m: r.conf for m, r in results.items()},
                   "n_db": len(db_ex.features), "n_query": len(q_ex.features),
                   "encode_seconds": {"db": db_ex.seconds, "query": q_ex.seconds},
                   "cached": {"db": db_ex.cached, "query": q_ex.cached},
                   "skipped": {"db": db_ex.skipped, "query": q_ex.skipped},
                   "ignored_files": {"db": db_ex.ignored, "query": q_ex.ignored},
                   "ground_truth": opts.gt.describe()},
        "versions": versions(),
    }
    io.save_json(out / "metrics.json", report)
    io.save_json(out / "config.json", _config(opts, command=command, db=str(db), query=str(query),
                                              methods=list(runners)))
    return report


def exclude_frames(exclude, source) -> int:
    """``--exclude`` in frames: an int, a string of digits, or ``"Ns"`` (seconds; videos only).

    Seconds are converted with the frame rate of the frames kept from the video
    (``--fps`` if it lowers the rate, else the video's rate divided by ``--step``).
    Image folders and lists have no time base, so seconds are refused there.
    """
    text = str(exclude).strip().lower()
    try:
        if not text.endswith("s"):
            n = int(text)
        else:
            seconds = float(text[:-1])
            rate = getattr(source, "video_fps", 0.0)
            if not rate:
                raise ValueError(f"--exclude {exclude}: seconds need a frame rate, and {source.path} "
                                 f"({source.kind}) has none; give frames instead (e.g. --exclude 30)")
            if source.fps is not None and source.fps < rate:
                rate = source.fps
            else:
                rate /= source.step or 1
            n = round(seconds * rate)
    except (TypeError, ValueError) as e:
        if "--exclude" in str(e):
            raise
        raise ValueError(f"--exclude must be a number of frames or seconds like 5s, got {exclude!r}") from None
    if n < 1:
        raise ValueError(f"--exclude must be at least 1 frame, got {exclude!r} ({n} frames)")
    return n


def run_loops(seq, method: str, opts: RunOptions, exclude: int | str = 30) -> dict:
    """Loop closures within the traverse ``seq`` with ``method``; writes the same outputs as ``match``.

    ``exclude``: frames, or ``"Ns"`` seconds for a video (:func:`exclude_frames`).
    Ground truth: ``opts.gt.files`` holds one positions file (``frame,x,y`` or
    ``traverse,frame,x,y``) used with ``opts.gt.radius``.
    """
    runner = _runners([method], opts)[method]
    if opts.gt.files and opts.gt.radius is None:
        raise ValueError("loops: --gt needs --radius")
    if len(opts.gt.files) > 1:
        raise ValueError("loops: --gt takes one positions file")
    out = Path(opts.out)
    # before encoding, so that a bad --exclude fails at once
    exclude = exclude_frames(exclude, open_source(seq, fps=opts.fps, step=opts.step, max_frames=opts.max_frames))
    (src,), encoder, (ex,) = _extract_all([seq], {method: runner}, opts)
    res = runner.loops(ex.features, exclude=exclude, progress=opts.progress)
    out.mkdir(parents=True, exist_ok=True)
    sim_file = write_similarity(out, res.similarity)
    gt_hard = mask = None
    if opts.gt.files:
        xy = positions_of_frames(opts.gt.files[0], src.name, ex.indices)
        gt_hard = evaluate.gt_from_positions(xy, xy, opts.gt.radius)
        mask = evaluate.loop_closure_mask(len(ex.features), exclude=exclude)
    metrics = {}
    metrics[method], curve = method_metrics(res, gt_hard, None, mask=mask)
    metrics[method]["similarity_file"] = sim_file
    write_matches(out, res, ex.features.names, ex.features.names)
    plots.plot_similarity(res.similarity, out / "similarity.png", best_db=res.best_db, accepted=res.accepted,
                          gt_hard=gt_hard, title=f"{method}: loop closures")
    if gt_hard is not None:
        plots.plot_pr({method: curve}, out / "pr.png", title=f"loop closures in {src.name}")
    report = {"methods": metrics,
              "params": {"command": "loops", "seq": str(seq), "exclude": exclude,
                         "encoder": encoder.name, "encoder_conf": encoder.conf, "method_conf": res.conf,
                         "n_frames": len(ex.features), "encode_seconds": ex.seconds, "skipped": ex.skipped,
                         "ground_truth": opts.gt.describe()},
              "versions": versions()}
    io.save_json(out / "metrics.json", report)
    io.save_json(out / "config.json", _config(opts, command="loops", seq=str(seq), method=method, exclude=exclude))
    return report
