"""The runs behind ``vpr match`` and ``compare`` (``loops`` shares their checks): before work, encoding, methods.

Every option, source and ground-truth file is checked before the first frame
is encoded, and a refused run writes nothing; every file is written
atomically, so an interrupted run leaves only complete files.
"""
from __future__ import annotations

import contextlib
import os
import pickle
import sys
import time
import uuid
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

import encoders
from pipelines.cluster import check_workers, dask_client, run_tasks, send_once, split_match
from pipelines.extract import extract_all
from pipelines.outputs import check_pairs, claim_methods, merge_metrics, versions, warn, write_method, write_ranked
from pipelines.report import write_report
from vpr import evaluate, io, methods
from vpr.groundtruth import (
    GroundTruthSpec,
    any_true,
    build_gt,
    check_rates,
    check_reversed,
    check_speeds,
    frame_rows,
    prepare_positions,
    sampling_step,
)
from vpr.interrupts import deferred
from vpr.methods import LOOP_EXCLUDE
from vpr.report import TABLE, table_cells, write_table
from vpr.similarity import budget_setting, dense_budget
from vpr.sources import check_ordered, open_sources
from vpr.types import MatchResult

__all__ = ["RunOptions", "run_compare", "run_fleet", "prepare_run", "compare_query", "MatchMap", "extract_run",
           "config"]


@dataclass
class RunOptions:
    """Everything but the inputs of a ``match`` / ``compare`` / ``loops`` run, checked where it is built.

    ``encoder_conf`` and ``method_conf`` (method -> conf) values may be strings
    (from the command line): they are read as the defaults' types.
    """

    out: Path
    #: the methods to run (the first is the headline)
    methods: tuple = ()
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
    #: bags' camera topic: one for all inputs, or a tuple of one per input
    topic: str | tuple | None = None
    #: keep one frame per this many metres of travel
    every: float | None = None
    #: Dask: a local cluster of this many workers (0: serial), or the cluster at ``scheduler``; None and None:
    #: serial (one query) or a local cluster of every core (a fleet)
    workers: int | None = None
    scheduler: str | None = None
    #: loops: a geometric second opinion on the closures of a method deciding frame by frame
    #: (:class:`vpr.verify.GeometricOpinion`)
    geometry: bool = False
    #: loops: candidates at least this many frames back, or ``"Ns"`` seconds where the frames have times
    exclude: int | str = LOOP_EXCLUDE
    #: the inputs are images (False: descriptor files, which no method or check that reads images can take)
    images: bool = True
    #: the N of Recall@N (:func:`vpr.evaluate.recall_at_n`)
    recall_at: tuple = evaluate.RECALL_AT
    #: the files the field's tools read (:func:`pipelines.outputs.write_ranked`): each query's N best (``top.csv``),
    #: hloc's pairs file of the N best, ``similarity.mat``
    top: int = 20
    pairs: int = 0
    mat: bool = False
    #: methods whose candidates are verified (None: all)
    verify_methods: tuple | None = None
    #: a query driven at another speed than the database matched again at the sampling that makes them agree
    #: (:func:`vpr.methods.match_at_speed`); False: its frames as they come
    follow_speed: bool = True
    #: further :class:`vpr.verify.Verifier` conf (e.g. ``{"n_features": 500}``)
    verify_conf: dict = field(default_factory=dict)
    progress: bool = True
    cache: Path | None = None
    #: bytes the dense matrices may take (``--memory-budget``; None: :func:`vpr.similarity.default_dense_budget`)
    memory_budget: int | None = None
    #: one hloc ``.h5`` for both: the database's and the queries' frames, by the beginning of their names
    db_prefix: str | None = None
    query_prefix: str | None = None

    def __post_init__(self):
        if isinstance(self.verify, bool) or not isinstance(self.verify, (int, np.integer)) or self.verify < 0:
            raise ValueError(f"--verify must be an integer >= 0, got {self.verify!r}")
        if self.min_inliers < 0:
            raise ValueError(f"--min-inliers must be >= 0, got {self.min_inliers}")
        if self.cache is not None and Path(self.cache).exists() and not Path(self.cache).is_dir():
            raise ValueError(f"--cache {self.cache}: is a file, expected a folder (of encodings, e.g. from `vpr "
                             "encode`)")
        check_workers(self.workers, self.scheduler)
        if not self.images and self.verify:
            raise ValueError("--verify matches the images' keypoints: the inputs are descriptors, no images")

    def chosen(self) -> str:
        """The options that chose the frames read (named when a source is too short)."""
        return " and ".join(f"{f} {v}" for f, v in (("--step", self.step), ("--max-frames", self.max_frames))
                            if v is not None)


