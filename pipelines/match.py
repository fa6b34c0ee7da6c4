"""``vpr match``, ``vpr compare`` and ``vpr loops``: image folders, videos or lists in,
similarity matrices, matches, metrics and plots out.

Outputs: each method writes ``out/METHOD``: ``similarity.npy`` (float32 db x query;
a top-K sparse ``similarity_topk.npz`` for large inputs), ``matches.csv`` (query,
best_db, score, accepted, ...), ``similarity.png``, ``pr_curve.npz`` and
``config.json`` (everything needed to repeat the run); ``out/metrics.json`` and
``out/pr.png`` hold every method run into ``out`` on the same inputs, merged
under a lock (:func:`merge_metrics`). Encodings are cached in ``out/cache``.

Faults: every option, source and ground-truth file is checked before the first
frame is encoded, and a refused run writes nothing; every file is written
atomically, so an interrupted run leaves only complete files and a rerun gives
the uninterrupted result.

:func:`run_compare` and :func:`run_loops` do the work from explicit parameters
(:class:`RunOptions`); :func:`run_command` only adapts the parsed command line.
"""
from __future__ import annotations

import argparse
import csv
import errno
import json
import os
import platform
import sys
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp

import encoders
from pipelines.extract import extract
from vpr import evaluate, io, methods, plots, presets
from vpr.config import parse_key_values
from vpr.groundtruth import GroundTruthSpec, build_gt, positions_of_frames
from vpr.methods import MatchResult
from vpr.sources import FrameSkippedWarning, open_source

__all__ = ["COMMANDS", "add_arguments", "add_preset_argument", "settings_from_args", "run_command", "RunOptions",
           "run_compare", "run_loops", "method_confs", "metrics_table", "method_metrics",
           "write_similarity", "write_matches", "versions"]

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
    #: the preset the settings came from (recorded in config.json), None when given explicitly
    preset: str | None = None
    encoder_conf: dict = field(default_factory=dict)
    method_conf: dict = field(default_factory=dict)
    fps: float | None = None
    step: int | None = None
    max_frames: int | None = None
    gt: GroundTruthSpec = field(default_factory=GroundTruthSpec)
    verify: int = 0
    min_inliers: int = 15
    #: methods whose candidates are verified (None: all); verification costs ~5-15 ms per candidate pair
    verify_methods: tuple | None = None
    #: further :class:`vpr.verify.Verifier` conf (e.g. ``{"n_features": 500}``)
    verify_conf: dict = field(default_factory=dict)
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
    # defaults None: a flag not given takes the preset's value (vpr.presets.resolve)
    add_preset_argument(ap)
    if command == "compare":
        ap.add_argument("--methods", help="comma-separated methods (default: the preset's)")
    else:
        ap.add_argument("--method", choices=methods.available(),
                        help="method (default: the preset's " + ("loop method" if command == "loops" else
                                                                 "first method") + ")")
    ap.add_argument("--method-conf", action="append", default=[], metavar="METHOD.KEY=VALUE",
                    help="method option, repeatable, e.g. seqslam.ds=20 or rshosm.p_extra=0.01")
    encoders.add_arguments(ap, default=None)
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


def add_preset_argument(ap: argparse.ArgumentParser) -> None:
    """``--preset NAME`` (default ``default``): the settings that flags not given take."""
    ap.add_argument("--preset", default=presets.DEFAULT, choices=presets.available(),
                    help=f"named settings (encoder, its conf, methods, their confs) that explicit flags override: "
                         f"{presets.describe()} (default: {presets.DEFAULT})")


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
        gt=GroundTruthSpec(tolerance=getattr(args, "tolerance", None), files=tuple(args.gt or ()),
                           radius=args.radius, soft=args.gt_soft),
        verify=getattr(args, "verify", 0), min_inliers=getattr(args, "min_inliers", 15),
        progress=not args.no_progress, cache=Path(args.cache) if args.cache else None)


