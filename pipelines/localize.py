"""``vpr learn`` and ``vpr localize``: learn a map once, then localise a query stream frame by frame.

``learn`` encodes and learns the database and writes a :class:`vpr.maps.Map`
(the localizer, the encoder with what it fitted on the database, the frames'
positions). ``localize`` reads a map (or learns a database first), then
encodes and localises each query frame as it comes (a folder, video, bag, or
``-``: image paths on stdin), one JSON line per frame (:mod:`pipelines.online`).
The query is standardised causally (``--query-standardise``, ``--window``,
``--prior-frames``: :class:`pipelines.stream.StreamEncoder`); ``research/docs/localize.md``.
"""
from __future__ import annotations

import argparse
import contextlib
import sys
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

import encoders
from pipelines.args import (
    add_common_arguments,
    add_field_files_arguments,
    add_gt_arguments,
    add_method_conf_argument,
    add_prefix_arguments,
    add_preset_argument,
    add_query_speed_argument,
    add_recall_at_argument,
    add_source_arguments,
    descriptor_inputs,
    field_files,
    follows_speed,
    gt_spec_from_args,
    input_encoder,
    method_confs,
    parse_every,
    parse_recall_at,
    topic_arg,
)
from pipelines.maps import learn, learn_plan, load_map, map_encoder, map_path, plan_learn
from pipelines.online import Online, run_online, summary_line
from pipelines.outputs import check_pairs, warn
from pipelines.stream import PRIOR_FRAMES, WINDOW, StreamEncoder
from vpr import evaluate, io, methods, presets
from vpr.checks import per_input
from vpr.groundtruth import (
    GroundTruthSpec,
    any_true,
    build_gt,
    input_spec,
    prepare_positions,
    runs_backwards,
    same_rate,
    same_sampling,
    sampling_step,
)
from vpr.methods import Map, MemoryFileError
from vpr.sources import check_ordered, open_source
from vpr.sources.stdin import StdinSource
from vpr.types import Decision, FollowingLocalizer, LateLocalizer, QueryLocalizer

__all__ = ["COMMANDS", "add_arguments", "run_command", "learn", "load_map", "localize", "LocalizeOptions"]

COMMANDS = {
    "learn": "learn a database traverse once and write a map file for `vpr localize`",
    "localize": "localise a query stream (folder, video, list or stdin) frame by frame against a map",
}


