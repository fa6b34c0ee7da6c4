"""The online frame loop of ``vpr localize`` and ``vpr loops -``: frames in as they come, one answer each.

Both commands run :func:`run_online` with an :class:`Online` (what encodes
and decides a frame, and what the answers are evaluated against): it reads
the frames (a source, or image paths on stdin, :func:`stdin_frames`), times
encoding and deciding, writes one flushed JSON line per frame and, at the
end, the run's outputs in the schema of every command (``METHOD/matches.csv``
and ``metrics.json``, :mod:`pipelines.outputs`) and the state (``--state-out``).

A stop (Ctrl-C, SIGTERM) is acted on between frames: a frame being decided
is finished first (:func:`pipelines.interrupts.deferred`), so the state is
that of the frames answered. Then the outputs of the frames answered so far
and the state are written, whole (atomic writes), and the stop goes on to the
command line (``vpr: interrupted``, 130; ``vpr: terminated``, 143): a robot
that is stopped keeps what it decided and its map, and ``--resume`` continues
exactly where it stopped.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipelines.interrupts import deferred
from pipelines.outputs import claim_methods, merge_metrics, versions, write_matches
from vpr.sources import decode_image
from vpr.types import MatchResult

__all__ = ["Online", "Answer", "run_online", "stdin_frames", "source_frames", "latency_summary", "JsonLines",
           "summary_line"]


@dataclass
class Answer:
    """One frame's answer, the same fields in every online command.

    ``query``: the frame's number (counted over a resumed run's earlier
    frames too); ``best``: the database (or earlier) frame, -1 for none;
    ``best_name`` its name; ``score``: the decision's statistic (None: no
    evidence); ``candidates`` / ``scores``: the frames with the most evidence
    and their scores (a column of the similarity).
    """

    query: int
    best: int
    best_name: str | None
    score: float | None
    accepted: bool
    candidates: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    scores: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    #: the frame's name, where the answer may come in a later run (a frame that waited when the run stopped)
    query_name: str | None = None


class Online:
    """What an online command does with a frame; :func:`run_online` does the rest.

    Subclasses set ``command`` and ``method`` and implement :meth:`encode`
    (timed as encoding), :meth:`decide`, :meth:`evaluate` and :meth:`save`.
    ``row_offset``: the number of the first candidate frame this run's
    metrics are over (a map's first frame, 0; in loop closure, the first frame
    of this run: a resumed detector also names frames from before it).
    """

    command = "online"
    method = "rshosm-seq"
    row_offset = 0

    def warm_up(self) -> None:
        """Compile kernels and load models now, so that the first frame's latency is its own."""

    def encode(self, image):
        raise NotImplementedError

    def decide(self, encoded, name: str) -> Answer | list[Answer] | None:
        """The frame's answer; or None while it waits (answered later, with another frame's, as a list)."""
        raise NotImplementedError

    def new_session(self):
        """A line ``#session`` on stdin: the next frame starts a new run of the robot (returns answers of frames
        that waited, as :meth:`decide`)."""

    def finish(self):
        """The stream ended (not stopped): decide what still waits (e.g. frames in a causal encoder); returns
        their answers as :meth:`decide`."""

    def evaluate(self, result: MatchResult, names: list[str], indices: list[int]) -> dict:
        """Metrics of the answers against the ground truth ({} without one)."""
        return {}

    def save(self, path) -> None:
        """Write the state (``--state-out``)."""
        raise NotImplementedError

    def params(self) -> dict:
        """What ``metrics.json`` records under ``params`` (besides the command and the frames skipped)."""
        return {}


# ----------------------------------------------------------------- frames
#: What :func:`stdin_frames` yields for a line ``#session``: the next frame starts a new session.
SESSION = (-2, "#session", None, "session")

#: A line longer than this is not a path (Linux's PATH_MAX).
_MAX_PATH = 4096


def _garbage(raw: bytes) -> str | None:
    """Why a line of stdin is not a path (None: it may be one)."""
    if b"\0" in raw:
        return "not a path (a NUL byte)"
    if len(raw) > _MAX_PATH:
        return f"not a path (over {_MAX_PATH} bytes)"
    if any(c < 32 and c != 9 for c in raw):
        return "not a path (control characters)"
    try:
        raw.decode("utf-8")
    except UnicodeDecodeError:
        if not os.path.exists(os.fsdecode(raw)):  # a real file may have a name that is not UTF-8
            return "not a path (not UTF-8 text, and no such file)"
    return None


