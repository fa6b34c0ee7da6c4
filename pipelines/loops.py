"""``vpr loops``: loop closures within one stream (or the sessions of one), in batch or online from stdin.

``vpr loops SEQ...`` runs the batch (:func:`run_loops`, any method that
supports loop closure); ``vpr loops -`` decides image paths on stdin frame by
frame (:mod:`pipelines.loops_online`).
"""
from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from pipelines import loops_online
from pipelines.args import (
    DESCRIPTORS,
    add_common_arguments,
    add_field_files_arguments,
    add_gt_arguments,
    add_query_speed_argument,
    add_recall_at_argument,
    add_run_arguments,
    field_files,
    loop_geometry,
    options_from_args,
    parse_recall_at,
    settings_from_args,
)
from pipelines.loops_online import no_revisit, rounded, say_session_speeds
from pipelines.outputs import claim_methods, merge_metrics, versions, write_method, write_ranked, write_stream_pairs
from pipelines.report import write_report
from pipelines.runs import RunOptions, config, extract_run, follows, prepare_run
from vpr import evaluate, groundtruth, io, methods
from vpr.groundtruth import any_true, build_stream_gt, frame_rows
from vpr.methods import LOOP_EXCLUDE
from vpr.similarity import budget_setting
from vpr.sources import frame_reader
from vpr.types import EncodedTraverse, MatchResult
from vpr.verify import opinion_around

__all__ = ["COMMANDS", "add_arguments", "run_batch", "run_command", "run_loops"]

COMMANDS = {"loops": "loop closures within one traverse (the paper's setting)"}


def add_arguments(ap: argparse.ArgumentParser, command: str) -> None:
    ap.add_argument("seq", metavar="SEQ", nargs="+",
                    help="image folder, video, image list, ROS bag, or descriptors computed elsewhere (.npy of N x "
                         "D, hloc's global-feature .h5); several: the sessions of one stream (a "
                         "robot's runs, in order); or - for image paths on stdin, decided online one frame at a time "
                         "(a JSON line per frame on stdout; a line #session starts a new session)")
    add_run_arguments(ap, "loop method")
    ap.add_argument("--exclude", default=None, metavar="W",
                    help="ignore matches fewer than W frames back, or W seconds for videos with 'Ws' "
                         f"(e.g. 5s; default {LOOP_EXCLUDE} frames)")
    ap.add_argument("--geometry", choices=("on", "off"),
                    help="a geometric second opinion (ORB + two-view RANSAC inliers of the best earlier frame, where "
                         "the images are large enough) accepts closures the method's own rule has not reached yet: "
                         "short loops, revisits a sequence is slow to trust; on by default for a method that decides "
                         "frame by frame (research/docs/loops.md), off: the method's rule alone decides")
    ap.add_argument("--pairs", type=int, default=0, metavar="N",
                    help="hloc's pairs file of the stream for structure from motion: each frame with its N next frames "
                         "and each accepted loop closure, METHOD/pairs-sequentialN-loops.txt (batch)")
    add_field_files_arguments(ap, pairs=False)
    add_query_speed_argument(ap, sessions=True)
    add_gt_arguments(ap, loops=True)
    add_recall_at_argument(ap)
    online = ap.add_argument_group("online (SEQ is -)")
    online.add_argument("--state-out", metavar="FILE.npz", help="save the loop detector after the last frame")
    online.add_argument("--resume", metavar="FILE.npz", help="continue a loop detector saved with --state-out")
    add_common_arguments(ap)


def run_command(args) -> int:
    """``vpr loops -`` runs online (:func:`pipelines.loops_online.run_command`), any other ``SEQ`` in batch
    (:func:`run_batch`)."""
    return (loops_online.run_command if "-" in args.seq else run_batch)(args)


def run_batch(args) -> int:
    """``vpr loops SEQ...``: the batch."""
    if args.state_out or args.resume:
        raise ValueError("--state-out and --resume are for online loop closure: SEQ - (image paths on stdin)")
    from vpr.report import metrics_table

    settings = settings_from_args(args)
    own = {"geometry": loop_geometry(settings["methods"][0], args.geometry, settings["encoder"] != DESCRIPTORS)}
    if args.exclude is not None:
        own["exclude"] = args.exclude
    if args.pairs < 0:
        raise ValueError(f"--pairs {args.pairs}: a number of next frames, 0 or more")
    files = field_files(args, pairs=False)
    opts = options_from_args(args, settings, pairs=args.pairs, top=files["top"], mat=files["mat"],
                             recall_at=parse_recall_at(args), **own)
    report = run_loops(args.seq[0] if len(args.seq) == 1 else args.seq, opts)
    print(metrics_table(report["methods"], "loops"))
    print(f"wrote {opts.out}/report.html (open it: the table, the plots and the frames side by side), metrics.json")
    return 0