# ------------------------------------------------------------------ localize
class LocalizeOnline(Online):
    """``vpr localize``: each query frame encoded with the map's encoder and localised by its :class:`vpr.Localizer`."""

    command = "localize"

    def __init__(self, the_map: Map, qenc: StreamEncoder, gt: GroundTruthSpec, q_src, params: dict, q_xy=None,
                 follower: FollowingLocalizer | None = None, late: LateLocalizer | None = None,
                 goes_on: bool = False):
        self.map, self.loc, self.qenc, self.gt, self.q_src = the_map, the_map.localizer, qenc, gt, q_src
        self.method = the_map.method
        self.resumed = bool(the_map.query_state)
        self._params, self.q_xy = params, q_xy  # the query frames' positions, by q_src.indices()
        self.top_k = self.loc.top_k
        self.follower = follower  # a query driven faster or slower than the map, followed (research/docs/localize.md)
        self.answering: QueryLocalizer = follower or self.loc
        self.late = late  # each frame answered a few frames late, with the frames after it
        #: the query frames' names and positions (or None) by frame number, while their answers wait
        self.waiting: dict[int, tuple[str, list | None]] = {}
        self._done: list[int] = []  # frames answered by the last call (their names read by the harness after it)
        self._from_state = 0  # frames read before this run, waiting in the state
        self._xy_of: dict[str, np.ndarray] | None = None
        self._state_xy: dict[int, list | None] = {}
        #: the input's end is a pause (``--state-out``): the frames waiting stay in the state
        self.goes_on = goes_on
        self._load_late()
        self._said = {0}
        # frames localised running the map backwards, accepted along it, decided
        self._reversed = self._accepted = self._decided = 0

    def warm_up(self) -> None:
        (self.late or self.answering).warm_up()
        self.qenc.warm_up()  # first calls (loading a CNN, the projection matrix) are not a frame's latency

    def encode(self, image):
        return self.qenc.encode(image)

    def answer(self, encoded, name: str) -> list[Decision]:
        for f in self._done:
            self.waiting.pop(f, None)
        ds = self.late.update(encoded) if self.late is not None else [self.answering.update(encoded)]
        frame = self.loc.frames - 1
        self.waiting[frame] = (name, self._xy(name))
        self._say_speed(frame, name)
        return self._count(ds)

    def _xy(self, name: str) -> list | None:
        """The query frame ``name``'s position (None without position ground truth)."""
        if self.q_xy is None:
            return None
        if self._xy_of is None:
            self._xy_of = dict(zip(self.q_src.names(), self.q_xy, strict=True))
        xy = self._xy_of.get(name)
        return None if xy is None else [float(v) for v in xy]

    def _count(self, ds: list[Decision]) -> list[Decision]:
        """Count the decisions ``ds`` and say what they show; returns ``ds``."""
        self._done = [d.frame for d in ds]
        for d in ds:
            self._reversed += bool(d.reversed)
            self._accepted += bool(d.accepted)
            self._decided += 1
            self._say(d, self.waiting_name(d.frame))
        return ds

    def waiting_name(self, frame: int) -> str | None:
        return self.waiting.get(frame, (str(frame), None))[0]

    def waiting_in_state(self) -> int:
        return self._from_state

    def waiting_xy(self, frame: int) -> list:
        """The position of frame ``frame``, read before this run (kept in the state)."""
        xy = self._state_xy.get(frame)
        return [np.nan, np.nan] if xy is None else xy

    def _load_late(self) -> None:
        """Continue the frames waiting in the map's state (a ``--state-out`` file)."""
        if self.late is None or self.map.late_state is None:
            return
        header, arrays = self.map.late_state
        self.late.load_state(header, arrays)
        self.waiting = {int(f): (str(n), xy) for f, n, xy in header["query"]}
        self._state_xy = {f: xy for f, (_, xy) in self.waiting.items()}
        self._from_state = len(self.late.waiting)

    def _say(self, d: Decision, name: str) -> None:
        if runs_backwards(self._reversed, self._accepted, self._decided) and "reversed" not in self._said:
            self._said.add("reversed")
            print(f"vpr localize: from query frame {d.frame} ({name}) on, the query runs the map backwards "
                  f"({self._reversed} frames localised so, {self._accepted} accepted along it): such frames' answers "
                  "are not accepted (metrics.json reversed_frames counts them)", file=sys.stderr, flush=True)

    def _say_speed(self, frame: int, name: str) -> None:
        if self.follower is None:
            return
        mode = self.follower.mode
        if mode not in self._said and (mode < 0 or self.follower.follows_faster):
            self._said.add(mode)
            k = self.follower.step
            how = (f"the map's {k} maps of one frame in {k}" if mode > 0 else
                   f"the map, its frames taken as {k} queries of one frame in {k}")
            print(f"vpr localize: from query frame {frame} ({name}) on, the map's best frames move "
                  f"{'faster' if mode > 0 else 'slower'} than one a frame: the query was driven at another speed than "
                  f"the map; frames are answered by {how} while it is so (research/docs/localize.md)", file=sys.stderr,
                  flush=True)

    def sampling(self) -> dict | None:
        return None if self.follower is None else self.follower.sampling()

    def name_of(self, frame: int) -> str | None:
        return self.loc.names[frame]

    def candidate_names(self) -> list[str]:
        return self.loc.names

    def n_candidates(self) -> int:
        return self.loc.n_db

    def evaluate(self, result, names, indices, frames) -> dict:
        gt = self.gt
        if not gt.given:
            return {}, None
        # the first rows: frames read before a restart, waiting in the state; then this run's source's frames
        n_from = self._from_state
        own = [i if i >= 0 else k - n_from for k, i in enumerate(indices)][n_from:]  # (stdin: the lines)
        positions = None
        if self.q_xy is not None:
            row = {k: r for r, k in enumerate(self.q_src.indices())}
            before = [self.waiting_xy(int(f)) for f in frames[:n_from]]
            positions = (self.map.positions, np.array([*before, *self.q_xy[[row[k] for k in own]]], np.float64))
        # a resumed run's query frames continue the stopped run's numbering: it read frames 0 .. frames[n_from] - 1
        step = sampling_step(own)
        first = int(frames[n_from]) if len(frames) > n_from else 0
        q_idx = [int(f * step) for f in frames[:n_from]] + [int(first * step) + i for i in own]
        gt_hard, gt_soft = query_gt(gt, MapFrames.of_map(self.map), names, q_idx, self.q_src, positions)
        if not any_true(gt_hard):  # a query of image paths on stdin (a source's is refused before any frame)
            warn(f"{gt.no_match_error(q_indices=q_idx)}: the decisions are written without metrics")
            return {}, None
        m, curve = evaluate.method_metrics(result, gt_hard, gt_soft, recall_at=self.recall_at)
        self.ground_truth = (gt_hard, gt_soft, None)
        m.pop("seconds", None)
        m.pop("n_accepted", None)
        return m, curve

    def new_session(self) -> list[Decision]:
        """A new query traverse: no evidence or path carries over, the query statistics start again (the frames
        waiting are answered first)."""
        ds = self.late.reset() if self.late is not None else []
        if self.late is None:
            self.answering.reset()
        self.qenc.new_session()
        return self._count(ds)

    def finish(self) -> list[Decision]:
        """The frames waiting answered with the frames there are after them; with ``--state-out`` they wait in the
        state instead (the input's end may be a pause)."""
        return self._count(self.late.flush()) if self.late is not None and not self.goes_on else []

    def save(self, path) -> None:
        self.map.query_state = self.qenc.state()[1]  # its header is empty: the arrays hold it
        self.map.follow_state = None if self.follower is None else self.follower.state()
        self.map.late_state = None
        if self.late is not None:
            header, arrays = self.late.state()
            frames = [int(w.decision.frame) for w in self.late.waiting]
            query = [[f, *self.waiting.get(f, (str(f), None))] for f in frames]
            self.map.late_state = ({**header, "query": query}, arrays)
        self.map.save(path)

    def resume_hint(self, path) -> str:
        return f"give {path} as the map (vpr localize {path} QUERY)"

    def report_sources(self, src) -> tuple[list, list]:
        """The map's sources where they are still on disk (the map keeps their paths, not their frames)."""
        dbs = self.map.info.get("db")
        srcs = []
        for d in [dbs] if isinstance(dbs, str) else dbs or []:
            with contextlib.suppress(OSError, ValueError), warnings.catch_warnings():
                warnings.simplefilter("ignore")
                srcs.append(open_source(d))
        return srcs, [src]

    def params(self) -> dict:
        return {**self._params, "method": self.method, "encoder": self.map.encoder["name"],
                "encoder_conf": self.map.encoder["conf"],
                "method_conf": {self.method: self.loc.conf}, "n_db": self.loc.n_db,
                "ground_truth": self.gt.describe(sampling_step(self.map.info.get("db_indices") or
                                                               range(self.loc.n_db)))}