def follows(label: str) -> bool:
    """Whether the method of a result's label (``m`` or ``m+verify``) follows sequences: its paths of best frames read
    the query's speed (a single-frame method's best frames form no path, and say nothing of it)."""
    name = label.split("+")[0]
    return name in methods.available() and methods.get_class(name).follows_sequences


def config(opts: RunOptions, argv=None, **inputs) -> dict:
    return {"argv": list(sys.argv[1:] if argv is None else argv), **inputs, **asdict(opts)}


def prepare_run(out: Path, paths, roles, opts: RunOptions, match: bool = False):
    """The checks of the methods, encoder, sources, ground truth and output before reading a frame.

    Returns (methods by name, encoder, sources, positions, ground truths): ``positions`` the frames' positions
    of each source (None without; :func:`vpr.groundtruth.prepare_positions`, which also leaves out frames
    without one and applies ``--every``); with ``match``, each query source's ground truth against the first
    source (gt_hard, gt_soft), also refused now when it holds no true pair.
    """
    chosen = opts.chosen()
    if not opts.verify and opts.min_inliers != RunOptions.min_inliers:
        warn(f"--min-inliers {opts.min_inliers} has no effect without --verify N; ignored")
    encoder = encoders.get(opts.encoder, **opts.encoder_conf)
    runners = methods.build(opts.methods, opts.method_conf, opts.images, sdr_bits=encoder.n_bits,
                            encoder=f"--encoder {encoder.name}")
    unknown = set(opts.verify_methods or ()) - set(runners)
    if unknown:
        raise ValueError(f"verify_methods: {', '.join(sorted(unknown))} not among the methods run")
    prefixes = [opts.db_prefix, *[opts.query_prefix] * (len(paths) - 1)]
    srcs = open_sources(paths, opts.topic, not match, fps=opts.fps, step=opts.step, max_frames=opts.max_frames,
                        prefix=prefixes, prefix_flags=["--db-prefix", *["--query-prefix"] * (len(paths) - 1)])
    check_ordered(srcs, roles, [m for m, r in runners.items() if r.reads_order])
    positions = prepare_positions(srcs, roles, opts.gt, opts.every)
    check_rates(srcs, opts.every, against_first=match)
    encoder.check_sources(srcs, roles, chosen)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder")
    io.check_writable(out / "metrics.json", "--out")  # a read-only --out fails now, not at the first cache write
    written = {(out / f).resolve(): f for f in [".", "cache", *runners]}
    for src in srcs:  # outputs written among the frames would be read back as frames
        where = written.get(src.path.resolve()) if src.path.is_dir() else None
        if where is not None:
            where = "--out" if where == "." else f"--out's {where}/"
            raise ValueError(f"--out {out}: {where} folder is the source folder {src.path}; the run would write its "
                             "outputs among the frames it reads. Choose another --out")
    if opts.cache is not None and Path(opts.cache).is_dir() and not os.access(opts.cache, os.W_OK | os.X_OK):
        warn(f"--cache {opts.cache}: not writable; encodings found there are read, new ones are not cached")
    n_db = len(srcs[0].indices())
    if match:
        check_pairs(opts.pairs, n_db, srcs[0].path)
    if opts.verify > n_db:
        raise ValueError(f"--verify {opts.verify}: more candidates per query than the database's {n_db} frames to read "
                         f"({srcs[0].path}); at most {n_db}")
    if not match:
        for runner in runners.values():
            runner.check_loops()  # a setting of online localisation: refused now, not after encoding
    gts = []
    for k, q_src in enumerate(srcs[1:] if match else [], start=1):
        db_att, q_att = srcs[0].indices(), q_src.indices()
        for runner in runners.values():
            runner.check_size(len(db_att), len(q_att))  # too large for a method: refused now, not after encoding
            runner.check_matching()  # a loop closure setting: refused now
        xy = None if positions is None else (positions[0], positions[k])
        gt_hard, gt_soft = build_gt(opts.gt, srcs[0].names(), q_src.names(), db_att, q_att, srcs[0].name,
                                    q_src.name, totals=(srcs[0].exact_total(), q_src.exact_total()), positions=xy,
                                    rates=(srcs[0].native_rate(), q_src.native_rate()))
        if gt_hard is not None and not any_true(gt_hard):
            raise opts.gt.no_match_error(db_att, q_att)
        gts.append((gt_hard, gt_soft))
    with deferred():  # numba loads or compiles the kernels here: a Ctrl-C inside its callbacks prints tracebacks
        for r in runners.values():
            r.warm_up()
    return runners, encoder, srcs, positions, gts


