"""The online frame loop of ``vpr localize`` and ``vpr loops -``: frames in as they come, one answer each.

:func:`run_online` reads a source's frames (a folder, a video, a bag, or
paths on stdin), times encoding and deciding, writes one flushed JSON line per
frame and, at the end, the outputs every command writes and the state
(``--state-out``). A stop (Ctrl-C, SIGTERM) waits for the frame being decided
(:func:`vpr.interrupts.deferred`); then the answers so far and the
state are written whole and the stop goes on (exit 130 / 143): ``--resume``
continues exactly where it stopped.
"""
from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from pipelines.outputs import claim_methods, merge_metrics, versions, write_method, write_ranked
from pipelines.report import write_report
from vpr import evaluate
from vpr.groundtruth import check_speeds
from vpr.interrupts import deferred
from vpr.report import metrics_table
from vpr.sources.stdin import SESSION
from vpr.types import Decision, MatchResult

__all__ = ["Online", "run_online", "latency_summary", "summary_line"]


class Online:
    """What an online command does with a frame; :func:`run_online` does the rest.

    ``top_k``: the candidates an answer keeps.
    """

    command = "online"
    #: the method that answers (its folder in the outputs)
    method: str = ""
    top_k: int | None = None
    #: (gt_hard, gt_soft, mask) of this run's frames, set by :meth:`evaluate` where there is ground truth
    ground_truth: tuple | None = None
    #: the job goes on from a saved state (``--resume``, or a map saved with ``--state-out``)
    resumed: bool = False
    #: the files the field's tools read (``top``, ``pairs``, ``mat`` of :func:`pipelines.outputs.write_ranked`), of
    #: the candidates :meth:`candidate_names`; None: none
    files: dict | None = None
    #: the N of Recall@N (:func:`vpr.evaluate.recall_at_n`)
    recall_at: tuple = evaluate.RECALL_AT

    def warm_up(self) -> None:
        """Compile kernels and load models now, so that the first frame's latency is its own."""

    def encode(self, image):
        raise NotImplementedError

    def answer(self, encoded, name: str) -> Decision | list[Decision] | None:
        """The frame's decision; or None while it waits (decided later, with another frame's, as a list)."""
        raise NotImplementedError

    def name_of(self, frame: int) -> str | None:
        """The name of a candidate frame."""
        raise NotImplementedError

    def candidate_names(self) -> list[str]:
        """The names of every candidate frame, in order (:attr:`files`)."""
        raise NotImplementedError

    def n_candidates(self) -> int:
        """The candidate frames the answers index (the rows of the similarity): a map's frames, or in loop closure
        every frame of the stream so far (those before a resume too)."""
        raise NotImplementedError

    def waiting_in_state(self) -> int:
        """Frames read before this run (a resumed state) whose answers are still to come; they come first."""
        return 0

    def waiting_name(self, frame: int) -> str | None:
        """The name of frame ``frame``, read before this run, answered in it (default: :meth:`name_of`, where the
        candidates are the stream's own frames)."""
        return self.name_of(frame)

    def new_session(self):
        """A line ``#session``: the next frame starts a new run (returns decisions of frames that waited)."""

    def finish(self):
        """The stream ended (not stopped): decide what still waits; returns decisions as :meth:`answer`."""

    def evaluate(self, result: MatchResult, names: list[str], indices: list[int], frames: np.ndarray) -> tuple:
        """(metrics, precision-recall curve or None) of the answers (``frames``: the frame numbers answered, the
        columns) against the ground truth (({}, None) without one); sets :attr:`ground_truth`."""
        return {}, None

    def save(self, path) -> None:
        raise NotImplementedError

    def resume_hint(self, path) -> str:
        """How the command goes on from the state saved at ``path`` (the stop message's words)."""
        return f"--resume {path}"

    def report_sources(self, src) -> tuple[list, list]:
        """The sources of the candidate frames and of the frames answered (``src``), for the report's pictures."""
        return [src], [src]

    def params(self) -> dict:
        """What ``metrics.json`` records under ``params`` (besides the command and the frames skipped)."""
        return {}

    def sampling(self) -> dict | None:
        """How frames were answered at another speed than they came (metrics.json's ``sampling``; None: as they
        came)."""
        return None