def run_loops(seq, opts: RunOptions) -> dict:
    """Loop closures within the traverse ``seq`` with the first of ``opts.methods``; writes the same outputs as
    ``match``.

    ``seq``: one source, or the sessions of one stream (a robot's runs, in
    order): learned one after the other, closures onto every earlier session
    count, nothing of a session's last moment carries into the next, and
    ``metrics.json`` reports each session pair. ``opts.exclude``: frames, or
    ``"Ns"`` seconds where the frames have times (:meth:`vpr.sources.Source.frames_in`).
    Ground truth: :func:`vpr.groundtruth.build_stream_gt`.
    """
    out, method, exclude = Path(opts.out), opts.methods[0], opts.exclude
    seqs = [seq] if isinstance(seq, (str, Path)) else list(seq)
    roles = ["sequence"] if len(seqs) == 1 else [f"session {k + 1}" for k in range(len(seqs))]
    runners, encoder, srcs, positions, _ = prepare_run(out, seqs, roles, replace(opts, methods=(method,)))
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
    if gt_hard is not None and not any_true(groundtruth.loop_pairs(gt_hard, exclude, sessions)):
        no_revisit(opts.gt, exclude)
    # ---- the work starts here: nothing above wrote a file
    with claim_methods(out, runners):  # a second run of this method into out meanwhile is refused
        exs = extract_run(srcs, roles, encoder, runners, opts)
        read = [ex.indices for ex in exs]
        starts = [0, *np.cumsum([len(ex.features) for ex in exs])[:-1].tolist()]
        features = EncodedTraverse.from_parts([ex.features for ex in exs], [s.name for s in srcs]) if len(exs) > 1 \
            else exs[0].features
        mask = None
        if gt_hard is not None:
            rows = np.concatenate([frame_rows(a, r, o) for a, r, o in zip(attempted, read, sessions, strict=True)])
            gt_hard = gt_hard[np.ix_(rows, rows)]
            gt_soft = gt_soft[np.ix_(rows, rows)] if gt_soft is not None else None
            mask = groundtruth.loop_closure_mask(len(features), exclude=exclude, starts=starts)
        confs, opinions, speeds = {}, {}, {}

        def write(m: str, res: MatchResult, evaluated) -> dict:
            confs[m] = res.conf
            if len(srcs) > 1:  # the closures per pair of sessions (with ground truth: their precision and recall)
                evaluated[0]["sessions"] = evaluate.session_pairs(res.best, res.accepted, gt_hard, starts,
                                                                  gt_soft, mask, [s.name for s in srcs])
                evaluated[0]["session_speeds"] = rounded(speeds[m])
            if opts.pairs:
                (out / m).mkdir(parents=True, exist_ok=True)
                write_stream_pairs(out / m, res, features.names, opts.pairs, starts)
            write_method(out / m, res, evaluated, features.names, features.names, (gt_hard, gt_soft, mask),
                         title=f"{m}: loop closures", loops=True)
            write_ranked(out / m, res, features.names, features.names, opts.top, 0, opts.mat)
            io.save_json(out / m / "config.json", config(opts, command="loops", seq=[str(q) for q in seqs],
                                                          method=m, exclude=exclude))

        def loops_of(r):
            opinion = opinion_around(frame_reader(srcs, read), opinions, r.name) if opts.geometry else None
            res = r.loops(features, exclude=exclude, progress=opts.progress, sessions=starts, opinion=opinion)
            speeds[r.name] = evaluate.session_speeds(res.best, starts)  # as the sessions came, before any is followed
            if not opts.follow_speed:
                return res
            if len(starts) > 1:
                return methods.loops_at_speed(r, features, res, starts, opts.progress)
            return methods.loops_in_run_at_speed(r, features, res, exclude, opts.progress)

        done = evaluate.run_methods(runners, loops_of, gt_hard, gt_soft, mask, on_result=write, loops=True,
                                    recall_at=opts.recall_at)
        if len(srcs) == 1:  # the sessions of a stream are read one by one (below)
            groundtruth.check_speeds({k: m.get("path_speed") for k, (m, _) in done.items() if follows(k)},
                                     fix="within one run, a stretch read faster is matched again by default "
                                         "(metrics.json sampling.runs), one read slower is decided as it comes; "
                                         "given as sessions (vpr loops RUN1 RUN2), a later run is followed whole")
        for k, (m, _) in done.items():
            say_session_speeds(k, m.get("session_speeds"), [str(src.path) for src in srcs],
                               {f["session"] for f in (m.get("sampling") or {}).get("sessions", [])})
        for m, o in opinions.items():
            done[m][0]["geometry"] = o.report()
        inputs = {"kind": "loops", "seq": [s.key() for s in srcs] if len(srcs) > 1 else srcs[0].key(),
                  "exclude": exclude, "encoder": encoder.name, "encoder_conf": encoder.conf,
                  "ground_truth": opts.gt.describe()}
        report = {"methods": {k: e for k, (e, _) in done.items()},
                  "params": {"command": "loops", "seq": str(seq) if len(seqs) == 1 else [str(q) for q in seqs],
                             "exclude": exclude, "encoder": encoder.name, "encoder_conf": encoder.conf,
                             "method_conf": confs, "n_frames": len(features), "memory_budget": budget_setting(),
                             "sessions": [{"source": str(q), "first_frame": a, "frames": len(ex.features)}
                                          for q, a, ex in zip(seqs, starts, exs, strict=True)],
                             "encode_seconds": sum(ex.seconds for ex in exs),
                             "skipped": [sk for ex in exs for sk in ex.skipped],
                             "salvaged": {s.name: s.salvaged for s in srcs if s.salvaged} or None,
                             "ground_truth": opts.gt.describe(), "inputs": inputs},
                  "versions": versions()}
        merged = merge_metrics(out, report, f"loop closures in {', '.join(s.name for s in srcs)}")
    write_report(out, srcs, srcs, kind="loops")
    return merged