@dataclass(frozen=True)
class MapFrames:
    """The frames a query is scored against: a learned map's, or a database's about to be learned (its sources'
    frames, read before any is encoded)."""

    method: str
    names: list
    indices: list
    source: str
    rate: float | None
    positions: np.ndarray | None
    origin: tuple | None

    @classmethod
    def of_map(cls, the_map: Map) -> MapFrames:
        info, loc = the_map.info, the_map.localizer
        return cls(the_map.method, list(loc.names), list(info.get("db_indices") or range(loc.n_db)),
                   info.get("db_source", "database"), info.get("source_rate"), the_map.positions, the_map.origin)

    @classmethod
    def of_plan(cls, plan) -> MapFrames:
        xy = None if plan.positions is None else np.concatenate(list(plan.positions))
        rate = plan.srcs[0].native_rate() if len(plan.srcs) == 1 else None
        return cls(plan.method.name, plan.names(), plan.indices(), plan.srcs[0].name, rate, xy, plan.origin())


def _query_positions(q_src, q_gt: GroundTruthSpec, db: MapFrames, every) -> np.ndarray:
    """The query source's frame positions (``--every``: one frame kept per so many metres), about the map's origin."""
    return prepare_positions([q_src], ["query"], q_gt, every, loops=False, origin=db.origin)[0]