def run_command(args) -> int:
    opts = options_from_args(args)
    names = settings_from_args(args)["methods"]
    if args.command == "loops":
        report = run_loops(args.seq, names[0], opts, exclude=args.exclude)
    else:
        report = run_compare(args.db, args.query, names, opts, command=args.command)
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
    m.update(evaluate.accepted_precision(res.best_db, res.accepted, gt_hard, gt_soft, mask=mask))
    return m, (prec, rec)


def metrics_table(table: dict) -> str:
    """The printed table: one row per method of ``{method: metrics}``."""
    keys = [("ap", "AP"), ("auc_pr", "AUC"), ("recall_at_100p", "R@100P"), ("recall_at_1", "R@1"),
            ("precision_accepted", "P(acc)"), ("seconds", "seconds")]
    lines = [f"{'method':<22}" + "".join(f"{h:>10}" for _, h in keys)]
    for name, m in table.items():
        cells = "".join(f"{m[k]:10.3f}" if isinstance(m.get(k), (int, float)) else f"{'-':>10}" for k, _ in keys)
        lines.append(f"{name:<22}{cells}")
    return "\n".join(lines)


def _any_true(G) -> bool:
    """Whether a dense or sparse bool ground truth holds any true pair (sparse has no ``any``)."""
    return bool(G.count_nonzero()) if sp.issparse(G) else bool(np.any(G))


def _score_at(S, rows) -> np.ndarray:
    """``S[rows[j], j]`` per column (rows >= 0), dense or sparse."""
    cols = np.arange(len(rows))
    rows = np.maximum(rows, 0)
    return np.asarray(S[rows, cols], dtype=np.float64).ravel()


def _config(opts: RunOptions, **inputs) -> dict:
    return {"argv": sys.argv[1:], **inputs, **asdict(opts)}


# ------------------------------------------------------- checks before work
def _warn(msg: str) -> None:
    warnings.warn(msg, UserWarning, stacklevel=3)


def _check_run_options(opts: RunOptions) -> None:
    """Options that are wrong whatever the inputs (``--verify``, ``--min-inliers``)."""
    if isinstance(opts.verify, bool) or not isinstance(opts.verify, (int, np.integer)) or opts.verify < 0:
        raise ValueError(f"--verify must be an integer >= 0, got {opts.verify!r}")
    if opts.min_inliers < 0:
        raise ValueError(f"--min-inliers must be >= 0, got {opts.min_inliers}")
    if not opts.verify and opts.min_inliers != RunOptions.min_inliers:
        _warn(f"--min-inliers {opts.min_inliers} has no effect without --verify N; ignored")


def _probe(name: str, runner) -> None:
    """Run a configured method once on a tiny synthetic traverse, so that a bad conf value fails now.

    Some values are only checked where they are used (SeqSLAM's ``ds``, the
    memory's ``p_extra``, the loop acceptance of ``rshosm-seq``): without this
    they would fail after encoding. Methods with loop closure run it too.
    """
    rng = np.random.default_rng(0)
    n, width = 12, int(runner.conf.get("n_inputs", 2048))
    bits = rng.random((n, width)) < min(1.0, 40 / width)
    tiny = methods.EncodedTraverse(names=list(range(n)), sdr=sp.csr_matrix(bits),
                                   desc=rng.random((n, 32)).astype(np.float32),
                                   pixels=rng.random((n, 64 * 32)).astype(np.float32))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            runner.match(tiny, tiny)
            if type(runner)._loops is not methods.Method._loops:
                runner.loops(tiny, exclude=2)
    except ValueError as exc:
        raise ValueError(f"--method-conf {name}: {exc}") from None


