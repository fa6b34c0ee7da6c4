"""``vpr loops -``: loop closure online, image paths on stdin decided frame by frame.

The loop detector a method that runs online hands out (:class:`vpr.types.StreamDetector`) with the preset's causal
loop encoder: the answers of the batch (:mod:`pipelines.loops`) on the same frames, one JSON line per frame
(:mod:`pipelines.online`); ``--state-out`` / ``--resume`` keep the detector.
"""
from __future__ import annotations

import sys

import numpy as np

import encoders
from pipelines.args import field_files, gt_spec_from_args, loop_geometry, parse_recall_at, settings_from_args
from pipelines.online import Online, run_online, summary_line
from pipelines.outputs import warn
from pipelines.stream import StreamEncoder
from vpr import evaluate, groundtruth, io, methods
from vpr.groundtruth import GroundTruthSpec, any_true, build_loop_gt, check_loop_gt_files
from vpr.methods import LOOP_EXCLUDE
from vpr.sources.base import frames_in
from vpr.sources.stdin import FramesByPath, StdinSource
from vpr.types import StreamDetector
from vpr.verify import opinion_around

__all__ = ["run_command", "detect_loops", "make_detector", "resume_detector", "LoopsOnline", "no_revisit",
           "say_session_speeds", "rounded"]

#: what follows a later session's speed where this command does not
LOCALIZE_SESSION = ("localise it against a map of the earlier sessions (vpr learn EARLIER --out map.npz; vpr localize "
                     "map.npz SESSION)")


def run_command(args) -> int:
    """``vpr loops -``: refuse what does not apply to a stream on stdin, then decide it frame by frame."""
    if len(args.seq) > 1:
        raise ValueError("vpr loops: - (paths on stdin) stands alone; mark its sessions with a line #session")
    settings = settings_from_args(args)
    given = [f for f, v in (("--fps", args.fps), ("--step", args.step), ("--max-frames", args.max_frames),
                            ("--cache", args.cache), ("--topic", args.topic), ("--every", args.every),
                            ("--gt-topic", args.gt_topic),
                            ("--memory-budget", args.memory_budget), ("--query-speed", args.query_speed),
                            ("--pairs", args.pairs or None), ("--mat", args.mat or None))
             if v is not None]
    if given:
        raise ValueError(f"vpr loops -: {', '.join(given)} apply to a folder or video, not to image paths on stdin")
    exclude = frames_in(LOOP_EXCLUDE if args.exclude is None else args.exclude, None, "image paths on stdin have none")
    if args.resume is not None:
        given = [f for f, v in (("--preset", args.preset), ("--method", args.method), ("--encoder", args.encoder),
                                ("--encoder-conf", args.encoder_conf), ("--method-conf", args.method_conf),
                                ("--exclude", args.exclude), ("--geometry", args.geometry)) if v]
        if given:
            raise ValueError(f"--resume {args.resume}: the encoder, the conf, --exclude and --geometry are the saved "
                             f"detector's; {', '.join(given)} cannot change them")
        det = resume_detector(args.resume)
    else:
        det = make_detector(settings, exclude, geometry=loop_geometry(settings["methods"][0], args.geometry))
    report = detect_loops(det, args.out, gt=gt_spec_from_args(args), state_out=args.state_out,
                          top=field_files(args, pairs=False)["top"], recall_at=parse_recall_at(args))
    print(summary_line(report, args.out, "loop closures accepted"), file=sys.stderr)
    return 0


def make_detector(settings: dict, exclude: int = LOOP_EXCLUDE, geometry: bool = True) -> StreamDetector:
    """The detector of ``vpr loops -`` for the run's ``settings`` (:func:`pipelines.args.settings_from_args`):
    the preset's loop encoder and the loop detector its method (one that runs online) hands out with its conf;
    ``geometry``: with the geometric second opinion (its frames read again from their paths)."""
    method = settings["methods"][0]
    unused = sorted(set(settings["method_conf"]) - {method})
    if unused:
        raise ValueError(f"vpr loops -: online loop closure is {method}'s; --method-conf for {', '.join(unused)} does "
                         "not apply")
    enc = encoders.get(settings["encoder"], **settings["encoder_conf"])
    runner = methods.get_online(method, sdr_bits=enc.n_bits, encoder=f"--encoder {enc.name}",
                                **settings["method_conf"].get(method, {}))
    enc.check_memory(1)  # frames come one at a time
    frames = FramesByPath()  # the detector's frame names, once it is made
    det = runner.loop_detector(StreamEncoder(enc), exclude=exclude,
                               opinion=opinion_around(frames) if geometry else None)
    frames.names = det.names
    det.meta.update({"encoder": enc.name, "encoder_conf": enc.conf, "preset": settings["preset"]})
    return det