def query_gt(gt: GroundTruthSpec, db: MapFrames, names, indices, q_src, positions=None):
    """(gt_hard, gt_soft) of the query frames ``names`` (source frame numbers ``indices``) against the map's frames
    ``db``; ``positions``: (the map's, the query frames') positions with ``--radius``."""
    return build_gt(gt, db.names, names, db.indices, indices, db.source, q_src.name, positions=positions,
                    rates=(db.rate, q_src.native_rate()))


def check_query_gt(gt: GroundTruthSpec, db: MapFrames, q_src, q_xy=None) -> None:
    """Refuse, before a frame is read, a ground truth in which no frame of the query source has a true match in the
    map (as ``vpr match`` refuses it; what it says is said again when the frames read are scored)."""
    if not gt.given:
        return
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        hard, _ = query_gt(gt, db, q_src.names(), q_src.indices(), q_src,
                           None if q_xy is None else (db.positions, q_xy))
    if hard is not None and not any_true(hard):
        raise gt.no_match_error(db.indices, q_src.indices())


@dataclass(frozen=True)
class LocalizeOptions:
    """How ``vpr localize`` reads and answers a query.

    Attributes
    ----------
    query_standardise, prior_frames, window : see :class:`pipelines.stream.StreamEncoder` (None: its default;
        window 0: all frames so far); ``prior_frames`` and ``window`` apply to ``"running"`` only.
    gt : ground truth (as ``vpr match``), optional; position ground truth (``--radius``) needs the map's
        positions and a query source.
    learn_options : how a database given instead of a map is learned (:func:`pipelines.maps.learn`'s keywords); over
        a map: ``method_conf``, its query-time settings (and ``method``, which must be the map's).
    fps, step, max_frames : the frames read (as ``vpr match``).
    state_out : optional path: the map with the query's state after the last frame (a robot's restart file).
    progress : progress bar while learning a database.
    topic : bags' camera topic (a pair: the database's and the query's); every : one query frame per so many
        metres (with the query's positions).
    db_prefix, query_prefix : one hloc ``.h5`` for both: the database's and the query's frames by the beginning of
        their names.
    follow_speed : a query driven faster or slower than the map at the same frame rate answered by the maps of one
        frame in k or as queries of one frame in k while it is so (the method's ``follower``, where it has one);
        False: the frames as they come.
    files : the files the field's tools read (``top``, ``pairs``, ``mat`` of
        :func:`pipelines.outputs.write_ranked`); default: each query frame's 20 best map frames (``top.csv``).
    recall_at : the N of Recall@N (:func:`vpr.evaluate.recall_at_n`).
    """

    query_standardise: str = "running"
    prior_frames: float | None = None
    window: int | None = None
    gt: GroundTruthSpec = field(default_factory=GroundTruthSpec)
    learn_options: dict = field(default_factory=dict)
    fps: float | None = None
    step: int | None = None
    max_frames: int | None = None
    state_out: str | Path | None = None
    progress: bool = False
    topic: str | tuple | None = None
    every: float | None = None
    follow_speed: bool = True
    files: dict = field(default_factory=lambda: {"top": 20, "pairs": 0, "mat": False})
    recall_at: tuple = evaluate.RECALL_AT
    db_prefix: str | None = None
    query_prefix: str | None = None


