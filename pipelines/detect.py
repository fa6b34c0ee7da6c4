"""``vpr loops -``: loop closure online, one image path per line on stdin, one JSON line per frame on stdout.

The frames are encoded with the preset's loop encoder (causal standardisation,
:class:`encoders.stream.StreamEncoder`) and decided by :class:`vpr.LoopDetector`
with the ``rshosm-seq`` conf of the preset (``--method-conf rshosm-seq.KEY=V``):
the answers are those of ``vpr loops SEQ`` on the same frames. Each frame's
line is written and flushed as soon as it is decided::

    {"query": 41, "query_name": "img/0041.png", "best_db": 3, "db_name": "img/0003.png",
     "score": 35.2, "accepted": true, "latency_ms": 14.1}

(the fields of every command's ``matches.csv``: ``best_db`` is the best
earlier frame, null while no frame is far enough back; ``latency_ms``:
encoding and deciding the frame, reading the file excluded). The first frames
of a causally standardised stream wait for the first ``CAUSAL_MIN`` before
they are encoded; they are never candidates of each other (``--exclude``
must exceed that wait), so their answers are known at once.

``--out DIR`` gets ``rshosm-seq/matches.csv`` and ``metrics.json`` (latency
median / p95 / max with and without encoding; with ``--gt`` the loop metrics of
``vpr loops`` over the frames read, numbered in the order they came), also when
the run is stopped (:mod:`pipelines.online`). ``--state-out FILE`` saves the
detector after the last frame; ``--resume FILE`` continues one (its encoder and
conf are in the file).
"""
from __future__ import annotations

import sys

import encoders
from encoders.stream import StreamEncoder
from pipelines.online import Answer, Online, run_online, stdin_frames
from pipelines.outputs import method_metrics
from vpr import groundtruth, io, methods, presets
from vpr.groundtruth import GroundTruthSpec, build_loop_gt, check_loop_gt_files
from vpr.shosm import LOOP_DETECTOR_DEFAULTS, LOOP_EXCLUDE, LoopDetector

__all__ = ["detect_loops", "make_detector"]

#: The method whose decisions the online detector gives.
ONLINE_METHOD = "rshosm-seq"


def make_detector(preset: str | None = None, encoder: str | None = None, encoder_conf: dict | None = None,
                  method_conf: dict | None = None, exclude: int = LOOP_EXCLUDE, resume=None) -> LoopDetector:
    """The detector of ``vpr loops -``: new (preset, encoder, ``rshosm-seq`` conf) or continued from ``resume``."""
    if resume is not None:
        given = [f for f, v in (("--encoder", encoder), ("--encoder-conf", encoder_conf),
                                ("--method-conf", method_conf)) if v]
        if given:
            raise ValueError(f"--resume {resume}: the encoder and the conf are the saved detector's; "
                             f"{', '.join(given)} cannot change them")
        det = LoopDetector.load(resume)
        enc = det.meta.get("encoder")
        if not enc:
            raise ValueError(f"{resume}: a loop detector saved without its encoder (not by `vpr loops -`)")
        return LoopDetector.load(resume, encoder=StreamEncoder(encoders.get(enc, **det.meta["encoder_conf"])))
    s = presets.resolve(preset, encoder=encoder, encoder_conf=encoder_conf, methods=[ONLINE_METHOD],
                        method_conf=method_conf, loops=True)
    unused = sorted(set(s["method_conf"]) - {ONLINE_METHOD})
    if unused:
        raise ValueError(f"vpr loops -: online loop closure is {ONLINE_METHOD}'s; --method-conf for "
                         f"{', '.join(unused)} does not apply")
    conf = methods.get(ONLINE_METHOD, **s["method_conf"].get(ONLINE_METHOD, {})).conf
    enc = encoders.get(s["encoder"], **s["encoder_conf"])
    det = LoopDetector(StreamEncoder(enc), exclude=exclude,
                       **{k: v for k, v in conf.items() if k in LOOP_DETECTOR_DEFAULTS})
    det.meta = {"encoder": enc.name, "encoder_conf": enc.conf, "preset": s["preset"]}
    return det


class LoopsOnline(Online):
    """``vpr loops -``: each frame learned and decided by a :class:`vpr.LoopDetector`."""

    command = "loops"
    method = ONLINE_METHOD

    def __init__(self, det: LoopDetector, gt: GroundTruthSpec):
        self.det, self.gt = det, gt
        self.row_offset = det.frames  # a resumed detector names frames from before this run too

    def warm_up(self) -> None:
        self.det.warm_up()
        self.det.encoder.warm_up()

    def encode(self, image):
        return self.det.encoder.push(image)

    def decide(self, encoded, name: str) -> Answer:
        r = self.det.update_encoded(encoded, name)
        return Answer(r.frame, r.best, r.earlier_name, round(r.score, 4), r.accepted, r.earlier, r.scores)

    def finish(self) -> None:
        self.det.flush()

    def evaluate(self, result, names, indices) -> dict:
        if not self.gt.files:
            return {}
        T = len(names)
        hard, soft = build_loop_gt(self.gt, names, list(range(T)), total=T)
        exclude = self.det.conf["exclude"]
        mask = groundtruth.loop_closure_mask(T, exclude=exclude)
        if not (hard & mask).any():
            raise self.gt.no_match_error(exclude=exclude)
        m, _ = method_metrics(result, hard, soft, mask=mask, loops=True)
        m.pop("seconds", None)
        m.pop("n_accepted", None)
        return m

    def save(self, path) -> None:
        self.det.save(path)

    def params(self) -> dict:
        det = self.det
        return {"seq": "-", "method": ONLINE_METHOD, "exclude": det.conf["exclude"],
                "encoder": det.meta.get("encoder"), "encoder_conf": det.meta.get("encoder_conf"),
                "method_conf": {ONLINE_METHOD: det.conf}, "ground_truth": self.gt.describe()}


def detect_loops(det: LoopDetector, out, stdin=None, stdout=None, gt: GroundTruthSpec | None = None,
                 state_out=None) -> dict:
    """Decide every frame named on ``stdin`` with ``det``; write ``out``'s files; return metrics.json's content.

    On a stop (Ctrl-C, SIGTERM) the frames decided so far are written and the
    detector saved, then the stop goes on (:func:`pipelines.online.run_online`).
    """
    gt = gt or GroundTruthSpec()
    check_loop_gt_files(gt)  # bad files are refused before any frame is read
    if state_out is not None:
        io.check_writable(state_out, "--state-out")
    job = LoopsOnline(det, gt)
    job.warm_up()
    return run_online(job, stdin_frames(stdin if stdin is not None else sys.stdin), out, stdout, state_out)