def extract_run(srcs, roles, encoder, runners: dict, opts: RunOptions):
    """The sources encoded once with what every method needs (:func:`pipelines.extract.extract_all`)."""
    needed = set().union(*(r.required_inputs for r in runners.values()))
    return extract_all(srcs, roles, encoder, needed, opts.cache or Path(opts.out) / "cache", opts.verify > 0,
                       opts.progress)


def run_compare(db, query, opts: RunOptions, command: str = "compare") -> dict:
    """Encode ``db`` and ``query`` once, run every method, write the outputs; return metrics.json's content.

    Each method writes its files in ``opts.out/METHOD``; ``opts.out/metrics.json``
    and ``pr.png`` hold every method run into ``opts.out`` on the same inputs
    (:func:`pipelines.outputs.merge_metrics`). With ``opts.workers`` or
    ``opts.scheduler`` the query is matched in blocks on Dask (:func:`pipelines.cluster.split_match`).
    """
    out = Path(opts.out)
    runners, encoder, (db_src, q_src), _, (gt,) = prepare_run(out, [db, query], ["database", "query"], opts, True)
    split = opts.workers is not None or opts.scheduler is not None
    # ---- the work starts here: nothing above wrote a file
    with claim_methods(out, runners), contextlib.ExitStack() as stack:  # a second run of these methods is refused
        db_ex, q_ex = extract_all([db_src, q_src], ["database", "query"], encoder,
                                  set().union(*(r.required_inputs for r in runners.values())),
                                  opts.cache or out / "cache", opts.verify > 0, opts.progress)
        the_map = MatchMap(str(db), db_src, db_ex, encoder.name, dict(encoder.conf),  # one query: learned as matched
                           {m: r.fit(db_ex.features, opts.progress, once=not split) for m, r in runners.items()})
        matcher, extra = None, {}
        if split and opts.workers != 0:
            scratch = out / f".dask-scratch-{os.getpid()}" if opts.scheduler is None else None
            client = stack.enter_context(dask_client(opts.workers, opts.scheduler, scratch))
            workers = opts.workers or len(client.scheduler_info().get("workers", {})) or 1
            extra["split"] = {}

            def matcher(f):
                if f.method.block_margin is None:
                    return f.match(q_ex.features, progress=opts.progress)
                return split_match(f, q_ex.features, client, workers, extra["split"].setdefault(f.name, {}))

        return compare_query(the_map, query, q_src, opts, (command, sys.argv[1:]), q_ex=q_ex, gt=gt,
                             encoder=encoder, matcher=matcher, extra=extra)