def _runners(names: list[str], opts: RunOptions) -> dict:
    """Configured methods by name, built (and their confs tried) before any work so that a bad conf fails at once."""
    if not names:
        raise ValueError("--methods is empty")
    unique = list(dict.fromkeys(names))
    if len(unique) < len(names):
        twice = sorted({m for m in names if names.count(m) > 1})
        _warn(f"--methods names {', '.join(twice)} more than once; each method runs once")
    for m in unique:
        methods.get_class(m)  # unknown names fail here, with the list of methods
    # a conf for a method this run does not use is still checked (a typo should not pass silently), then ignored
    built = {m: methods.get(m, **c) for m, c in opts.method_conf.items()}
    unused = [m for m in built if m not in unique]
    if unused:
        _warn(f"--method-conf for {', '.join(unused)}, which this run does not use ({', '.join(unique)}); ignored")
    for m in unique:
        if m in built:
            _probe(m, built[m])
    return {m: built.get(m) or methods.get(m) for m in unique}


def _check_out(out: Path, srcs, folders) -> None:
    """Refuse an output folder whose writes would land in a source folder (they would be read back as frames)."""
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder")
    # a read-only or forbidden --out would otherwise fail only when the first encoding is cached
    anc = out.absolute()
    while not anc.exists() and anc != anc.parent:
        anc = anc.parent
    if not os.access(anc, os.W_OK | os.X_OK):
        readonly = hasattr(os, "statvfs") and os.statvfs(anc).f_flag & getattr(os, "ST_RDONLY", 1)
        code = errno.EROFS if readonly else errno.EACCES
        raise OSError(code, f"cannot write ({os.strerror(code)})", str(out))
    written = {(out / f).resolve(): f for f in folders}
    for src in srcs:
        if src.kind == "folder" and src.path.resolve() in written:
            where = "--out" if written[src.path.resolve()] == "." else f"--out's {written[src.path.resolve()]}/"
            raise ValueError(f"--out {out}: {where} folder is the source folder {src.path}; the run would write its "
                             "outputs among the frames it reads. Choose another --out")


def _open_sources(paths, opts: RunOptions):
    return [open_source(p, fps=opts.fps, step=opts.step, max_frames=opts.max_frames) for p in paths]


def _gt_rows(attempted, read) -> list[int]:
    """Rows of the frames read (source numbers ``read``) in a ground truth built for ``attempted``."""
    row = {k: r for r, k in enumerate(attempted)}
    return [row[k] for k in read]


# ----------------------------------------------------------------- pipeline
def _extract_all(srcs, roles, encoder, runners: dict, opts: RunOptions):
    """Encode the sources once with what every method needs; one warning per source with skipped frames."""
    needed = set().union(*(r.inputs() for r in runners.values()))
    exs = []
    for src, role in zip(srcs, roles, strict=True):
        attempted = len(src.indices())
        with warnings.catch_warnings():
            # one summary line per source below, not one line per bad frame
            warnings.simplefilter("ignore", FrameSkippedWarning)
            ex = extract(src, encoder, need_sdr="sdr" in needed, need_desc="desc" in needed,
                         need_pixels="pixels" in needed, thumbs=opts.verify > 0,
                         cache_dir=opts.cache or Path(opts.out) / "cache", progress=opts.progress)
        lost = attempted - len(ex.features)
        if lost > 0 or ex.skipped:
            first = f" (first: {ex.skipped[0][0]}: {ex.skipped[0][1]})" if ex.skipped else ""
            _warn(f"{role} {src.path}: {lost} of {attempted} frames could not be read and were skipped{first}")
        exs.append(ex)
    return exs


