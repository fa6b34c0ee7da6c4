"""``vpr loops -``: loop closure online, one image path per line on stdin, one JSON line per frame on stdout.

The frames are encoded with the preset's loop encoder (causal standardisation,
:class:`encoders.stream.StreamEncoder`) and decided by :class:`vpr.LoopDetector`
with the ``rshosm-seq`` conf of the preset (``--method-conf rshosm-seq.KEY=V``):
the answers are those of ``vpr loops SEQ`` on the same frames. Each frame's
line is written and flushed as soon as it is decided::

    {"frame": 41, "name": "img/0041.png", "best_earlier": 3, "earlier_name": "img/0003.png",
     "score": 35.2, "accepted": true, "latency_ms": 14.1}

(``latency_ms``: encoding and deciding the frame, reading the file excluded;
``best_earlier`` null while no frame is far enough back). The first frames
of a causally standardised stream wait for the first ``CAUSAL_MIN`` before
they are encoded; they are never candidates of each other (``--exclude``
must exceed that wait), so their answers are known at once.

``--out DIR`` gets ``matches.csv`` and ``metrics.json`` (latency median / p95 /
max with and without encoding; with ``--gt`` the loop metrics of ``vpr loops``
over the frames read, numbered in the order they came). ``--state-out FILE``
saves the detector after the last frame; ``--resume FILE`` continues one (its
encoder and conf are in the file).
"""
from __future__ import annotations

import csv
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

import encoders
from encoders.stream import StreamEncoder
from pipelines.frames import JsonLines, latency_summary, stdin_frames
from pipelines.outputs import method_metrics, versions
from vpr import groundtruth, io, methods, presets
from vpr.groundtruth import GroundTruthSpec, build_loop_gt, check_loop_gt_files
from vpr.shosm import LOOP_DETECTOR_DEFAULTS, LOOP_EXCLUDE, LoopDetector
from vpr.types import MatchResult

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


def detect_loops(det: LoopDetector, out, stdin=None, stdout=None, gt: GroundTruthSpec | None = None,
                 state_out=None) -> dict:
    """Decide every frame named on ``stdin`` with ``det``; write ``out``'s files; return metrics.json's content."""
    stdout = sys.stdout if stdout is None else stdout
    out = Path(out)
    gt = gt or GroundTruthSpec()
    check_loop_gt_files(gt)  # bad files are refused before any frame is read
    if state_out is not None and Path(state_out).is_dir():
        raise ValueError(f"--state-out {state_out}: is a folder, expected a file")
    det.warm_up()
    det.encoder.warm_up()
    lines = JsonLines(stdout)
    first = det.frames
    rows, skipped, lat_all, lat_det, cols = [], [], [], [], []
    t_run = time.perf_counter()
    for _, name, image, reason in stdin_frames(stdin if stdin is not None else sys.stdin):
        if image is None:
            skipped.append([name, reason])
            print(f"vpr loops: skipped {name}: {reason}", file=sys.stderr, flush=True)
            continue
        t0 = time.perf_counter()
        x = det.encoder.push(image)
        t1 = time.perf_counter()
        r = det.update_encoded(x, name)
        t2 = time.perf_counter()
        ms, ms_det = (t2 - t0) * 1e3, (t2 - t1) * 1e3
        lat_all.append(ms)
        lat_det.append(ms_det)
        lines.write({**r.as_dict(), "latency_ms": round(ms, 3)})
        rows.append([r.frame, name, r.best, r.earlier_name or "", round(r.score, 4), int(r.accepted), round(ms, 3),
                     round(ms_det, 3)])
        cols.append((r.earlier, r.scores))
    seconds = time.perf_counter() - t_run
    det.flush()
    if not rows:
        raise ValueError("vpr loops -: no readable frames on stdin")
    out.mkdir(parents=True, exist_ok=True)
    with io.atomic_open(out / "matches.csv", "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["frame", "name", "best_earlier", "earlier_name", "score", "accepted", "latency_ms",
                    "latency_detector_ms"])
        w.writerows(rows)
    metrics = {"frames": len(rows), "first_frame": first, "seconds": seconds,
               "latency_ms": {"with_encoding": latency_summary(lat_all), "without_encoding": latency_summary(lat_det)},
               "n_accepted": int(sum(r[5] for r in rows))}
    if gt.files:
        metrics.update(_metrics(det, rows, cols, gt, seconds))
    if state_out:
        det.save(state_out)
    report = {"metrics": metrics,
              "params": {"command": "loops", "seq": "-", "method": ONLINE_METHOD, "exclude": det.conf["exclude"],
                         "encoder": det.meta.get("encoder"), "encoder_conf": det.meta.get("encoder_conf"),
                         "detector_conf": det.conf, "skipped": skipped, "ground_truth": gt.describe()},
              "versions": versions()}
    io.save_json(out / "metrics.json", report)
    return report


def _metrics(det: LoopDetector, rows, cols, gt: GroundTruthSpec, seconds: float) -> dict:
    """The loop metrics of ``vpr loops`` over the frames of this run (numbered from 0 in the order they came)."""
    T = len(rows)
    first = rows[0][0]
    names = [r[1] for r in rows]
    hard, soft = build_loop_gt(gt, names, list(range(T)), total=T)
    exclude = det.conf["exclude"]
    mask = groundtruth.loop_closure_mask(T, exclude=exclude)
    if not (hard & mask).any():
        raise gt.no_match_error(exclude=exclude)
    idx, val, ptr = [], [], [0]
    for earlier, scores in cols:
        keep = (earlier >= first)  # candidates read in this run (a resumed detector knows older ones too)
        idx.append(earlier[keep] - first)
        val.append(scores[keep])
        ptr.append(ptr[-1] + int(keep.sum()))
    S = sp.csc_matrix((np.concatenate(val).astype(np.float32), np.concatenate(idx), ptr), shape=(T, T)).tocsr()
    best = np.array([r[2] - first if r[2] >= first else -1 for r in rows], np.int64)
    res = MatchResult(ONLINE_METHOD + "-online", S, best, np.array([r[4] for r in rows], np.float64),
                      np.array([bool(r[5]) for r in rows]), seconds, dict(det.conf))
    m, _ = method_metrics(res, hard, soft, mask=mask, loops=True)
    m.pop("seconds", None)
    return m