def latency_summary(ms) -> dict:
    """Median, 95th percentile and maximum of latencies (None without any)."""
    ms = np.asarray(ms, np.float64)
    if not ms.size:
        return {"median": None, "p95": None, "max": None}
    return {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)), "max": float(ms.max())}


def summary_line(report: dict, out, accepted: str | None = None) -> str:
    """What an online command prints on stderr at the end (its stdout holds a JSON line per frame): with ground
    truth the metrics table with Recall@N, as ``vpr match`` prints it; then a line of the frames, what was accepted
    and the latency (of the method the run's ``params`` name)."""
    if not report["methods"]:  # every frame read waits in the state (said when the input ended)
        return f"vpr {report['params']['command']}: {report['waiting']} frames wait in the state; nothing answered yet"
    m = report["methods"][report["params"]["method"]]
    lat = m["latency_ms"]
    what = f", {m['n_accepted']} {accepted}" if accepted else ""
    truth = report["params"].get("ground_truth") or {}
    unit = f"; ground truth {truth['tolerance_text']}" if truth.get("tolerance_text") else ""
    line = (f"vpr {report['params']['command']}: {m['frames']} frames{what}, latency median "
            f"{lat['with_encoding']['median']:.2f} ms ({lat['without_encoding']['median']:.2f} ms without encoding)"
            f"{unit}; wrote {out}/report.html and metrics.json")
    if "recall_at_1" not in m:  # no ground truth: nothing scored
        return line
    kind = "loops" if report["params"]["command"] == "loops" else "match"
    table = {report["params"]["method"]: m}
    return "\n".join([metrics_table(table, kind), line])


class _Lines:
    """One flushed JSON line per frame; a reader that goes away (``| head``) stops the lines, not the run."""

    def __init__(self, stream):
        self.stream, self.open = stream, True

    def write(self, obj: dict) -> None:
        if self.open:
            try:
                self.stream.write(json.dumps(obj) + "\n")
                self.stream.flush()
            except BrokenPipeError:  # keep going for the files
                self.open = False


def run_online(job: Online, src, out, stdout=None, state_out=None) -> dict:
    """Answer every frame of the source ``src`` with ``job``; write the outputs and the state; return metrics.json.

    The method's folder is claimed with the first frame (a second run of the
    method into ``out`` meanwhile is refused; a run refused before it writes nothing).
    """
    out = Path(out)
    before = out / job.method / "matches.csv"
    if job.resumed and before.is_file():
        raise ValueError(f"--out {out}: holds {job.method}'s answers of an earlier run ({before}); a resumed run "
                         "writes the frames it answers and would replace them: give it another --out")
    with contextlib.ExitStack() as claim:
        return _run(job, src, out, sys.stdout if stdout is None else stdout, state_out, claim)