def _lines(stream):
    """Byte lines of ``stream`` as they arrive (a text stream without a byte buffer is encoded back)."""
    buf = getattr(stream, "buffer", None)
    if buf is not None:
        yield from buf
        return
    for line in stream:
        yield line.encode("utf-8", "surrogateescape")


def stdin_frames(stream, what: str = "stdin"):
    """(index, name, image, reason) of the image paths read from ``stream`` as they arrive.

    Unreadable images come with ``image`` None and the reason; blank lines
    and ``#`` comments are skipped, but for ``#session``, which comes as
    :data:`SESSION` (a new run of the robot starts); a line that cannot be a path (a NUL byte,
    control characters, binary garbage) comes as ``stdin line N`` with the
    reason. Binary data where the first path should be (an image piped in
    instead of its path) is refused: ValueError naming ``what``.
    """
    index = 0
    seen_path = False
    for lineno, raw in enumerate(_lines(stream), start=1):
        raw = raw.rstrip(b"\r\n")
        text = raw.strip()
        if text == b"#session":
            yield SESSION
            continue
        if not text or text.startswith(b"#"):
            continue
        why = _garbage(text)
        if why is not None:
            if not seen_path:
                raise ValueError(f"{what}: binary data, not image paths one per line (line {lineno}: {why})")
            yield -1, f"{what} line {lineno}", None, why
            continue
        seen_path = True
        name = os.fsdecode(text)
        img, reason = decode_image(Path(name))
        yield index, name, img, ("" if img is not None else reason)
        index += 1