def resume_detector(path) -> StreamDetector:
    """A detector saved by ``vpr loops - --state-out``, with the encoder and the opinion it was saved with."""
    meta = methods.saved_loop_meta(path)
    enc = meta.get("encoder")
    if not enc:
        raise ValueError(f"{path}: a loop detector saved without its encoder (not by `vpr loops -`)")
    frames = FramesByPath()  # the detector's frame names, once it is made
    det = methods.resume_loop_detector(path, StreamEncoder(encoders.get(enc, **meta["encoder_conf"])),
                                       opinion=opinion_around(frames) if meta["opinion"] else None)
    frames.names = det.names
    return det


class LoopsOnline(Online):
    """``vpr loops -``: each frame learned and decided by a method's loop detector (a
    :class:`vpr.types.StreamDetector`)."""

    command = "loops"

    def __init__(self, det: StreamDetector, gt: GroundTruthSpec, goes_on: bool = False):
        self.det, self.gt = det, gt
        self.method = det.meta["method"]
        self.resumed = det.frames > 0
        self.goes_on = goes_on  # the input's end is a pause (--state-out): closures wait in the state
        self.top_k = det.top_k
        self._reader = evaluate.SpeedReader()  # the current later session's speed onto the earlier ones
        self._said: set[int] = set()  # the later sessions whose speed was said (numbered from 1, the first)
        self._run = evaluate.SpeedReader()  # one run's paths of best earlier frames: a revisit driven faster

    def warm_up(self) -> None:
        self.det.warm_up()
        self.det.encoder.warm_up()

    def encode(self, image):
        return self.det.encoder.push(image)

    def answer(self, encoded, name: str):
        d = self.det.update_encoded(encoded, name)
        return self._watch(sorted([*self.det.take_late(), *([d] if d is not None else [])], key=lambda d: d.frame))

    def _watch(self, ds: list) -> list:
        """Say, from the frame it is read, a later session driven at another speed than the earlier ones (its paths
        of best earlier frames, as :func:`vpr.evaluate.session_speeds` reads them); returns ``ds``."""
        starts = self.det.starts
        a, n = starts[-1], len(starts)
        if not a:
            return self._watch_run(ds)
        if n in self._said:
            return ds
        for d in (d for d in ds if d.frame >= a):
            self._reader.step(d.best, d.best < a)
            v = self._reader.speed
            if groundtruth.speed_step(v):
                self._said.add(n)
                print(f"vpr loops: from frame {d.frame} on, session {n}'s best frames in the earlier sessions move "
                      f"{v:.2g} of theirs a frame: driven {'faster' if v > 1 else 'slower'} than they were at the "
                      f"same frame rate; its closures onto them are not followed online: {LOCALIZE_SESSION}, or "
                      "vpr loops S1 S2, follows it (research/docs/loops.md)",
                      file=sys.stderr, flush=True)
                break
        return ds

    def _watch_run(self, ds: list) -> list:
        """Say, once, a revisit within one run driven faster than the first pass: a run of best earlier frames that
        moves :data:`~vpr.groundtruth.RATE_RATIO` or more of them a frame (what the batch matches again:
        :func:`vpr.methods.loops_in_run_at_speed`); returns ``ds``."""
        for d in ds:
            if 0 in self._said:
                break
            self._run.step(d.best)
            v = self._run.run_speed
            if groundtruth.speed_step(v) > 0:
                self._said.add(0)
                print(f"vpr loops: from frame {d.frame} on, the best earlier frames move {v:.2g} of them a frame: a "
                      "revisit driven faster than the first pass at the same frame rate, not matched again online; "
                      "vpr loops of the folder or video matches it again (research/docs/loops.md)", file=sys.stderr,
                      flush=True)
        return ds

    def name_of(self, frame: int) -> str | None:
        return self.det.names[frame]

    def n_candidates(self) -> int:
        return self.det.frames  # a resumed detector's frames from before this run are candidates too

    def candidate_names(self) -> list[str]:
        return list(self.det.names[:self.n_candidates()])

    def waiting_in_state(self) -> int:
        return self.det.waiting + (self.det.encoder.waiting if self.det.encoder is not None else 0)

    def finish(self):
        self.det.flush(closures=not self.goes_on)
        return self._watch(self.det.take_late())

    def new_session(self):
        self.det.new_session()
        self._reader = evaluate.SpeedReader()
        return self._watch(self.det.take_late())

    def evaluate(self, result, names, indices, frames) -> dict:
        """Metrics over the frames answered in this run, against every frame of the stream before them (those
        from before a resume too: the state's names)."""
        starts = self.det.starts
        labels = [str(k + 1) for k in range(len(starts))]  # as the batch run's table, the sessions by their number
        N = self.det.frames
        speeds = {}
        if len(starts) > 1:  # said, not followed: an online detector answers each frame as it comes
            best = np.full(N, -1, np.int64)
            best[frames] = result.best
            speeds = {"session_speeds": rounded(evaluate.session_speeds(best, starts))}
            say_session_speeds(self.method, speeds["session_speeds"], read=self._said)
        if not self.gt.files:
            m = {"sessions": evaluate.session_pairs(result.best, result.accepted, None, starts, names=labels,
                                                    frames=frames), **speeds} if len(starts) > 1 else {}
            m.update(self._geometry())
            return m, None
        hard, soft = build_loop_gt(self.gt, self.det.names, list(range(N)), total=N)
        exclude = self.det.conf["exclude"]
        if not any_true(groundtruth.loop_pairs(hard, exclude, starts)[:, frames]):
            no_revisit(self.gt, exclude)
        hard, soft = (None if g is None else g[:, frames] for g in (hard, soft))
        mask = groundtruth.loop_closure_mask(N, exclude=exclude, starts=starts)[:, frames]
        m, curve = evaluate.method_metrics(result, hard, soft, mask=mask, loops=True, recall_at=self.recall_at)
        self.ground_truth = (hard, soft, mask)
        if len(starts) > 1:
            m["sessions"] = evaluate.session_pairs(result.best, result.accepted, hard, starts, soft, mask, labels,
                                                   frames=frames)
        m.update(speeds)
        m.update(self._geometry())
        m.pop("seconds", None)
        m.pop("n_accepted", None)
        return m, curve

    def _geometry(self) -> dict:
        """metrics.json's ``geometry``: the second opinion's report (frames verified, blind, accepted), if any."""
        report = self.det.opinion_report()
        return {"geometry": report} if report is not None else {}

    def save(self, path) -> None:
        self.det.save(path)

    def params(self) -> dict:
        det = self.det
        return {"seq": "-", "method": self.method, "exclude": det.conf["exclude"],
                "encoder": det.meta.get("encoder"), "encoder_conf": det.meta.get("encoder_conf"),
                "method_conf": {self.method: det.conf}, "ground_truth": self.gt.describe()}


