"""Online localisation answered a few frames late, with the evidence of the frames after each one."""
from __future__ import annotations

import dataclasses
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from vpr import sdr as _sdr
from vpr.statefile import part_state
from vpr.types import Column, Decision, FollowingLocalizer, LateLocalizer

from .decide import PathDecider, refuse_stands
from .evidence import Engine, merge_columns
from .localizer import Localizer

__all__ = ["Lagged"]


@dataclass
class _Waiting:
    """A frame waiting for the ones after it: its active bits, its causal raw evidence per speed model, its decision
    at once, whether it moved, and whether a speed follower answered it from other maps (``followed``)."""

    bits: np.ndarray
    raw: list[tuple[np.ndarray, np.ndarray, int]]
    decision: Decision
    unmoved: bool
    followed: bool


class Lagged(LateLocalizer):
    """Answers each query frame ``lag`` frames late: its evidence is the causal one plus a backward pass from the
    ``lag``-th frame after it, the two added as the batch evidence of both directions adds them
    (:meth:`vpr.shosm.Engine.run`), decided by the map's path rule (:class:`PathDecider`). A frame is accepted where
    that rule accepts its path on its own frame or on one of the frames waiting after it
    (:meth:`PathDecider.accepted_ahead`), except within :attr:`memory_frames` after a query frame that did not move
    and on which no path was accepted (there on its own score only).

    ``base``: the map's :class:`Localizer`, stepped on every frame (it reads the direction of the query and the stands
    at once); ``answering``: what answers each frame at once (``base``, or a speed follower over it: a frame it
    answered from other maps keeps that answer, late). :meth:`update` returns the decisions that are due (none for
    the first ``lag`` frames of a traverse); :meth:`flush` the rest, each with the frames there are after it.
    ``lag`` 0: every frame answered at once, as ``answering`` does.
    """

    def __init__(self, base: Localizer, answering=None, lag: int = 0):
        self.base, self.answering, self.lag = base, answering or base, int(lag)
        #: the speed follower that answers at once, if any (a frame it answered from other maps keeps that answer)
        self.follower = self.answering if isinstance(self.answering, FollowingLocalizer) else None
        if self.lag < 0:
            raise ValueError(f"lag must be >= 0, got {lag}")
        graph = base.lanes[0].graph
        seq = base.seq
        # the backward pass: the frames from the last one back, along the map's transitions reversed; the frame's
        # own overlap taken out once of the two passes' sum (the causal pass keeps it)
        self.backward = [Engine(graph, lane, seq.beam, base.exact, reverse=True, z_weight=1.0)
                         for lane in seq.evidence.split()]
        self.decider = PathDecider(seq.path(), base.sessions)
        self.waiting: list[_Waiting] = []
        #: frames over which the evidence forgets (``1 / (1 - decay)``): a frame this close after a query stand on
        #: which no path was accepted carries the evidence that ran on alone during it
        self.memory_frames = int(round(1.0 / (1.0 - float(seq.evidence.decay))))
        self.settling = self.memory_frames  # frames decided since the last of such a stand
        self._worker: ThreadPoolExecutor | None = None  # the thread of the backward passes

    def warm_up(self) -> None:
        self.answering.warm_up()
        header, arrays = self.backward[0].state()
        self.backward[0].step(np.zeros(0, np.int64))
        self.backward[0].load_state(header, arrays)

    def update(self, sdr_row) -> list[Decision]:
        """Localise the next query frame; returns the decisions now due (the frame ``lag`` frames before).

        The due frame's backward pass (from this frame back to it) runs on a second thread while this frame is
        localised at once: the two read the map and nothing of each other."""
        if not self.lag:
            return [self.answering.update(sdr_row)]
        b = self.base
        window = None
        if len(self.waiting) >= self.lag:
            bits = _sdr.row_bits(sdr_row, b.memory.n_inputs, name="query SDR")
            window = self._pool().submit(self._backward, [bits, *(w.bits for w in self.waiting[:self.lag][::-1])])
        try:
            d = self.answering.update(sdr_row)
        finally:
            backs = window.result() if window is not None else None
        followed = self.follower is not None and self.follower.mode != 0
        s = b.last  # what the map's localizer made of this frame (its own answer: ``d``, or the follower's)
        self.waiting.append(_Waiting(s.bits, list(s.raw), d, s.unmoved, followed))
        return [self._decide(backs)] if len(self.waiting) > self.lag else []

    def _pool(self) -> ThreadPoolExecutor:
        if self._worker is None:
            self._worker = ThreadPoolExecutor(1, thread_name_prefix="vpr-late")
        return self._worker

    def _backward(self, frames: list[np.ndarray]) -> list[list[tuple]]:
        """The backward pass over ``frames`` (from the last one back to the oldest waiting): per frame, its raw
        evidence per speed model."""
        backs = [[] for _ in frames]
        for engine in self.backward:
            engine.reset()
            for i, got in enumerate(engine.steps_raw(frames)):
                backs[i].append(got)
        return backs

    def flush(self) -> list[Decision]:
        """The decisions of the frames still waiting (the traverse ended), each with the frames after it."""
        out = []
        while self.waiting:
            out.append(self._decide())
        return out

    def reset(self) -> list[Decision]:
        """A new query traverse: the frames waiting are decided first (returned), then nothing carries over."""
        out = self.flush()
        self.answering.reset()
        self.decider.new_session()
        self.settling = self.memory_frames
        return out

    def _decide(self, backs=None) -> Decision:
        """The late decision of the oldest waiting frame (taken out of :attr:`waiting`); ``backs``: its backward
        pass (:meth:`_backward`) where already run."""
        w = self.waiting.pop(0)
        after = [w, *self.waiting[:self.lag]][::-1]  # from the last frame there is back to this one
        if backs is None:  # per frame, from the last back to this one: its backward raw per speed model
            backs = self._backward([x.bits for x in after])

        def column(i: int):  # frame ``after[i]``'s evidence of both directions, its speed models merged
            x = after[i]
            return merge_columns([e.column(*_added(r[:2], back), r[2], x.decision.frame)
                                  for e, r, back in zip(self.backward, x.raw, backs[i], strict=True)])

        late = self.decider.decide(column(-1))
        # a query stand on which no path was accepted: the evidence ran on alone, ahead of the query
        self.settling = 0 if w.unmoved and not late.accepted else self.settling + 1
        settled = self.settling >= self.memory_frames
        if w.followed:  # answered from another map or as another query: that answer stands
            return w.decision
        b = self.base
        # not refused, then accepted on its own path score or (settled) on the frames after it; refused where the map's
        # localizer refuses now, with the frames after this one read (the direction over the newest frames: the first
        # frames of a query take the reading of the frames after them, as the batch's direction check reads them)
        ahead = (column(i) for i in range(len(after) - 2, -1, -1))
        refusing = b.last is None or b.last.refusing
        ok = not refusing and refuse_stands(late.best, True, b.standing, w.unmoved) \
            and (late.accepted or settled and self.decider.accepted_ahead(ahead))
        return dataclasses.replace(late, accepted=bool(ok), reversed=w.decision.reversed, frame=w.decision.frame)

    # ------------------------------------------------------------ state
    def state(self) -> tuple[dict, dict]:
        """(header, arrays) of the frames waiting and the late path rule (:meth:`load_state`)."""
        dh, da = self.decider.state()
        ws = self.waiting
        header = {"lag": self.lag, "decider": dh, "n_waiting": len(ws), "lanes": len(self.backward),
                  "settling": self.settling,
                  "waiting": [[int(w.decision.frame), int(w.decision.best), float(w.decision.score),
                               bool(w.decision.accepted), float(w.decision.margin), bool(w.decision.reversed),
                               bool(w.unmoved), bool(w.followed)] for w in ws]}
        arrays = {**{f"decider_{k}": v for k, v in da.items()}, **_ragged("bits", [w.bits for w in ws])}
        for j in range(len(self.backward)):
            arrays.update(_ragged(f"rows{j}", [w.raw[j][0] for w in ws]))
            arrays.update(_ragged(f"val{j}", [w.raw[j][1] for w in ws]))
            arrays[f"n{j}"] = np.array([w.raw[j][2] for w in ws], np.int64)
        cols = [w.decision.column for w in ws]
        arrays.update(_ragged("crows", [c.rows if c is not None else np.zeros(0, np.int64) for c in cols]))
        arrays.update(_ragged("cz", [c.z if c is not None else np.zeros(0, np.float32) for c in cols]))
        arrays["cfill"] = np.array([c.fill if c is not None else np.nan for c in cols], np.float64)
        arrays["cn"] = np.array([c.n if c is not None else -1 for c in cols], np.int64)
        return header, arrays

    def load_state(self, header: dict, arrays: dict) -> Lagged:
        """Continue from a :meth:`state` of a :class:`Lagged` of the same lag and speed models."""
        if int(header["lag"]) != self.lag or int(header["lanes"]) != len(self.backward):
            raise ValueError(f"the state answers {header['lag']} frames late over {header['lanes']} speed models; "
                             f"this localizer {self.lag} over {len(self.backward)}")
        self.decider.load_state(*part_state(header, arrays, "decider"))
        n = int(header["n_waiting"])
        bits = _unragged(arrays, "bits", n)
        raws = [list(zip(_unragged(arrays, f"rows{j}", n), _unragged(arrays, f"val{j}", n),
                         (int(v) for v in arrays[f"n{j}"]), strict=True)) for j in range(len(self.backward))]
        crows, cz = _unragged(arrays, "crows", n), _unragged(arrays, "cz", n)
        self.settling = int(header["settling"])
        self.waiting = []
        for i, (frame, best, score, accepted, margin, rev, unmoved, followed) in enumerate(header["waiting"]):
            cn = int(arrays["cn"][i])
            col = None if cn < 0 else Column(crows[i].astype(np.int64), cz[i].astype(np.float32),
                                              float(arrays["cfill"][i]), cn, int(frame))
            d = Decision(int(best), float(score), bool(accepted), float(margin), int(frame), col, bool(rev))
            self.waiting.append(_Waiting(bits[i].astype(np.int64), [r[i] for r in raws], d, bool(unmoved),
                                         bool(followed)))
        return self


def _added(a, b) -> tuple[np.ndarray, np.ndarray]:
    """Two sparse columns (rows, values) added; a row one lacks scores 0 there."""
    rows = np.union1d(a[0], b[0])
    val = np.zeros(rows.size, np.float64)
    for r, v in (a, b):
        val[np.searchsorted(rows, r)] += v
    return rows, val


def _ragged(name: str, parts: list[np.ndarray]) -> dict:
    return {f"{name}_sizes": np.array([p.size for p in parts], np.int64),
            f"{name}_data": np.concatenate(parts) if parts else np.zeros(0)}


def _unragged(arrays: dict, name: str, n: int) -> list[np.ndarray]:
    sizes = np.asarray(arrays[f"{name}_sizes"], np.int64)
    if sizes.size != n:
        raise ValueError(f"the state holds {sizes.size} waiting frames' {name}, not {n}")
    return np.split(np.asarray(arrays[f"{name}_data"]), np.cumsum(sizes)[:-1]) if n else []