def run_fleet(db, queries, opts: RunOptions, command: str = "match", progress=None) -> dict:
    """Every query traverse of ``queries`` against ``db``, on Dask; return the summary written to ``OUT/metrics.json``.

    The database is encoded and learned once, here, and sent to the cluster
    once (:func:`pipelines.cluster.send_once`); each query traverse is one task
    that writes ``OUT/<query name>/`` as ``vpr match DB QUERY`` would
    (``opts.workers`` 0: here, one after the other). A task killed with its
    worker runs again elsewhere; its files are written atomically, so the
    results are the serial run's. ``progress(name, done, total)`` after each.
    """
    out = Path(opts.out)
    queries = [str(q) for q in queries]
    if len(queries) < 2:
        raise ValueError("a fleet needs two or more query traverses (one query: vpr match DB QUERY)")
    runners, encoder, srcs, _, gts = prepare_run(out, [db, *queries], ["database", *["query"] * len(queries)],
                                                 opts, True)
    db_src, q_srcs = srcs[0], srcs[1:]
    names = [s.name for s in q_srcs]
    for k, (s, n) in enumerate(zip(q_srcs, names, strict=True)):
        if n in names[:k]:
            raise ValueError(f"two query traverses are both named {n!r} ({q_srcs[names.index(n)].path} and "
                             f"{s.path}): their outputs would share OUT/{n}; rename one")
    # ---- the work starts here
    t0 = time.perf_counter()
    (db_ex,) = extract_all([db_src], ["database"], encoder, set().union(*(r.required_inputs for r in runners.values())),
                           opts.cache or out / "cache", opts.verify > 0, opts.progress)
    the_map = MatchMap(str(db), db_src, db_ex, encoder.name, dict(encoder.conf),
                       {m: r.fit(db_ex.features, progress=opts.progress) for m, r in runners.items()})
    t_map = time.perf_counter() - t0
    argv = sys.argv[1:]
    jobs = {n: (q, s, RunOptions(**{**opts.__dict__, "out": out / n, "progress": False}), command, argv, g)
            for n, q, s, g in zip(names, queries, q_srcs, gts, strict=True)}
    shipped = {"map_bytes": len(pickle.dumps(the_map, protocol=pickle.HIGHEST_PROTOCOL))}
    reports: dict = {}
    n_workers = check_workers(opts.workers, opts.scheduler)
    if n_workers == 0:
        for k, (n, job) in enumerate(jobs.items()):
            reports[n] = _query_task(the_map, *job)
            if progress:
                progress(n, k + 1, len(jobs))
    else:
        scratch = out / f".dask-scratch-{uuid.uuid4().hex[:8]}" if opts.scheduler is None else None
        with dask_client(None if n_workers is None else min(n_workers, len(jobs)), opts.scheduler, scratch) as client:
            client.wait_for_workers(1, timeout=60)
            shared, _ = send_once(client, the_map, f"vpr-map-{uuid.uuid4().hex[:8]}")
            shipped["task_bytes"] = max(len(pickle.dumps(j, protocol=pickle.HIGHEST_PROTOCOL)) for j in jobs.values())
            reports = run_tasks(client, _query_task, shared, jobs, progress)
    summary = {
        "queries": {n: reports[n]["methods"] for n in jobs},
        "params": {"command": command, "db": str(db), "queries": dict(zip(names, queries, strict=True)),
                   "preset": opts.preset, "encoder": encoder.name, "encoder_conf": encoder.conf,
                   "methods": list(runners), "n_db": len(db_ex.features),
                   "n_query": {n: reports[n]["params"]["n_query"] for n in jobs},
                   "workers": n_workers, "scheduler": opts.scheduler, "map_seconds": t_map,
                   "memory_budget": budget_setting(),
                   "seconds": time.perf_counter() - t0, "shipped": shipped,
                   "ground_truth": opts.gt.describe(sampling_step(srcs[0].indices()))},
        "versions": versions(),
    }
    io.save_json(out / "metrics.json", summary)
    write_table(out, f"vpr {command}: {len(jobs)} query traverses against {db}", TABLE["match"],
                       [(f"{n}: {m}", table_cells(v)) for n in jobs for m, v in summary["queries"][n].items()],
                       [], ["each query traverse's page, with its frames: OUT/<query>/report.html"])
    return summary


def _query_task(the_map: MatchMap, query: str, q_src, opts: RunOptions, command: str, argv, gt) -> dict:
    """One query traverse of a fleet, on a worker: its folder's report (``metrics.json``'s content)."""
    out = Path(opts.out)
    if out.is_dir():  # what a killed attempt left half-written (atomic writes: ``.NAME.RANDOM.SUFFIX``)
        for p in out.rglob(".*"):
            if p.is_file() and p.name != ".metrics.lock" and p.name.count(".") >= 3:
                p.unlink(missing_ok=True)
    with warnings.catch_warnings(), dense_budget(opts.memory_budget):  # the run's budget, not the worker's default
        warnings.simplefilter("ignore")  # a worker has no terminal; what matters is in metrics.json
        return compare_query(the_map, query, q_src, opts, (command, argv), gt=gt)


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