def _run(job: Online, src, out: Path, stdout, state_out, claim: contextlib.ExitStack) -> dict:
    lines = _Lines(stdout)
    rows = []  # (name, source index, decision, ms, ms deciding)
    waiting: list[tuple] = []  # (name, index, ms, ms_dec) of frames whose answers come later, in order
    told = 0
    taken = None  # (input line, name) of the last frame or #session taken in whole: a stop goes on after it

    from_state = job.waiting_in_state()  # frames read before a restart, answered first: no entry in ``waiting``

    def answered(got) -> None:
        nonlocal from_state
        for d in ([] if got is None else [got] if isinstance(got, Decision) else got):
            if from_state:
                from_state -= 1
                name, index, ms, ms_dec = job.waiting_name(d.frame), -1, 0.0, 0.0
            else:
                name, index, ms, ms_dec = waiting.pop(0)
            if d.column is not None:  # the outputs keep each answer's top-K: held whole, a long run's grow as T^2
                d = dataclasses.replace(d, column=d.column.kept(job.top_k))
            rows.append((name, index, d, ms, ms_dec))
            lines.write({"query": int(d.frame), "query_name": name, "best_db": d.best if d.best >= 0 else None,
                         "db_name": job.name_of(d.best) if d.best >= 0 else None,
                         "score": round(d.score, 4) if np.isfinite(d.score) and d.best >= 0 else None,
                         "accepted": bool(d.accepted),
                         "latency_ms": round(ms, 3)})

    stop = None
    t_run = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # skipped frames are said here, one line each, and in metrics.json
            for f in src:
                for name, reason in src.skipped[told:]:
                    print(f"vpr {job.command}: skipped {name}: {reason}", file=sys.stderr, flush=True)
                told = len(src.skipped)
                if f is SESSION:
                    with deferred():
                        answered(job.new_session())
                        taken = (src.line, taken[1] if taken else None)
                    print(f"vpr {job.command}: #session{_line(src)}: the frames that follow are a new run (nothing "
                          "carries over but what was learned)", file=sys.stderr, flush=True)
                    continue
                if not rows and not waiting:
                    claim.enter_context(claim_methods(out, [job.method]))
                with deferred():  # a stop waits for this frame: the state is always that of whole frames
                    t0 = time.perf_counter()
                    x = job.encode(f.image)
                    t1 = time.perf_counter()
                    got = job.answer(x, f.name)
                    t2 = time.perf_counter()
                    waiting.append((f.name, f.index, (t2 - t0) * 1e3, (t2 - t1) * 1e3))
                    answered(got)
                    taken = (src.line, f.name)
            with deferred():
                answered(job.finish())
    except KeyboardInterrupt as e:  # Ctrl-C, and SIGTERM (vpr.interrupts.Terminated)
        stop = e
    seconds = time.perf_counter() - t_run
    for name, reason in src.skipped[told:]:
        print(f"vpr {job.command}: skipped {name}: {reason}", file=sys.stderr, flush=True)
    if stop is not None and (rows or waiting):
        print(_stopped(job, taken, [w[0] for w in waiting], state_out), file=sys.stderr, flush=True)
    elif waiting:  # the input ended with frames waiting in the state for the frames after them
        print(f"vpr {job.command}: {len(waiting)} frame{'s' if len(waiting) > 1 else ''} read ({waiting[0][0]} .. "
              f"{waiting[-1][0]}) wait in {state_out} for the frames after them, not yet in the outputs: to continue, "
              f"{job.resume_hint(state_out)} with another --out; their answers come first", file=sys.stderr,
              flush=True)
    if not rows:
        if waiting and state_out:  # every frame read waits for the frames after it: kept in the state alone
            with deferred():
                job.save(state_out)
            if stop is not None:
                raise stop
            return {"methods": {}, "params": {"command": job.command, "method": job.method}, "waiting": len(waiting)}
        if stop is not None:
            raise stop
        raise ValueError("no readable frames")
    with deferred():  # the outputs are written whole; a second signal stops at once
        report = _write(job, out, src, rows, [list(s) for s in src.skipped], seconds, state_out,
                        [w[0] for w in waiting], stop is not None)
    if stop is not None:
        raise stop
    return report


def _line(src) -> str:
    return f" (input line {src.line})" if src.line else ""


