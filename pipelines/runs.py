"""The runs behind ``vpr match``, ``compare`` and ``loops``: checks before work, encoding, the methods, outputs.

:func:`run_compare` and :func:`run_loops` do the work from explicit parameters
(:class:`RunOptions`); :func:`run_methods` is the one evaluation harness (every
method on the same encoded traverses, evaluated against the same ground truth,
one result alive at a time), which the Nordland benchmark uses too.

Faults: every option, source and ground-truth file is checked before the first
frame is encoded, and a refused run writes nothing; every file is written
atomically, so an interrupted run leaves only complete files and a rerun gives
the uninterrupted result.
"""
from __future__ import annotations

import os
import resource
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp

import encoders
from pipelines.cluster import check_workers, dask_client
from pipelines.features import extract
from pipelines.interrupts import deferred
from pipelines.outputs import claim_methods, merge_metrics, method_metrics, versions, warn, write_method
from pipelines.positions import prepare_positions
from pipelines.split import split_match
from vpr import evaluate, groundtruth, io, methods
from vpr.groundtruth import GroundTruthSpec, build_gt, build_loop_gt
from vpr.groundtruth.files import is_loop_pairs_file
from vpr.shosm import LOOP_EXCLUDE
from vpr.sources import FrameSkippedWarning, open_source
from vpr.types import EncodedTraverse, MatchResult