def _write_method(folder: Path, m: str, res, db_names, q_names, gt_hard, gt_soft, verifier, opts, mask=None,
                  title="") -> dict:
    """Write one method's files in its folder; return its metrics entries (``m`` and ``m+verify``)."""
    sim_file = write_similarity(folder, res.similarity)
    entries = {}
    metrics, curve = method_metrics(res, gt_hard, gt_soft, mask=mask)
    metrics["similarity_file"] = f"{folder.name}/{sim_file}"
    entries[m] = (metrics, curve)
    extra = {}
    if verifier is not None and (opts.verify_methods is None or m in opts.verify_methods):
        t0 = time.perf_counter()
        vr = verifier.verify(res.similarity, opts.verify, progress=opts.progress)
        # the method's matrix with only each query's candidates re-ordered by inliers: its AP compares
        # with the unverified one (vpr.verify.rerank); seconds: the method's plus verification
        # (pairs shared with earlier methods are cached)
        S_v = vr.reranked(res.similarity)
        score_v = np.where(vr.best_db >= 0, _score_at(S_v, vr.best_db), -np.inf)
        verified = MatchResult(m + "+verify", S_v, vr.best_db, score_v, vr.accepted,
                               res.seconds + time.perf_counter() - t0, res.conf)
        extra = {"verified_db": vr.best_db.tolist(),
                 "inliers": np.where(vr.best_db >= 0, vr.score, -1).astype(int).tolist(),
                 "verified": vr.accepted.astype(int).tolist()}
        vm, vcurve = method_metrics(verified, gt_hard, gt_soft)
        vm["similarity_file"] = metrics["similarity_file"]
        entries[m + "+verify"] = (vm, vcurve)
    write_matches(folder, res, db_names, q_names, extra)
    plots.plot_similarity(res.similarity, folder / "similarity.png", best_db=res.best_db, accepted=res.accepted,
                          gt_hard=gt_hard, title=title or f"{m}: database x query")
    out = {}
    for name, (mm, c) in entries.items():
        if c is not None:
            fname = "pr_curve_verify.npz" if name.endswith("+verify") else "pr_curve.npz"
            with io.atomic_path(folder / fname) as tmp:
                with open(tmp, "wb") as fh:
                    np.savez(fh, precision=np.asarray(c[0], np.float64), recall=np.asarray(c[1], np.float64))
            mm["pr_curve"] = f"{folder.name}/{fname}"
        out[name] = mm
    return out


def _jsonable(o):
    return o.item() if isinstance(o, np.generic) else o.tolist() if isinstance(o, np.ndarray) else str(o)


def merge_metrics(out: Path, report: dict, pr_title: str) -> dict:
    """Merge this run's ``report`` into ``out/metrics.json`` and redraw ``out/pr.png``; return the merged report.

    Runs on the same inputs (``params["inputs"]``) add or replace their
    methods; a metrics.json of other inputs is replaced (with a warning). The
    read-modify-write holds a lock (``out/.metrics.lock``), so that concurrent
    runs into one folder keep each other's methods.
    """
    with io.locked(out / ".metrics.lock"):
        old = None
        path = out / "metrics.json"
        if path.is_file():
            try:
                old = json.loads(path.read_text(encoding="utf-8"))
            except ValueError:
                _warn(f"{path}: unreadable, replaced")
        merged = report
        if isinstance(old, dict) and isinstance(old.get("methods"), dict):
            # compared as JSON: tuples and NumPy scalars of this run read back as lists and numbers
            same = json.loads(json.dumps(report["params"]["inputs"], default=_jsonable))
            if old.get("params", {}).get("inputs") == same:
                merged = {**report, "methods": {**old["methods"], **report["methods"]}}
                merged["params"] = {**report["params"], "method_conf": {**old["params"].get("method_conf", {}),
                                                                        **report["params"]["method_conf"]}}
            else:
                _warn(f"{path} held results of other inputs or settings "
                      f"({', '.join(old['methods'])}); replaced by this run's")
        curves = {}
        for name, m in merged["methods"].items():
            f = m.get("pr_curve")
            if f and (out / f).is_file():
                try:
                    with np.load(out / f) as z:
                        curves[name] = (z["precision"], z["recall"])
                except (OSError, ValueError, KeyError):
                    pass  # a damaged curve file is not drawn; the metrics stay
        io.save_json(path, merged)
        if curves:
            plots.plot_pr(curves, out / "pr.png", title=pr_title)
    return merged