def _stopped(job: Online, taken: tuple | None, waiting: list[str], state_out) -> str:
    """What a stop leaves: the frames taken (``taken``: the input line and name of the last) are answered in the
    outputs, or wait in the state for the frames after them (a loop closure is decided a few frames late); a frame
    read as the stop came is not taken, and is fed again."""
    line, name = taken if taken is not None else (None, None)
    go_on = (f"feed it from input line {line + 1}" if line else f"feed it the frames after {name}" if name
             else "feed it every frame")
    upto = f" up to input line {line}" if line else f" up to {name}" if name else ""
    if not waiting:
        return f"vpr {job.command}: stopped; every frame{upto} is answered in the outputs" + (
            f"; to continue, {job.resume_hint(state_out)} with another --out and {go_on}" if state_out else "")
    which = f"{len(waiting)} frame{'s' if len(waiting) > 1 else ''} read ({waiting[0]} .. {waiting[-1]})"
    if not state_out:
        return f"vpr {job.command}: stopped; {which} wait for later frames and are not answered (no --state-out)"
    return (f"vpr {job.command}: stopped; {which} wait in {state_out} for later frames, not yet in the outputs: "
            f"to continue, {job.resume_hint(state_out)} with another --out and {go_on}; their answers come first")


def _write(job: Online, out: Path, src, rows, skipped, seconds, state_out, waiting: list[str], stopped: bool) -> dict:
    """The outputs of the frames answered; ``waiting``: the frames read and not yet answered (after a stop, or
    waiting in the state for the frames after them); ``stopped``: the run was stopped."""

    names = [r[0] for r in rows]
    ds = [r[2] for r in rows]
    T = len(ds)
    frames = np.array([d.frame for d in ds], np.int64)
    res = MatchResult.from_decisions(job.method, ds, job.n_candidates(), job.top_k, seconds)
    best, accepted = res.best, res.accepted
    lat_all, lat_dec = [r[3] for r in rows], [r[4] for r in rows]
    speed, sampling = evaluate.speed_metric(best, accepted), job.sampling()
    if sampling is None:
        check_speeds({job.method: speed})
    m = {"frames": T, "seconds": round(seconds, 4), "n_accepted": int(accepted.sum()), "stopped": stopped,
         "path_speed": speed, **({"sampling": sampling} if sampling else {}),
         **({"reversed_frames": res.reversed} if res.reversed else {}),
         "latency_ms": {"with_encoding": latency_summary(lat_all), "without_encoding": latency_summary(lat_dec)}}
    if waiting:
        m["waiting"] = waiting  # in the state (--state-out), answered after --resume
    scored, curve = job.evaluate(res, names, [r[1] for r in rows], frames)
    m.update(scored)
    m = write_method(out / job.method, res, (m, curve), None, names, job.ground_truth or (None, None, None),
                     title=f"{job.method}: {'loop closures' if job.command == 'loops' else 'the map x the query'}",
                     loops=job.command == "loops",
                     matches={"columns": {"latency_ms": [round(v, 3) for v in lat_all],
                                          "latency_decide_ms": [round(v, 3) for v in lat_dec]},
                              "best_names": [job.name_of(b) if b >= 0 else "" for b in best],
                              "query_ids": frames.tolist(), "name_of": job.name_of})[job.method]
    if job.files:  # the files the field's tools read
        write_ranked(out / job.method, res, job.candidate_names(), names, **job.files)
    if state_out:
        job.save(state_out)
    params = {"command": job.command, **job.params(), "skipped": skipped,
              "salvaged": {src.name: src.salvaged} if src.salvaged else None}
    params.setdefault("method_conf", {})
    # what makes two runs' results belong to one metrics.json (compared by merge_metrics)
    digest = hashlib.sha256("\n".join(names).encode("utf-8", "surrogateescape")).hexdigest()
    params["inputs"] = {"kind": job.command, "n_frames": T, "frames_sha256": digest}
    report = {"methods": {job.method: m}, "params": params, "versions": versions()}
    merged = merge_metrics(out, report, f"{job.command}: {job.method}")
    db_srcs, q_srcs = job.report_sources(src)
    write_report(out, db_srcs, q_srcs, kind="loops" if job.command == "loops" else "match")
    return merged