def localize(map_or_db, query, out, opts: LocalizeOptions | None = None, stdout=None, stdin=None, **options) -> dict:
    """Localise every frame of ``query`` against a map (or a database learned first); return metrics.json's content.

    ``map_or_db``: a map written by :func:`learn`, or a database source (learned with ``opts.learn_options``);
    ``query``: folder, video, image list, bag, or ``"-"`` (paths read from ``stdin``); ``out``: the output folder
    (``METHOD/matches.csv``, ``metrics.json``; :mod:`pipelines.online`); ``opts``: :class:`LocalizeOptions`, with
    ``**options`` over them.
    """
    o = replace(opts or LocalizeOptions(), **options)
    out = Path(out)
    io.check_writable(out / "metrics.json", "--out")
    if o.state_out:
        io.check_writable(o.state_out, "--state-out")
    running = {k: v for k, v in (("prior_frames", o.prior_frames), ("window", o.window)) if v is not None}
    if o.query_standardise != "running" and running:
        raise ValueError(f"--{' and --'.join(k.replace('_', '-') for k in running)} appl"
                         f"{'ies' if len(running) == 1 else 'y'} to --query-standardise running, not "
                         f"{o.query_standardise} (the database's statistics, fixed)")
    if running.get("window") == 0:
        running["window"] = None  # every frame so far
    p = Path(map_or_db)
    learned = Map.is_map(p) or (p.is_file() and p.suffix.lower() == ".npz")  # a foreign .npz is refused by Map.load
    gt = o.gt or GroundTruthSpec()
    gt.check()
    if learned and gt.positional and len(gt.files) > 1:
        raise ValueError(f"--gt {' '.join(gt.files)}: {map_or_db} is a learned map, which keeps its frames' "
                         "positions; give the query's positions alone (--gt QUERY_FILE)")
    # one camera topic for both, or the database's and the query's; each input's own positions
    db_topic, topic = [None, *per_input(o.topic, 1, "--topic")] if learned else per_input(o.topic, 2, "--topic")
    db_gt, q_gt = (None, input_spec(gt, 0, 1)) if learned else (input_spec(gt, 0, 2), input_spec(gt, 1, 2))
    gt = replace(gt, topic=q_gt.topic)
    stdin_query = str(query) == "-"
    frames = {"fps": o.fps, "step": o.step, "max_frames": o.max_frames}
    learn_options = dict(o.learn_options or {})
    plan = None
    if learned:
        the_map, enc = load_map(p)
        named = learn_options.get("method")
        if named and named != the_map.method:
            raise ValueError(f"{map_or_db} is a map of {the_map.method}: --method-conf for {named} does not apply")
        if learn_options.get("method_conf"):  # query-time settings apply to a learned map
            the_map.localizer = the_map.localizer.reconfigure(**learn_options["method_conf"])
        db = MapFrames.of_map(the_map)
    else:  # checked and opened now, learned once the query is checked too
        plan = plan_learn(map_or_db, **learn_options, topic=db_topic, positions=db_gt if gt.positional else None,
                          every=o.every if gt.positional else None, prefix=o.db_prefix, **frames)
        db = MapFrames.of_plan(plan)
    if o.every is not None and not gt.positional:
        prepare_positions([], ["query"], q_gt, o.every)  # refused: --every needs the frames' positions
    q_src = StdinSource(stdin if stdin is not None else sys.stdin) if stdin_query else \
        open_source(query, topic=topic, prefix=o.query_prefix, prefix_flag="--query-prefix", **frames)
    if stdin_query and o.query_prefix is not None:
        raise ValueError("--query-prefix picks the frames of an .h5 by name: image paths on stdin have none")
    if not stdin_query:
        check_ordered([q_src], ["query"], [db.method] if methods.get_class(db.method).reads_order else [])
    if gt.positional and stdin_query:
        raise ValueError("position ground truth (--radius) reads the query's positions from its source; with "
                         "paths on stdin give --gt PAIRS.csv or --tolerance")
    if gt.positional and db.positions is None:
        raise ValueError(f"{map_or_db}: the map holds no positions of its frames, so --radius has nothing to "
                         "match; learn it with --gt-topic or --gt (or give the database itself)")
    check_pairs(o.files.get("pairs", 0), len(db.names), map_or_db)
    if not stdin_query:  # every frame of the query source (--every keeps some of them, later)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # said when the frames kept are read
            q_xy = _query_positions(q_src, q_gt, db, None) if gt.positional else None
        check_query_gt(gt, db, q_src, q_xy)
    # ---- the work starts here: every refusal above
    if plan is not None:
        the_map = learn_plan(plan, o.progress)
        the_map.save(map_path(out / "map.npz"))  # the map learned, to localise against again (vpr localize DIR/map.npz)
        enc = map_encoder(the_map)
    the_map, every = same_sampling(the_map, o.every, gt.positional, str(map_or_db), o.progress)
    if not stdin_query and every is None:  # a query at another frame rate than the map's
        the_map, q_fps = same_rate(the_map, q_src, o.fps, str(map_or_db), o.progress)
        if q_fps:
            q_src = open_source(query, topic=topic, prefix=o.query_prefix, **{**frames, "fps": q_fps})
    q_xy = _query_positions(q_src, q_gt, MapFrames.of_map(the_map), every) if gt.positional else None
    qenc = StreamEncoder(enc, o.query_standardise, **running)
    qenc.load_state({}, the_map.query_state)  # a --state-out file continues its query's running statistics
    follower = methods.get(the_map.method).follower(the_map.localizer, the_map.sdr) if o.follow_speed else None
    if follower is not None:
        if the_map.follow_state is not None:  # a --state-out file continues its follower too
            try:
                follower.load_state(*the_map.follow_state)
            except (KeyError, ValueError, TypeError, IndexError) as e:
                raise MemoryFileError(f"{map_or_db}: corrupt map file (the state of its speed follower: "
                                      f"{type(e).__name__}: {e})") from e
    late = methods.get(the_map.method).late(the_map.localizer, follower)
    job = LocalizeOnline(the_map, qenc, gt, q_src,
                         {"map_or_db": str(map_or_db), "query": str(query), "query_standardise": o.query_standardise,
                          "prior_frames": o.prior_frames, "window": o.window, "follow_speed": o.follow_speed}, q_xy,
                         follower, late, goes_on=bool(o.state_out))
    job.files = dict(o.files)
    job.recall_at = tuple(o.recall_at)
    job.warm_up()
    return run_online(job, q_src, out, stdout, o.state_out)