__all__ = ["RunOptions", "run_compare", "run_loops", "run_methods", "exclude_frames", "peak_rss_mb", "check_fit_frames",
           "prepare_run", "extract_all", "check_match", "compare_query", "MatchMap"]


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
    #: ROS bags: the camera topic (:func:`vpr.sources.open_source`)
    topic: str | None = None
    #: keep one frame per this many metres of travel (:mod:`pipelines.positions`)
    every: float | None = None
    #: one query traverse split in blocks across Dask workers (:mod:`pipelines.split`): a local cluster of this
    #: many workers (0: serial), or the cluster at ``scheduler``; None and None: serial
    workers: int | None = None
    scheduler: str | None = None
    #: loops: a geometric second opinion on rshosm-seq's closures (:class:`vpr.verify.GeometricOpinion`); off by
    #: default: it accepts closures onto the same road ahead on rendered forward drives (docs/loops.md)
    geometry: bool = False
    #: methods whose candidates are verified (None: all); verification is the expensive part of a run
    verify_methods: tuple | None = None
    #: further :class:`vpr.verify.Verifier` conf (e.g. ``{"n_features": 500}``)
    verify_conf: dict = field(default_factory=dict)
    progress: bool = True
    cache: Path | None = None


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far, MB (Linux reports kB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


# ------------------------------------------------------------------ the harness
def run_methods(runners: dict, call: Callable, gt_hard=None, gt_soft=None, mask=None,
                on_result: Callable | None = None, resources: bool = False, loops: bool = False) -> dict:
    """Run and evaluate every method, one at a time (one similarity matrix alive at once).

    Parameters
    ----------
    runners : dict
        Label -> configured :class:`vpr.methods.Method`.
    call : callable
        ``call(runner) -> MatchResult``: the run (``runner.match(db, q)`` or ``runner.loops(seq, exclude)``).
    gt_hard, gt_soft, mask
        Ground truth and evaluated pairs (None: no metrics but the seconds).
    on_result : callable, optional
        ``on_result(label, result, (metrics, curve))``, e.g. writing the
        method's files; may return further entries ``{label: (metrics, curve)}``
        (a verified twin).
    resources : bool
        Also record ``cpu_seconds`` and the process's ``peak_rss_mb`` after each method.
    loops : bool
        Loop closures within one stream (per-frame decision metrics, :func:`pipelines.outputs.method_metrics`).

    Returns
    -------
    dict: label -> (metrics, curve or None), in the order run. Each metrics
    dict holds the method's ``seconds`` (matching alone).
    """
    out = {}
    for label, runner in runners.items():
        c0 = time.process_time()
        res = call(runner)
        cpu = time.process_time() - c0
        metrics, curve = method_metrics(res, gt_hard, gt_soft, mask=mask, loops=loops)
        if resources:
            metrics.update(cpu_seconds=round(cpu, 4), peak_rss_mb=round(peak_rss_mb(), 1))
        out[label] = (metrics, curve)
        if on_result is not None:
            out.update(on_result(label, res, (metrics, curve)) or {})
        del res
    return out


# ------------------------------------------------------- checks before work
def _any_true(G) -> bool:
    """Whether a dense or sparse bool ground truth holds any true pair (sparse has no ``any``)."""
    return bool(G.count_nonzero()) if sp.issparse(G) else bool(np.any(G))


def _config(opts: RunOptions, argv=None, **inputs) -> dict:
    return {"argv": list(sys.argv[1:] if argv is None else argv), **inputs, **asdict(opts)}


def _check_run_options(opts: RunOptions) -> None:
    """Options that are wrong whatever the inputs (``--verify``, ``--min-inliers``)."""
    if isinstance(opts.verify, bool) or not isinstance(opts.verify, (int, np.integer)) or opts.verify < 0:
        raise ValueError(f"--verify must be an integer >= 0, got {opts.verify!r}")
    if opts.min_inliers < 0:
        raise ValueError(f"--min-inliers must be >= 0, got {opts.min_inliers}")
    if not opts.verify and opts.min_inliers != RunOptions.min_inliers:
        warn(f"--min-inliers {opts.min_inliers} has no effect without --verify N; ignored")


def _runners(names: list[str], opts: RunOptions) -> dict:
    """Configured methods by name, built before any work: each method checks its conf where it is built."""
    if not names:
        raise ValueError("--methods is empty")
    unique = list(dict.fromkeys(names))
    if len(unique) < len(names):
        twice = sorted({m for m in names if names.count(m) > 1})
        warn(f"--methods names {', '.join(twice)} more than once; each method runs once")
    for m in unique:
        methods.get_class(m)  # unknown names fail here, with the list of methods
    # a conf for a method this run does not use is still checked (a typo should not pass silently), then ignored
    built = {}
    for m, c in opts.method_conf.items():
        try:
            built[m] = methods.get(m, **c)
        except ValueError as exc:
            raise ValueError(f"--method-conf {m}: {exc}") from None
    unused = [m for m in built if m not in unique]
    if unused:
        warn(f"--method-conf for {', '.join(unused)}, which this run does not use ({', '.join(unique)}); ignored")
    return {m: built.get(m) or methods.get(m) for m in unique}


def _check_out(out: Path, srcs, folders) -> None:
    """Refuse an output folder whose writes would land in a source folder (they would be read back as frames)."""
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder")
    # a read-only or forbidden --out would otherwise fail only when the first encoding is cached
    io.check_writable(out / "metrics.json", "--out")
    written = {(out / f).resolve(): f for f in folders}
    for src in srcs:
        if src.kind == "folder" and src.path.resolve() in written:
            where = "--out" if written[src.path.resolve()] == "." else f"--out's {written[src.path.resolve()]}/"
            raise ValueError(f"--out {out}: {where} folder is the source folder {src.path}; the run would write its "
                             "outputs among the frames it reads. Choose another --out")


def _gt_rows(attempted, read) -> list[int]:
    """Rows of the frames read (source numbers ``read``) in a ground truth built for ``attempted``."""
    row = {k: r for r, k in enumerate(attempted)}
    return [row[k] for k in read]


def check_fit_frames(src, encoder, role: str, step=None, max_frames=None) -> None:
    """Refuse, before reading a frame, a source too short for an encoder fitted on it (``standardise=fit``)."""
    how = encoder.conf.get("standardise")
    if how not in ("fit", "per_batch"):
        return
    n = len(src.indices())
    if n < 2:
        by = [f"{f} {v}" for f, v in (("--step", step), ("--max-frames", max_frames)) if v is not None]
        why = f" with {' and '.join(by)}" if by else ""
        raise ValueError(f"{role} {src.path}: {n} frame(s) to read{why}; encoder {encoder.name} with "
                         f"standardise={how} is fitted on the traverse and needs at least 2 (more frames, or "
                         "--encoder-conf standardise=none)")


def prepare_run(out: Path, paths, roles, method_names, opts: RunOptions):
    """The checks of the options, methods, encoder, sources and output before reading a frame.

    Returns (runners, encoder, sources, positions): ``positions`` the frames'
    positions of each source for position ground truth (None without;
    :func:`pipelines.positions.prepare_positions`, which also leaves out frames
    without one and applies ``--every``); the ground truth is checked where it
    is built (:func:`check_match`, :func:`vpr.groundtruth.build_loop_gt`), also before any work.
    """
    _check_run_options(opts)
    runners = _runners(method_names, opts)
    encoder = encoders.get(opts.encoder, **opts.encoder_conf)
    srcs = [open_source(p, fps=opts.fps, step=opts.step, max_frames=opts.max_frames, topic=opts.topic)
            for p in paths]
    positions = prepare_positions(srcs, roles, opts.gt, opts.every)
    for src, role in zip(srcs, roles, strict=True):
        check_fit_frames(src, encoder, role, opts.step, opts.max_frames)
    encoder.check_memory(max(len(s.indices()) for s in srcs))
    _check_out(out, srcs, [".", "cache", *runners])
    if opts.cache is not None:
        cache = Path(opts.cache)
        if cache.exists() and not cache.is_dir():
            raise ValueError(f"--cache {cache}: is a file, expected a folder (of encodings, e.g. from `vpr encode`)")
        if cache.is_dir() and not os.access(cache, os.W_OK | os.X_OK):
            warn(f"--cache {cache}: not writable; encodings found there are read, new ones are not cached")
    with deferred():  # numba loads or compiles the kernels here: a Ctrl-C inside its callbacks prints tracebacks
        for r in runners.values():
            r.warm_up()
    return runners, encoder, srcs, positions


# ----------------------------------------------------------------- encoding
def extract_all(srcs, roles, encoder, runners: dict, opts: RunOptions):
    """Encode the sources once with what every method needs; one warning per source with skipped frames."""
    needed = set().union(*(r.required_inputs for r in runners.values()))
    exs = []
    for src, role in zip(srcs, roles, strict=True):
        attempted = len(src.indices())
        with warnings.catch_warnings():
            # one summary line per source below, not one line per bad frame
            warnings.simplefilter("ignore", FrameSkippedWarning)
            ex = extract(src, encoder, needed, thumbs=opts.verify > 0,
                         cache_dir=opts.cache or Path(opts.out) / "cache", progress=opts.progress)
        lost = attempted - len(ex.features)
        if lost > 0 or ex.skipped:
            first = f" (first: {ex.skipped[0][0]}: {ex.skipped[0][1]})" if ex.skipped else ""
            warn(f"{role} {src.path}: {lost} of {attempted} frames could not be read and were skipped{first}")
        degenerate = degenerate_sdrs(ex.features.sdr) if ex.features.sdr is not None else None
        if degenerate:
            warn(f"{role} {src.path}: {degenerate}; matching those frames is guesswork (encoder {encoder.name})")
        exs.append(ex)
    return exs


def degenerate_sdrs(x, duplicate_share: float = 0.1) -> str | None:
    """What is wrong with an SDR batch whose frames cannot be told apart: empty rows, or many identical rows.

    None when nothing is: no empty row, and fewer than ``duplicate_share`` of
    the frames repeat an earlier frame's SDR exactly (a stop repeats a few).
    """
    x = sp.csr_matrix(x)
    n = x.shape[0]
    if n == 0:
        return None
    empty = int((np.diff(x.indptr) == 0).sum())
    rows = {x.indices[x.indptr[i]:x.indptr[i + 1]].tobytes() for i in range(n)}
    dup = n - len(rows)
    parts = []
    if empty:
        parts.append(f"{empty} of {n} frames have an empty SDR")
    if dup >= max(1, duplicate_share * n):
        parts.append(f"{dup} of {n} frames repeat another frame's SDR exactly")
    return "; ".join(parts) or None


# ----------------------------------------------------------------- the runs
def run_compare(db, query, method_names: list[str], opts: RunOptions, command: str = "compare") -> dict:
    """Encode ``db`` and ``query`` once, run every method, write the outputs; return metrics.json's content.

    Every option, file and the ground truth is checked before any frame is
    encoded; a refused run writes nothing. Each method writes its files in
    ``opts.out/METHOD``; ``opts.out/metrics.json`` and ``pr.png`` hold every
    method run into ``opts.out`` on the same inputs (see
    :func:`pipelines.outputs.merge_metrics`).

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
    runners, encoder, (db_src, q_src), positions = prepare_run(out, [db, query], ["database", "query"], method_names,
                                                               opts)
    gt = check_match(runners, opts, db_src, q_src, positions)
    split = opts.workers is not None or opts.scheduler is not None
    n_workers = check_workers(opts.workers, opts.scheduler) if split else None
    # ---- the work starts here: nothing above wrote a file
    with claim_methods(out, runners):  # a second run of these methods into out meanwhile is refused
        db_ex, q_ex = extract_all([db_src, q_src], ["database", "query"], encoder, runners, opts)
        the_map = MatchMap(str(db), db_src, db_ex, encoder.name, dict(encoder.conf),
                           {m: r.fit(db_ex.features, progress=opts.progress) for m, r in runners.items()})
        if not split or n_workers == 0:
            return compare_query(the_map, query, q_src, opts, command, q_ex=q_ex, argv=sys.argv[1:], gt=gt,
                                 encoder=encoder)
        shipped: dict = {}
        scratch = out / f".dask-scratch-{os.getpid()}" if opts.scheduler is None else None
        with dask_client(n_workers, opts.scheduler, scratch) as client:
            workers = n_workers or len(client.scheduler_info().get("workers", {})) or 1

            def matcher(f):
                if f.method.block_margin is None:
                    return f.match(q_ex.features, progress=opts.progress)
                return split_match(f, q_ex.features, client, workers, shipped.setdefault(f.name, {}))

            report = compare_query(the_map, query, q_src, opts, command, q_ex=q_ex, argv=sys.argv[1:], gt=gt,
                                   encoder=encoder, matcher=matcher, extra={"split": shipped})
        return report


def check_match(runners: dict, opts: RunOptions, db_src, q_src, positions=None):
    """The checks of a database x query run that need both sources (before any work); returns the ground truth.

    ``positions``: the two sources' frame positions (:func:`prepare_run`), for position ground truth.
    """
    unknown = set(opts.verify_methods or ()) - set(runners)
    if unknown:
        raise ValueError(f"verify_methods: {', '.join(sorted(unknown))} not among the methods run")
    db_att, q_att = db_src.indices(), q_src.indices()
    for runner in runners.values():
        runner.check_size(len(db_att), len(q_att))  # too large for a method: refused now, not after encoding
    gt_hard, gt_soft = build_gt(opts.gt, db_src.names(), q_src.names(), db_att, q_att, db_src.name, q_src.name,
                                totals=(db_src.exact_total(), q_src.exact_total()), positions=positions)
    if gt_hard is not None and not _any_true(gt_hard):
        raise opts.gt.no_match_error(db_att, q_att)
    return gt_hard, gt_soft


@dataclass
class MatchMap:
    """The database side of a run, built once: its source, its encoding and every method fitted on it.

    A fleet of query traverses (:mod:`pipelines.fleet`) ships it to each
    worker once; :func:`compare_query` matches one query traverse with it.
    """

    db: str
    src: object
    ex: object
    encoder: str
    encoder_conf: dict
    fitted: dict


def compare_query(the_map: MatchMap, query, q_src, opts: RunOptions, command: str = "compare", q_ex=None,
                  argv=None, gt=None, encoder=None, matcher=None, extra: dict | None = None) -> dict:
    """One query traverse against a built map: encode it (unless ``q_ex``), run, evaluate, write ``opts.out``.

    What :func:`run_compare` does after the database is encoded and learned;
    the same files and ``metrics.json``, wherever it runs. ``gt`` (the
    ground truth of :func:`check_match`) and ``encoder`` (the map's) are
    built here when not given (a fleet's worker gets the map alone).
    ``matcher(fitted)``: how each method matches the query (default: in this
    process; :func:`pipelines.split.split_match` on a cluster); ``extra``: more
    ``params`` for ``metrics.json``.
    """
    out = Path(opts.out)
    db_src, db_ex = the_map.src, the_map.ex
    runners = {m: f.method for m, f in the_map.fitted.items()}
    gt_hard, gt_soft = gt if gt is not None else check_match(runners, opts, db_src, q_src)
    db_att, q_att = db_src.indices(), q_src.indices()
    if encoder is None:
        encoder = encoders.get(the_map.encoder, **the_map.encoder_conf)
    if q_ex is None:
        (q_ex,) = extract_all([q_src], ["query"], encoder, runners, opts)
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
    confs = {}
    db_names, q_names = db_ex.features.names, q_ex.features.names
    db, argv = the_map.db, list(sys.argv[1:] if argv is None else argv)

    def write(m: str, res: MatchResult, evaluated) -> dict:
        confs[m] = res.conf
        folder = out / m
        v = verifier if opts.verify_methods is None or m in opts.verify_methods else None
        entries = write_method(folder, m, res, evaluated, db_names, q_names, gt_hard, gt_soft, v, opts.verify,
                               opts.progress)
        io.save_json(folder / "config.json", _config(opts, argv, command=command, db=str(db), query=str(query),
                                                     methods=list(runners)))
        return {k: (e, None) for k, e in entries.items() if k != m}

    done = run_methods(the_map.fitted, matcher or (lambda f: f.match(q_ex.features, progress=opts.progress)),
                       gt_hard, gt_soft, on_result=write)
    metrics = {k: e for k, (e, _) in done.items()}
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
                   "ground_truth": opts.gt.describe(), "inputs": inputs, **(extra or {})},
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


def run_loops(seq, method: str, opts: RunOptions, exclude: int | str = LOOP_EXCLUDE) -> dict:
    """Loop closures within the traverse ``seq`` with ``method``; writes the same outputs as ``match``.

    ``seq``: one source, or a list of sources that are the sessions of one
    stream (a robot's runs, in order): learned one after the other, closures
    onto every earlier session count, and nothing of a session's last moment
    carries into the next (:meth:`vpr.shosm.LoopStream.new_session`);
    ``metrics.json`` then reports each session pair (``sessions``).
    ``exclude``: frames, or ``"Ns"`` seconds for a video (:func:`exclude_frames`).
    Ground truth (:func:`vpr.groundtruth.build_loop_gt`): a positions file
    (``frame,x,y`` or ``traverse,frame,x,y``; with sessions one each, or one
    with ``traverse`` rows) with ``opts.gt.radius`` (pairs within ``opts.gt.soft``
    but not ``radius`` are ignored), positions from a bag's topic, a
    ``frame,earlier`` pairs CSV, or loop matrices (``.npy``, ``.png``,
    ``.bmp``, ``.mat``) over the sessions' frames in order. Checks as in
    :func:`run_compare`.
    """
    out = Path(opts.out)
    seqs = [seq] if isinstance(seq, (str, Path)) else list(seq)
    roles = ["sequence"] if len(seqs) == 1 else [f"session {k + 1}" for k in range(len(seqs))]
    runners, encoder, srcs, positions = prepare_run(out, seqs, roles, [method], opts)
    exclude = exclude_frames(exclude, srcs[0])  # frames, or seconds with the (first) video's rate
    runner = runners[method]
    if not runner.supports_loops:
        raise ValueError(runner.no_loops_reason or f"{method} does not support loop closure within one traverse")
    attempted = [s.indices() for s in srcs]
    T = sum(len(a) for a in attempted)
    runner.check_size(T, T)
    if exclude >= max(len(a) for a in attempted):
        raise ValueError(f"--exclude {exclude} leaves no pair to compare within a session: {srcs[0].path} has "
                         f"{len(attempted[0])} frames to read, and a loop closure needs frames at least --exclude "
                         "apart")
    sessions = [0, *np.cumsum([len(a) for a in attempted])[:-1].tolist()]
    gt_hard, gt_soft = _stream_gt(opts.gt, srcs, attempted, sessions, positions)
    mask = None
    if gt_hard is not None:
        mask = groundtruth.loop_closure_mask(T, exclude=exclude, starts=sessions)
        if not _any_true(gt_hard & mask):
            raise opts.gt.no_match_error(exclude=exclude)
    # ---- the work starts here: nothing above wrote a file
    with claim_methods(out, runners):  # a second run of this method into out meanwhile is refused
        exs = extract_all(srcs, roles, encoder, runners, opts)
        read = [ex.indices for ex in exs]
        starts = [0, *np.cumsum([len(ex.features) for ex in exs])[:-1].tolist()]
        features = _joined(exs, srcs) if len(exs) > 1 else exs[0].features
        if gt_hard is not None:
            rows = np.concatenate([np.asarray(_gt_rows(a, r), np.int64) + o
                                   for a, r, o in zip(attempted, read, sessions, strict=True)])
            gt_hard = gt_hard[np.ix_(rows, rows)]
            gt_soft = gt_soft[np.ix_(rows, rows)] if gt_soft is not None else None
            mask = groundtruth.loop_closure_mask(len(features), exclude=exclude, starts=starts)
            if not _any_true(gt_hard & mask):  # skipped frames took the last true pairs
                raise opts.gt.no_match_error(exclude=exclude)
        names = features.names
        confs = {}

        def write(m: str, res: MatchResult, evaluated) -> dict:
            confs[m] = res.conf
            if gt_hard is not None and len(srcs) > 1:
                evaluated[0]["sessions"] = evaluate.session_pairs(res.best_db, res.accepted, gt_hard, starts,
                                                                  gt_soft, mask, [s.name for s in srcs])
            write_method(out / m, m, res, evaluated, names, names, gt_hard, gt_soft, title=f"{m}: loop closures",
                         loops=True, mask=mask)
            io.save_json(out / m / "config.json", _config(opts, command="loops", seq=[str(q) for q in seqs],
                                                          method=m, exclude=exclude))

        opinions = {}

        def loops_of(r):
            opinion = None
            if opts.geometry:
                from vpr.verify import GeometricOpinion  # pycolmap: loaded only when verifying

                loop, image = r.seq.loop(), _frame_images(srcs, exs)

                def opinion(decider):
                    opinions[r.name] = GeometricOpinion(decider, image, loop.back, loop.ahead, loop.stop_ratio)
                    return opinions[r.name]
            return r.loops(features, exclude=exclude, progress=opts.progress, sessions=starts, opinion=opinion)

        done = run_methods(runners, loops_of, gt_hard, gt_soft, mask, on_result=write, loops=True)
        for m, o in opinions.items():
            done[m][0]["geometry"] = o.report()
        inputs = {"kind": "loops", "seq": [s.key() for s in srcs] if len(srcs) > 1 else srcs[0].key(),
                  "exclude": exclude, "encoder": encoder.name, "encoder_conf": encoder.conf,
                  "ground_truth": opts.gt.describe()}
        report = {"methods": {k: e for k, (e, _) in done.items()},
                  "params": {"command": "loops", "seq": str(seq) if len(seqs) == 1 else [str(q) for q in seqs],
                             "exclude": exclude, "encoder": encoder.name, "encoder_conf": encoder.conf,
                             "method_conf": confs, "n_frames": len(features),
                             "sessions": [{"source": str(q), "first_frame": a, "frames": len(ex.features)}
                                          for q, a, ex in zip(seqs, starts, exs, strict=True)],
                             "encode_seconds": sum(ex.seconds for ex in exs),
                             "skipped": [sk for ex in exs for sk in ex.skipped],
                             "ground_truth": opts.gt.describe(), "inputs": inputs},
                  "versions": versions()}
        return merge_metrics(out, report, f"loop closures in {', '.join(s.name for s in srcs)}")


def _frame_images(srcs, exs):
    """``image(j)``: frame ``j`` of the (joined) stream of frames read, decoded again at the source's resolution."""
    where = [(src, i) for src, ex in zip(srcs, exs, strict=True) for i in ex.indices]
    pos_of = {id(src): {k: p for p, k in enumerate(src.indices())} for src in srcs}

    def image(j: int):
        src, index = where[j]
        pos = pos_of[id(src)][index]
        for f in src.iter_range(pos, pos + 1):
            return f.image
        raise ValueError(f"{src.path}: frame {index} could not be read again for geometric verification")

    return image


def _joined(exs, srcs) -> EncodedTraverse:
    """The sessions' encodings as one stream, frame names prefixed with their source (``day/0001.png``)."""
    names = [f"{s.name}/{n}" for s, ex in zip(srcs, exs, strict=True) for n in ex.features.names]
    keys = set.intersection(*(set(k for k, v in ex.features.inputs.items() if v is not None) for ex in exs))
    inputs = {}
    for k in keys:
        parts = [ex.features.inputs[k] for ex in exs]
        inputs[k] = sp.vstack(parts).tocsr() if sp.issparse(parts[0]) else np.concatenate(parts)
    return EncodedTraverse(names, **inputs)


def _stream_gt(spec: GroundTruthSpec, srcs, attempted, sessions, positions):
    """The loop ground truth of one stream, or of the sessions of one, over the frames to attempt in order."""
    if len(srcs) == 1:
        src = srcs[0]
        return build_loop_gt(spec, src.names(), attempted[0], src.name, total=src.exact_total(),
                             positions=None if positions is None else positions[0])
    if positions is not None:
        return build_loop_gt(spec, [], [], positions=np.concatenate(positions))
    if spec.files and is_loop_pairs_file(spec.files[0]):
        raise ValueError(f"--gt {spec.files[0]}: vpr render's loop_pairs.csv pairs frames of one traverse; for "
                         "sessions give positions (its ground_truth.csv with --radius)")
    totals = [s.exact_total() for s in srcs]
    offsets = np.cumsum([0, *[t if t is not None else len(a) for t, a in zip(totals, attempted, strict=True)]])
    names = [f"{s.name}/{n}" for s in srcs for n in s.names()]
    indices = [int(i) + int(o) for a, o in zip(attempted, offsets, strict=False) for i in a]
    total = int(offsets[-1]) if all(t is not None for t in totals) else None
    return build_loop_gt(spec, names, indices, None, total=total)