def compare_query(the_map: MatchMap, query, q_src, opts: RunOptions, ran: tuple = ("compare", None), q_ex=None,
                  gt=(None, None), encoder=None, matcher=None, extra: dict | None = None) -> dict:
    """One query traverse against a built map: encode it (unless ``q_ex``), run, evaluate, write ``opts.out``.

    ``ran``: the command and its argument list (None: this process's), recorded in the outputs; ``gt``: the ground
    truth of :func:`prepare_run`; ``encoder`` (the map's)
    is built here when not given (a fleet's worker gets the map alone);
    ``matcher(fitted)``: how each method matches the query (default: in this
    process; a query matched again at its speed is matched here); ``extra``: more ``params`` for ``metrics.json``.
    """
    out = Path(opts.out)
    db_src, db_ex = the_map.src, the_map.ex
    runners = {m: f.method for m, f in the_map.fitted.items()}
    gt_hard, gt_soft = gt
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
    command, argv = ran
    db, argv = the_map.db, list(sys.argv[1:] if argv is None else argv)

    def write(m: str, res: MatchResult, evaluated) -> dict:
        confs[m] = res.conf
        v = verifier if opts.verify_methods is None or m in opts.verify_methods else None
        io.save_json(out / m / "config.json", config(opts, argv, command=command, db=str(db), query=str(query),
                                                      methods=list(runners)))
        entries = write_method(out / m, res, evaluated, db_names, q_names, (gt_hard, gt_soft, None),
                               (v, opts.verify, opts.progress) if v is not None else None)
        write_ranked(out / m, res, db_names, q_names, opts.top, opts.pairs, opts.mat)
        return {k: (e, None) for k, e in entries.items() if k != m}

    read: dict = {}  # the query's speed as the first method to read it read it, for those that read none

    def call(f):
        res = matcher(f) if matcher else f.match(q_ex.features, progress=opts.progress)
        if not opts.follow_speed:
            return res
        res = methods.match_at_speed(f, q_ex.features, opts.progress, first=res, speed=read.get("speed"))
        if res.sampling:
            read.setdefault("speed", res.sampling["speed"])
        return res

    done = evaluate.run_methods(the_map.fitted, call, gt_hard, gt_soft, on_result=write, recall_at=opts.recall_at)
    check_speeds({k: m.get("path_speed") for k, (m, _) in done.items() if not m.get("sampling") and follows(k)})
    check_reversed({k: (m.get("reversed_frames", 0), m["n_accepted"]) for k, (m, _) in done.items()},
                   len(q_ex.features))
    # what makes two runs' metrics comparable: same frames (content keys), encoding and ground truth
    truth = opts.gt.describe(sampling_step(db_src.indices()))  # a tolerance in frames kept and in input frames
    inputs = {"kind": "match", "db": db_src.key(), "query": q_src.key(), "encoder": encoder.name,
              "encoder_conf": encoder.conf, "ground_truth": truth}
    report = {
        "methods": {k: e for k, (e, _) in done.items()},
        "params": {"command": command, "db": str(db), "query": str(query), "preset": opts.preset,
                   "encoder": encoder.name, "encoder_conf": encoder.conf, "method_conf": confs,
                   "n_db": len(db_ex.features), "n_query": len(q_ex.features),
                   "encode_seconds": {"db": db_ex.seconds, "query": q_ex.seconds},
                   "cached": {"db": db_ex.cached, "query": q_ex.cached},
                   "skipped": {"db": db_ex.skipped, "query": q_ex.skipped},
                   "ignored_files": {"db": db_ex.ignored, "query": q_ex.ignored},
                   "ground_truth": truth, "inputs": inputs, "memory_budget": budget_setting(),
                   "salvaged": {r: s.salvaged for r, s in (("db", db_src), ("query", q_src)) if s.salvaged} or None,
                   **(extra or {})},
        "versions": versions(),
    }
    merged = merge_metrics(out, report, f"{db_src.name} vs {q_src.name} ({encoder.name})")
    write_report(out, [db_src], [q_src])
    return merged