# ------------------------------------------------------------------ command line
def _add_learn_args(ap):
    add_preset_argument(ap)
    encoders.add_arguments(ap, default=None)
    online = [m for m in methods.available() if methods.get_class(m).runs_online]
    ap.add_argument("--method", choices=online, help=f"the method that learns the map (default {methods.online()})")
    add_method_conf_argument(ap)


def add_arguments(ap: argparse.ArgumentParser, command: str) -> None:
    if command == "learn":
        ap.add_argument("db", metavar="DB", nargs="+", help="database traverse: image folder, video, image list, ROS "
                        "bag, or descriptors computed elsewhere (.npy of N x D, hloc's global-feature .h5); several: "
                        "the sessions of one map (a robot's runs)")
        ap.add_argument("--out", required=True, metavar="MAP.npz", help="map file to write")
        _add_learn_args(ap)
        add_source_arguments(ap)
        add_prefix_arguments(ap, query=False)
        pos = ap.add_argument_group("the frames' positions, kept in the map (vpr localize --radius evaluates "
                                    "against them; --every needs them)")
        pos.add_argument("--gt", nargs=1, metavar="FILE", help="positions CSV (frame,x,y), TUM trajectory, KITTI "
                         "poses, or the word names (UTM in the file names) or exif")
        pos.add_argument("--gt-topic", nargs="+", metavar="TOPIC", help="ROS bags: a NavSatFix, Odometry or "
                         "PoseStamped topic; one for all sessions or one per session, in order")
        add_common_arguments(ap)
        return
    ap.add_argument("map", metavar="MAP_OR_DB", help="map from `vpr learn` (.npz), or a database traverse to learn "
                    "(as vpr learn's DB)")
    ap.add_argument("query", metavar="QUERY", help="image folder, video, image list, ROS bag, descriptors computed "
                    "elsewhere (.npy of N x D, hloc's global-feature .h5), or - (image paths on stdin)")
    ap.add_argument("--out", required=True, help="output folder (matches.csv, metrics.json)")
    ap.add_argument("--query-standardise", choices=("running", "db"), default="running",
                    help="standardise=fit encoders: running statistics of the query so far (default) or the "
                         "database's")
    ap.add_argument("--prior-frames", type=float,
                    help="running: weight of the database's statistics in the running ones, in frames (default "
                         f"{PRIOR_FRAMES:g})")
    ap.add_argument("--window", type=int,
                    help=f"running: statistics over the last N query frames that moved (default {WINDOW}; 0: all "
                         "frames so far; a frame that keeps most of the one before's bits does not join them)")
    ap.add_argument("--state-out", metavar="FILE.npz", help="also write the localizer with its state at the end")
    add_query_speed_argument(ap)
    add_field_files_arguments(ap)
    learn_group = ap.add_argument_group("learning MAP_OR_DB when it is a database")
    _add_learn_args(learn_group)
    add_source_arguments(ap)
    add_prefix_arguments(ap)
    add_gt_arguments(ap, title="ground truth (optional; enables AP and R@1)")
    add_recall_at_argument(ap)
    add_common_arguments(ap)