def source_frames(src):
    """(index, name, image, reason) of a source's frames; its skipped frames last, with index -1."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # skipped frames are reported in metrics.json
        for f in src:
            yield f.index, f.name, f.image, ""
    for name, reason in src.skipped:
        yield -1, name, None, reason


def latency_summary(ms) -> dict:
    """Median, 95th percentile and maximum of latencies (None without any)."""
    ms = np.asarray(ms, np.float64)
    if not ms.size:
        return {"median": None, "p95": None, "max": None}
    return {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)), "max": float(ms.max())}


def summary_line(report: dict, method: str, out, accepted: str | None = None) -> str:
    """The line an online command prints on stderr at the end: frames, what was accepted, the latency."""
    m = report["methods"][method]
    lat = m["latency_ms"]
    what = f", {m['n_accepted']} {accepted}" if accepted else ""
    return (f"vpr {report['params']['command']}: {m['frames']} frames{what}, latency median "
            f"{lat['with_encoding']['median']:.2f} ms ({lat['without_encoding']['median']:.2f} ms without encoding); "
            f"wrote {out}/metrics.json")


class JsonLines:
    """One flushed JSON line per frame; a reader that goes away (``| head``) stops the lines, not the run."""

    def __init__(self, stream):
        self.stream = stream
        self.open = True

    def write(self, obj: dict) -> None:
        if not self.open:
            return
        try:
            self.stream.write(json.dumps(obj) + "\n")
            self.stream.flush()
        except BrokenPipeError:  # keep going for the files
            self.open = False


# ----------------------------------------------------------------- the loop
def run_online(job: Online, frames, out, stdout=None, state_out=None, n_rows: int | None = None) -> dict:
    """Answer every frame of ``frames`` with ``job``; write the outputs and the state; return metrics.json's content.

    ``frames``: (index, name, image, reason) tuples (:func:`stdin_frames`,
    :func:`source_frames`). ``n_rows``: the number of rows of the similarity
    the candidates index (the map's frames; None: the frames of this run, as
    in loop closure). On a stop the outputs of the frames answered so far are
    written and the stop raised again (see the module docstring). The
    method's folder is claimed with the first frame (a second run of the same
    method into ``out`` meanwhile is refused; a run refused before it writes
    nothing).
    """
    with contextlib.ExitStack() as claim:
        return _run(job, frames, Path(out), sys.stdout if stdout is None else stdout, state_out, n_rows, claim)


def _run(job: Online, frames, out: Path, stdout, state_out, n_rows, claim: contextlib.ExitStack) -> dict:
    lines = JsonLines(stdout)
    names, indices, answers, lat_all, lat_dec, skipped = [], [], [], [], [], []
    waiting: list[tuple] = []  # (name, index, ms, ms_dec) of frames whose answers come later, in order

    def answered(got) -> None:
        for a in ([] if got is None else [got] if isinstance(got, Answer) else got):
            # a frame pushed before a restart (it waited in the saved state) has no entry here
            name, index, ms, ms_dec = waiting.pop(0) if waiting else (a.query_name or f"frame {a.query}", -1, 0.0, 0.0)
            names.append(name)
            indices.append(index)
            answers.append(a)
            lat_all.append(ms)
            lat_dec.append(ms_dec)
            lines.write({"query": a.query, "query_name": name, "best_db": a.best if a.best >= 0 else None,
                         "db_name": a.best_name, "score": a.score, "accepted": a.accepted,
                         "latency_ms": round(ms, 3)})

    stop = None
    t_run = time.perf_counter()
    try:
        for index, name, image, reason in frames:
            if (index, name) == SESSION[:2]:
                with deferred():
                    answered(job.new_session())
                continue
            if image is None:
                skipped.append([name, reason])
                print(f"vpr {job.command}: skipped {name}: {reason}", file=sys.stderr, flush=True)
                continue
            if not answers and not waiting:
                claim.enter_context(claim_methods(out, [job.method]))
            with deferred():  # a stop waits for this frame: the state is always that of whole frames
                t0 = time.perf_counter()
                x = job.encode(image)
                t1 = time.perf_counter()
                got = job.decide(x, name)
                t2 = time.perf_counter()
                waiting.append((name, index, (t2 - t0) * 1e3, (t2 - t1) * 1e3))
                answered(got)
        with deferred():
            answered(job.finish())
    except KeyboardInterrupt as e:  # Ctrl-C, and SIGTERM (pipelines.interrupts.Terminated)
        stop = e
    seconds = time.perf_counter() - t_run
    if not answers:
        if stop is not None:
            raise stop
        raise ValueError(f"vpr {job.command}: no readable frames")
    with deferred():  # the outputs are written whole; a second signal stops at once
        report = _write(job, out, names, indices, answers, lat_all, lat_dec, skipped, seconds, n_rows, state_out,
                        stopped=stop is not None)
    if stop is not None:
        raise stop
    return report


def _write(job: Online, out: Path, names, indices, answers, lat_all, lat_dec, skipped, seconds, n_rows, state_out,
           stopped: bool) -> dict:
    import scipy.sparse as sp

    T = len(answers)
    rows = T if n_rows is None else int(n_rows)
    off = job.row_offset
    best = np.array([a.best - off if a.best >= off else -1 for a in answers], np.int64)
    score = np.array([np.nan if a.score is None else a.score for a in answers], np.float64)
    score = np.where(np.isfinite(score), score, -np.inf)
    accepted = np.array([a.accepted for a in answers], bool)
    keep = [a.candidates >= off for a in answers]  # candidates of this run's frames (and the map's)
    ptr = np.r_[0, np.cumsum([k.sum() for k in keep])]
    S = sp.csc_matrix((np.concatenate([a.scores[k] for a, k in zip(answers, keep, strict=True)]).astype(np.float32),
                       np.concatenate([a.candidates[k] - off for a, k in zip(answers, keep, strict=True)]),
                       ptr), shape=(rows, T)).tocsr()
    res = MatchResult(job.method, S, best, score, accepted, seconds, {})
    shown = MatchResult(job.method, S, np.array([a.best for a in answers], np.int64), score, accepted, seconds, {})
    write_matches(out / job.method, shown, None, names, {"latency_ms": [round(v, 3) for v in lat_all],
                                                         "latency_decide_ms": [round(v, 3) for v in lat_dec]},
                  best_names=[a.best_name or "" for a in answers], query_ids=[a.query for a in answers])
    m = {"frames": T, "seconds": round(seconds, 4), "n_accepted": int(accepted.sum()), "stopped": stopped,
         "latency_ms": {"with_encoding": latency_summary(lat_all), "without_encoding": latency_summary(lat_dec)}}
    m.update(job.evaluate(res, names, indices))
    if state_out:
        job.save(state_out)
    params = {"command": job.command, **job.params(), "skipped": skipped}
    params.setdefault("method_conf", {})
    # what makes two runs' results belong to one metrics.json (compared by merge_metrics)
    digest = hashlib.sha256("\n".join(names).encode("utf-8", "surrogateescape")).hexdigest()
    params["inputs"] = {"kind": job.command, "n_frames": T, "frames_sha256": digest}
    report = {"methods": {job.method: m}, "params": params, "versions": versions()}
    return merge_metrics(out, report, f"{job.command}: {job.method}")