def detect_loops(det: StreamDetector, out, stdin=None, stdout=None, gt: GroundTruthSpec | None = None,
                 state_out=None, top: int = 20, recall_at: tuple = evaluate.RECALL_AT) -> dict:
    """Decide every frame named on ``stdin`` with ``det``; write ``out``'s files; return metrics.json's content.

    ``top``: each frame's best earlier frames kept in ``top.csv``; ``recall_at``: the N of Recall@N.

    On a stop (Ctrl-C, SIGTERM) the frames decided so far are written and the
    detector saved, then the stop goes on (:func:`pipelines.online.run_online`).
    """
    gt = gt or GroundTruthSpec()
    check_loop_gt_files(gt)  # bad files are refused before any frame is read
    if state_out is not None:
        io.check_writable(state_out, "--state-out")
    job = LoopsOnline(det, gt, goes_on=state_out is not None)
    job.files = {"top": int(top), "pairs": 0, "mat": False} if top else {}
    job.recall_at = tuple(recall_at)
    job.warm_up()
    return run_online(job, StdinSource(stdin if stdin is not None else sys.stdin), out, stdout, state_out)


def no_revisit(gt: GroundTruthSpec, exclude: int) -> None:
    """Say that the ground truth holds no loop to close: a drive without revisits, whose closures are all false."""
    warn(f"{gt.no_match_error(exclude=exclude)}: every closure accepted is false (metrics.json: n_false, "
         "false_per_1000 frames)")


def rounded(speeds) -> list:
    """metrics.json's ``session_speeds``: each later session's speed to 3 decimals (None: not read)."""
    return [None if v is None else round(v, 3) for v in speeds]


def say_session_speeds(method: str, speeds, names=None, read=()) -> None:
    """Warn for each later session (``speeds``: metrics.json's ``session_speeds``; ``names``: every session's source)
    driven at another speed than the earlier ones, but those ``read`` and followed where they needed it
    (:func:`vpr.methods.loops_at_speed`; numbered from 1, the first session)."""
    src = lambda s: f" ({names[s + 1]})" if names else ""  # noqa: E731
    groundtruth.check_speeds({f"{method}: session {s + 2}{src(s)} against the earlier ones": v
                              for s, v in enumerate(speeds or []) if s + 2 not in read},
                             paths="paths of best earlier frames",
                             fix=f"{LOCALIZE_SESSION}, which follows its speed")