def _online_method(args) -> tuple[str, dict]:
    """The method that learns the map (``--method``, else the one that runs online ``--method-conf`` names, else
    :func:`vpr.methods.online`) and the conf given for it; a conf of another method refused."""
    confs = method_confs(args.method_conf)
    online = [m for m in confs if methods.get_class(m).runs_online]
    name = args.method or (online[0] if len(online) == 1 else methods.online())
    other = sorted(set(confs) - {name})
    if other:
        raise ValueError(f"vpr {args.command}: the map is {name}'s; --method-conf for {', '.join(other)} does not "
                         "apply")
    return name, confs.get(name, {})


def run_command(args) -> int:
    name, given = _online_method(args)
    # the preset's encoder and the method's conf unless flags name others (vpr.presets.resolve)
    encoder = input_encoder(args, descriptor_inputs(args))
    settings = presets.resolve(args.preset, encoder=encoder, encoder_conf=encoders.parse_conf(args.encoder_conf),
                               methods=[name], method_conf={name: given})
    methods.get_online(name, **settings["method_conf"][name]).check_matching(online=True)  # before a frame is read
    every = parse_every(args.every) if args.every else None
    if args.command == "learn":
        # where the positions are (no radius: nothing is evaluated here; the map keeps them)
        spec = GroundTruthSpec(files=tuple(args.gt or ()), topic=topic_arg(args.gt_topic), radius=0.0) \
            if args.gt or args.gt_topic else None
        the_map = learn(args.db[0] if len(args.db) == 1 else args.db, args.out, fps=args.fps, step=args.step,
                    max_frames=args.max_frames,
                    progress=not args.no_progress, encoder=settings["encoder"], encoder_conf=settings["encoder_conf"],
                    method=name, method_conf=settings["method_conf"][name], topic=topic_arg(args.topic), positions=spec,
                    every=every, prefix=args.db_prefix)
        loc = the_map.localizer
        skipped = the_map.info.get("skipped") or []
        if skipped:
            warn(f"{len(skipped)} of the frames could not be read and are not in the map "
                 f"(first: {skipped[0][0]}: {skipped[0][1]})")
        print(f"learned {loc.n_db} frames ({loc!r}); wrote {map_path(args.out)}")
        return 0
    if Map.is_map(args.map) or Path(args.map).suffix.lower() == ".npz":
        fixed = [f for f, v in (("--encoder", args.encoder), ("--encoder-conf", args.encoder_conf),
                                ("--preset", args.preset), ("--method", args.method), ("--db-prefix", args.db_prefix))
                 if v]
        if fixed:
            raise ValueError(f"{args.map} is a learned map: it fixes the method, the encoder and its conf "
                             f"({', '.join(fixed)} cannot change them); --method-conf METHOD.KEY=VALUE sets the "
                             "query-time options")
        learn_opts = {"method": name if given else None, "method_conf": given}  # over the map's own: what was given
    else:
        learn_opts = {"encoder": settings["encoder"], "encoder_conf": settings["encoder_conf"], "method": name,
                      "method_conf": settings["method_conf"][name]}
    src_opts = {"fps": args.fps, "step": args.step, "max_frames": args.max_frames, "topic": topic_arg(args.topic),
                "every": every}
    opts = LocalizeOptions(query_standardise=args.query_standardise, prior_frames=args.prior_frames,
                           window=args.window, state_out=args.state_out, gt=gt_spec_from_args(args),
                           learn_options=learn_opts, progress=not args.no_progress,
                           follow_speed=follows_speed(args), files=field_files(args),
                           recall_at=parse_recall_at(args), db_prefix=args.db_prefix,
                           query_prefix=args.query_prefix, **src_opts)
    report = localize(args.map, args.query, args.out, opts)
    print(summary_line(report, args.out), file=sys.stderr)
    return 0