def _prepare(out: Path, paths, roles, method_names, opts: RunOptions, loops_exclude: int | None = None):
    """Every check that can be made before reading a frame; returns (runners, encoder, sources)."""
    _check_run_options(opts)
    opts.gt.check(loops=loops_exclude is not None)
    runners = _runners(method_names, opts)
    encoder = encoders.get(opts.encoder, **opts.encoder_conf)
    srcs = _open_sources(paths, opts)
    _check_out(out, srcs, [".", "cache", *runners])
    return runners, encoder, srcs


def run_compare(db, query, method_names: list[str], opts: RunOptions, command: str = "compare") -> dict:
    """Encode ``db`` and ``query`` once, run every method, write the outputs; return metrics.json's content.

    Every option, file and the ground truth is checked before any frame is
    encoded; a refused run writes nothing. Each method writes its files in
    ``opts.out/METHOD``; ``opts.out/metrics.json`` and ``pr.png`` hold every
    method run into ``opts.out`` on the same inputs (see :func:`merge_metrics`).

    Parameters
    ----------
    db, query : str or Path
        Image folders, videos or image lists (see :func:`vpr.sources.open_source`).
    method_names : list of str
        Methods (see :func:`vpr.methods.available`).
    opts : RunOptions
        Encoder, method confs, sources, ground truth, verification, output.
    command : str
        Recorded in ``metrics.json``.
    """
    out = Path(opts.out)
    runners, encoder, (db_src, q_src) = _prepare(out, [db, query], ["database", "query"], method_names, opts)
    unknown = set(opts.verify_methods or ()) - set(runners)
    if unknown:
        raise ValueError(f"verify_methods: {', '.join(sorted(unknown))} not among the methods run")
    db_att, q_att = db_src.indices(), q_src.indices()
    for runner in runners.values():
        runner.check_size(len(db_att), len(q_att))  # too large for a method: refused now, not after encoding
    gt_hard, gt_soft = build_gt(opts.gt, db_src.names(), q_src.names(), db_att, q_att, db_src.name, q_src.name)
    if gt_hard is not None and not _any_true(gt_hard):
        raise opts.gt.no_match_error(db_att, q_att)
    # ---- the work starts here: nothing above wrote a file
    db_ex, q_ex = _extract_all([db_src, q_src], ["database", "query"], encoder, runners, opts)
    if gt_hard is not None:
        rows, cols = _gt_rows(db_att, db_ex.indices), _gt_rows(q_att, q_ex.indices)
        gt_hard = gt_hard[np.ix_(rows, cols)]
        gt_soft = gt_soft[np.ix_(rows, cols)] if gt_soft is not None else None
        if not _any_true(gt_hard):
            raise opts.gt.no_match_error(db_ex.indices, q_ex.indices)
    verifier = None
    if opts.verify:
        from vpr.verify import Verifier  # pycolmap: loaded only when verifying

        # one verifier for all methods: features and pair inliers are computed once
        verifier = Verifier(db_ex.thumbs, q_ex.thumbs, **{"min_inliers": opts.min_inliers, **opts.verify_conf})
    metrics, confs = {}, {}
    for m, runner in runners.items():
        res = runner.match(db_ex.features, q_ex.features, progress=opts.progress)
        confs[m] = res.conf
        folder = out / m
        metrics.update(_write_method(folder, m, res, db_ex.features.names, q_ex.features.names, gt_hard, gt_soft,
                                     verifier, opts))
        io.save_json(folder / "config.json", _config(opts, command=command, db=str(db), query=str(query),
                                                     methods=list(runners)))
    # what makes two runs' metrics comparable: same frames (content keys), encoding and ground truth
    inputs = {"kind": "match", "db": db_src.key(), "query": q_src.key(), "encoder": encoder.name,
              "encoder_conf": encoder.conf, "ground_truth": opts.gt.describe()}
    report = {
        "methods": metrics,
        "params": {"command": command, "db": str(db), "query": str(query), "preset": opts.preset,
                   "encoder": encoder.name, "encoder_conf": encoder.conf, "method_conf": confs,
                   "n_db": len(db_ex.features), "n_query": len(q_ex.features),
                   "encode_seconds": {"db": db_ex.seconds, "query": q_ex.seconds},
                   "cached": {"db": db_ex.cached, "query": q_ex.cached},
                   "skipped": {"db": db_ex.skipped, "query": q_ex.skipped},
                   "ignored_files": {"db": db_ex.ignored, "query": q_ex.ignored},
                   "ground_truth": opts.gt.describe(), "inputs": inputs},
        "versions": versions(),
    }
    return merge_metrics(out, report, f"{db_src.name} vs {q_src.name} ({encoder.name})")


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
    ``traverse,frame,x,y``) used with ``opts.gt.radius``; pairs within ``opts.gt.soft``
    but not ``radius`` are ignored. Checks as in :func:`run_compare`.
    """
    if opts.gt.tolerance is not None:
        raise ValueError("loops: ground truth is --gt FILE --radius R [--gt-soft R2] (no --tolerance)")
    out = Path(opts.out)
    runners, encoder, (src,) = _prepare(out, [seq], ["sequence"], [method], opts, loops_exclude=exclude)
    exclude = exclude_frames(exclude, src)  # frames, or seconds with the video's rate
    runner = runners[method]
    if type(runner)._loops is methods.Method._loops:
        raise ValueError(runner.no_loops_reason or f"{method} does not support loop closure within one traverse")
    attempted = src.indices()
    runner.check_size(len(attempted), len(attempted))
    if exclude >= len(attempted):
        raise ValueError(f"--exclude {exclude} leaves no pair to compare: {src.path} has {len(attempted)} frames "
                         "to read, and a loop closure needs frames at least --exclude apart")
    gt_hard = gt_soft = mask = None
    if opts.gt.files:
        xy = positions_of_frames(opts.gt.files[0], src.name, attempted)
        gt_hard = evaluate.gt_from_positions(xy, xy, opts.gt.radius)
        if opts.gt.soft is not None:
            gt_soft = evaluate.gt_from_positions(xy, xy, opts.gt.soft)
        mask = evaluate.loop_closure_mask(len(attempted), exclude=exclude)
        if not _any_true(gt_hard & mask):
            raise opts.gt.no_match_error(exclude=exclude)
    # ---- the work starts here: nothing above wrote a file
    (ex,) = _extract_all([src], ["sequence"], encoder, runners, opts)
    if gt_hard is not None:
        rows = _gt_rows(attempted, ex.indices)
        gt_hard = gt_hard[np.ix_(rows, rows)]
        gt_soft = gt_soft[np.ix_(rows, rows)] if gt_soft is not None else None
        mask = evaluate.loop_closure_mask(len(ex.features), exclude=exclude)
        if not _any_true(gt_hard & mask):  # skipped frames took the last true pairs
            raise opts.gt.no_match_error(exclude=exclude)
    res = runner.loops(ex.features, exclude=exclude, progress=opts.progress)
    folder = out / method
    metrics = _write_method(folder, method, res, ex.features.names, ex.features.names, gt_hard, gt_soft, None, opts,
                            mask=mask, title=f"{method}: loop closures")
    io.save_json(folder / "config.json", _config(opts, command="loops", seq=str(seq), method=method, exclude=exclude))
    inputs = {"kind": "loops", "seq": src.key(), "exclude": exclude,
              "encoder": encoder.name, "encoder_conf": encoder.conf, "ground_truth": opts.gt.describe()}
    report = {"methods": metrics,
              "params": {"command": "loops", "seq": str(seq), "exclude": exclude,
                         "encoder": encoder.name, "encoder_conf": encoder.conf, "method_conf": {method: res.conf},
                         "n_frames": len(ex.features), "encode_seconds": ex.seconds, "skipped": ex.skipped,
                         "ground_truth": opts.gt.describe(), "inputs": inputs},
              "versions": versions()}
    return merge_metrics(out, report, f"loop closures in {src.name}")
