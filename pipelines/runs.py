"""The runs behind ``vpr match``, ``compare`` and ``loops``: checks before work, encoding, the methods, outputs.

Every option, source and ground-truth file is checked before the first frame
is encoded, and a refused run writes nothing; every file is written
atomically, so an interrupted run leaves only complete files.
"""
from __future__ import annotations

import os
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

import encoders
from encoders.extract import extract_all
from pipelines.cluster import check_workers, dask_client
from pipelines.interrupts import deferred
from pipelines.outputs import claim_methods, merge_metrics, versions, warn, write_method
from pipelines.split import split_match
from vpr import evaluate, groundtruth, io, methods
from vpr.groundtruth import GroundTruthSpec, any_true, build_gt, build_stream_gt, frame_rows, prepare_positions
from vpr.shosm import LOOP_EXCLUDE
from vpr.sources import frame_reader, open_source
from vpr.types import EncodedTraverse, MatchResult

__all__ = ["RunOptions", "run_compare", "run_loops", "prepare_run", "check_match", "compare_query", "MatchMap",
           "extract_run"]


@dataclass
class RunOptions:
    """Everything but the inputs and the methods of a ``match`` / ``compare`` / ``loops`` run.

    ``encoder_conf`` and ``method_conf`` (method -> conf) values may be strings
    (from the command line): they are read as the defaults' types.
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
    topic: str | None = None
    #: keep one frame per this many metres of travel
    every: float | None = None
    #: one query traverse split in blocks across Dask workers: a local cluster of this many workers (0: serial),
    #: or the cluster at ``scheduler``; None and None: serial
    workers: int | None = None
    scheduler: str | None = None
    #: loops: a geometric second opinion on rshosm-seq's closures (:class:`vpr.verify.GeometricOpinion`)
    geometry: bool = False
    #: methods whose candidates are verified (None: all)
    verify_methods: tuple | None = None
    #: further :class:`vpr.verify.Verifier` conf (e.g. ``{"n_features": 500}``)
    verify_conf: dict = field(default_factory=dict)
    progress: bool = True
    cache: Path | None = None

    def chosen(self) -> str:
        """The options that chose the frames read (named when a source is too short)."""
        return " and ".join(f"{f} {v}" for f, v in (("--step", self.step), ("--max-frames", self.max_frames))
                            if v is not None)


def _config(opts: RunOptions, argv=None, **inputs) -> dict:
    return {"argv": list(sys.argv[1:] if argv is None else argv), **inputs, **asdict(opts)}


def _check_out(out: Path, srcs, folders) -> None:
    """Refuse an output folder whose writes would land in a source folder (they would be read back as frames)."""
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder")
    io.check_writable(out / "metrics.json", "--out")  # a read-only --out fails now, not at the first cache write
    written = {(out / f).resolve(): f for f in folders}
    for src in srcs:
        where = written.get(src.path.resolve()) if src.path.is_dir() else None
        if where is not None:
            where = "--out" if where == "." else f"--out's {where}/"
            raise ValueError(f"--out {out}: {where} folder is the source folder {src.path}; the run would write its "
                             "outputs among the frames it reads. Choose another --out")


def prepare_run(out: Path, paths, roles, method_names, opts: RunOptions):
    """The checks of the options, methods, encoder, sources and output before reading a frame.

    Returns (methods by name, encoder, sources, positions): ``positions`` the
    frames' positions of each source for position ground truth (None without;
    :func:`vpr.groundtruth.prepare_positions`, which also leaves out frames
    without one and applies ``--every``).
    """
    if isinstance(opts.verify, bool) or not isinstance(opts.verify, (int, np.integer)) or opts.verify < 0:
        raise ValueError(f"--verify must be an integer >= 0, got {opts.verify!r}")
    if opts.min_inliers < 0:
        raise ValueError(f"--min-inliers must be >= 0, got {opts.min_inliers}")
    if not opts.verify and opts.min_inliers != RunOptions.min_inliers:
        warn(f"--min-inliers {opts.min_inliers} has no effect without --verify N; ignored")
    runners = methods.build(method_names, opts.method_conf)
    encoder = encoders.get(opts.encoder, **opts.encoder_conf)
    srcs = [open_source(p, fps=opts.fps, step=opts.step, max_frames=opts.max_frames, topic=opts.topic)
            for p in paths]
    positions = prepare_positions(srcs, roles, opts.gt, opts.every)
    encoder.check_sources(srcs, roles, opts.chosen())
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


def extract_run(srcs, roles, encoder, runners: dict, opts: RunOptions):
    """The sources encoded once with what every method needs (:func:`encoders.extract.extract_all`)."""
    needed = set().union(*(r.required_inputs for r in runners.values()))
    return extract_all(srcs, roles, encoder, needed, opts.cache or Path(opts.out) / "cache", opts.verify > 0,
                       opts.progress)


def run_compare(db, query, method_names: list[str], opts: RunOptions, command: str = "compare") -> dict:
    """Encode ``db`` and ``query`` once, run every method, write the outputs; return metrics.json's content.

    Each method writes its files in ``opts.out/METHOD``; ``opts.out/metrics.json``
    and ``pr.png`` hold every method run into ``opts.out`` on the same inputs
    (:func:`pipelines.outputs.merge_metrics`). With ``opts.workers`` or
    ``opts.scheduler`` the query is matched in blocks on Dask (:mod:`pipelines.split`).
    """
    out = Path(opts.out)
    runners, encoder, (db_src, q_src), positions = prepare_run(out, [db, query], ["database", "query"], method_names,
                                                               opts)
    gt = check_match(runners, opts, db_src, q_src, positions)
    split = opts.workers is not None or opts.scheduler is not None
    n_workers = check_workers(opts.workers, opts.scheduler) if split else None
    # ---- the work starts here: nothing above wrote a file
    with claim_methods(out, runners):  # a second run of these methods into out meanwhile is refused
        db_ex, q_ex = extract_run([db_src, q_src], ["database", "query"], encoder, runners, opts)
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

            return compare_query(the_map, query, q_src, opts, command, q_ex=q_ex, argv=sys.argv[1:], gt=gt,
                                 encoder=encoder, matcher=matcher, extra={"split": shipped})


def check_match(runners: dict, opts: RunOptions, db_src, q_src, positions=None):
    """The checks of a database x query run that need both sources (before any work); returns the ground truth."""
    unknown = set(opts.verify_methods or ()) - set(runners)
    if unknown:
        raise ValueError(f"verify_methods: {', '.join(sorted(unknown))} not among the methods run")
    db_att, q_att = db_src.indices(), q_src.indices()
    for runner in runners.values():
        runner.check_size(len(db_att), len(q_att))  # too large for a method: refused now, not after encoding
    gt_hard, gt_soft = build_gt(opts.gt, db_src.names(), q_src.names(), db_att, q_att, db_src.name, q_src.name,
                                totals=(db_src.exact_total(), q_src.exact_total()), positions=positions)
    if gt_hard is not None and not any_true(gt_hard):
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

    ``gt`` (of :func:`check_match`) and ``encoder`` (the map's) are built here
    when not given (a fleet's worker gets the map alone); ``matcher(fitted)``:
    how each method matches the query (default: in this process); ``extra``:
    more ``params`` for ``metrics.json``.
    """
    out = Path(opts.out)
    db_src, db_ex = the_map.src, the_map.ex
    runners = {m: f.method for m, f in the_map.fitted.items()}
    gt_hard, gt_soft = gt if gt is not None else check_match(runners, opts, db_src, q_src)
    if encoder is None:
        encoder = encoders.get(the_map.encoder, **the_map.encoder_conf)
    if q_ex is None:
        (q_ex,) = extract_run([q_src], ["query"], encoder, runners, opts)
    if gt_hard is not None:
        rows, cols = frame_rows(db_src.indices(), db_ex.indices), frame_rows(q_src.indices(), q_ex.indices)
        gt_hard = gt_hard[np.ix_(rows, cols)]
        gt_soft = gt_soft[np.ix_(rows, cols)] if gt_soft is not None else None
        if not any_true(gt_hard):
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
        v = verifier if opts.verify_methods is None or m in opts.verify_methods else None
        entries = write_method(out / m, m, res, evaluated, db_names, q_names, gt_hard, gt_soft, v, opts.verify,
                               opts.progress)
        io.save_json(out / m / "config.json", _config(opts, argv, command=command, db=str(db), query=str(query),
                                                      methods=list(runners)))
        return {k: (e, None) for k, e in entries.items() if k != m}

    done = evaluate.run_methods(the_map.fitted, matcher or (lambda f: f.match(q_ex.features, progress=opts.progress)),
                                gt_hard, gt_soft, on_result=write)
    # what makes two runs' metrics comparable: same frames (content keys), encoding and ground truth
    inputs = {"kind": "match", "db": db_src.key(), "query": q_src.key(), "encoder": encoder.name,
              "encoder_conf": encoder.conf, "ground_truth": opts.gt.describe()}
    report = {
        "methods": {k: e for k, (e, _) in done.items()},
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


def run_loops(seq, method: str, opts: RunOptions, exclude: int | str = LOOP_EXCLUDE) -> dict:
    """Loop closures within the traverse ``seq`` with ``method``; writes the same outputs as ``match``.

    ``seq``: one source, or the sessions of one stream (a robot's runs, in
    order): learned one after the other, closures onto every earlier session
    count, nothing of a session's last moment carries into the next, and
    ``metrics.json`` reports each session pair. ``exclude``: frames, or
    ``"Ns"`` seconds where the frames have times (:meth:`vpr.sources.Source.frames_in`).
    Ground truth: :func:`vpr.groundtruth.build_stream_gt`.
    """
    out = Path(opts.out)
    seqs = [seq] if isinstance(seq, (str, Path)) else list(seq)
    roles = ["sequence"] if len(seqs) == 1 else [f"session {k + 1}" for k in range(len(seqs))]
    runners, encoder, srcs, positions = prepare_run(out, seqs, roles, [method], opts)
    exclude = srcs[0].frames_in(exclude)
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
    gt_hard, gt_soft = build_stream_gt(opts.gt, srcs, attempted, positions)
    if gt_hard is not None and not any_true(gt_hard & groundtruth.loop_closure_mask(T, exclude, starts=sessions)):
        raise opts.gt.no_match_error(exclude=exclude)
    # ---- the work starts here: nothing above wrote a file
    with claim_methods(out, runners):  # a second run of this method into out meanwhile is refused
        exs = extract_run(srcs, roles, encoder, runners, opts)
        read = [ex.indices for ex in exs]
        starts = [0, *np.cumsum([len(ex.features) for ex in exs])[:-1].tolist()]
        features = EncodedTraverse.join([ex.features for ex in exs], [s.name for s in srcs]) if len(exs) > 1 \
            else exs[0].features
        mask = None
        if gt_hard is not None:
            rows = np.concatenate([frame_rows(a, r, o) for a, r, o in zip(attempted, read, sessions, strict=True)])
            gt_hard = gt_hard[np.ix_(rows, rows)]
            gt_soft = gt_soft[np.ix_(rows, rows)] if gt_soft is not None else None
            mask = groundtruth.loop_closure_mask(len(features), exclude=exclude, starts=starts)
            if not any_true(gt_hard & mask):  # skipped frames took the last true pairs
                raise opts.gt.no_match_error(exclude=exclude)
        confs, opinions = {}, {}

        def write(m: str, res: MatchResult, evaluated) -> dict:
            confs[m] = res.conf
            if gt_hard is not None and len(srcs) > 1:
                evaluated[0]["sessions"] = evaluate.session_pairs(res.best_db, res.accepted, gt_hard, starts,
                                                                  gt_soft, mask, [s.name for s in srcs])
            write_method(out / m, m, res, evaluated, features.names, features.names, gt_hard, gt_soft,
                         title=f"{m}: loop closures", loops=True, mask=mask)
            io.save_json(out / m / "config.json", _config(opts, command="loops", seq=[str(q) for q in seqs],
                                                          method=m, exclude=exclude))

        def loops_of(r):
            opinion = None
            if opts.geometry:
                from vpr.verify import GeometricOpinion  # pycolmap: loaded only when verifying

                loop, image = r.seq.loop(), frame_reader(srcs, read)

                def opinion(decider):
                    opinions[r.name] = GeometricOpinion(decider, image, loop.back, loop.ahead, loop.stop_ratio)
                    return opinions[r.name]
            return r.loops(features, exclude=exclude, progress=opts.progress, sessions=starts, opinion=opinion)

        done = evaluate.run_methods(runners, loops_of, gt_hard, gt_soft, mask, on_result=write, loops=True)
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
