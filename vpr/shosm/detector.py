"""Online loop closure for a robot: one frame in, "I have been here before, at frame i" (or not) out.

**Our extension, not the paper's** decision (the memory is the paper's
Algorithm 1, learned as frames arrive). :class:`LoopDetector` runs the same
engine as the batch :func:`vpr.shosm.loop_evidence` (``vpr loops``),
:class:`vpr.shosm.LoopStream`, so its answers are the batch's on the same
frames; it adds frame names, an optional encoder for images, and
:meth:`LoopDetector.save` / :meth:`LoopDetector.load` so that a robot can stop
and continue with the answers it would have given without stopping.

The cost of a frame grows only with what the memory must search: the beam of
the frames that still carry evidence, capped from frame
:data:`vpr.shosm.LOOP_UNCAPPED_MAX` on (``docs/loops.md`` has the latency).

Encoding images is the caller's: ``vpr`` never imports ``encoders``. An
``encoder`` passed in is any object with ``push(image)`` returning the SDR
rows of the frames now ready (and optionally ``delay``, ``waiting``,
``flush()``, ``state()``, ``load_state(arrays)``), as
:class:`encoders.stream.StreamEncoder`.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from vpr.checks import check_int

from .conf import LOOP_EXCLUDE, RshosmSeqConf
from .loops import LoopStream
from .state import load_state, save_state

__all__ = ["LoopDetector", "LoopResult"]

_FORMAT = "vpr.LoopDetector"
_FORMAT_VERSION = 1


@dataclass
class LoopResult:
    """The answer for one frame.

    ``best``: the earlier frame it most likely revisits (-1, ``earlier_name``
    None: no candidate yet); ``score``: the path score of
    :class:`vpr.shosm.LoopConf` (0: a new place); ``accepted``: a loop
    closure; ``margin``: how far the best place stood out this frame;
    ``earlier`` / ``scores``: the ``top_k`` earlier frames with the most
    evidence and their z-scores, best first.
    """

    frame: int
    name: str | None
    best: int
    earlier_name: str | None
    score: float
    accepted: bool
    margin: float
    earlier: np.ndarray
    scores: np.ndarray

    def as_dict(self) -> dict:
        """JSON-ready fields (``best`` as ``best_earlier``, None without a candidate)."""
        return {"frame": self.frame, "name": self.name, "best_earlier": self.best if self.best >= 0 else None,
                "earlier_name": self.earlier_name, "score": round(self.score, 4), "accepted": self.accepted}


def _is_sdr(x) -> bool:
    if sp.issparse(x):
        return True
    a = np.asarray(x)
    return a.dtype == bool or (a.ndim == 1 and a.dtype.kind in "iu")


class LoopDetector:
    """Loop closure within one stream, learned online, one frame at a time.

    Parameters
    ----------
    encoder : object, optional
        Encodes images passed to :meth:`update` (see the module docstring).
        Without it, :meth:`update` takes SDR rows.
    conf : RshosmSeqConf, optional
        rSHOSM-seq's conf (the ``rshosm-seq`` method's, ``method.seq``; its
        ``top_k``: the earlier frames reported per frame,
        :attr:`LoopResult.earlier`); ``**flat`` keys over it
        (:meth:`RshosmSeqConf.of`). The same conf gives ``vpr loops``'s answers.
    exclude : int >= 1
        Frames closer than this are not candidates.

    Attributes
    ----------
    frames : int
        Frames seen (given to :meth:`update`).
    names : list of str
        Their names (``frame <i>`` when none was given).
    meta : dict
        Caller metadata stored by :meth:`save` (``vpr loops -`` keeps the encoder there).
    """

    def __init__(self, encoder=None, conf: RshosmSeqConf | None = None, exclude: int = LOOP_EXCLUDE, **flat):
        self.seq = RshosmSeqConf.of(conf, **flat)
        exclude = check_int(exclude, "LoopDetector: exclude", 1)
        delay = int(getattr(encoder, "delay", 0) or 0)
        if exclude <= delay:
            raise ValueError(f"LoopDetector: exclude {exclude} must exceed the encoder's delay of {delay} frames "
                             "(its first frames wait for each other; they must not be candidates of each other)")
        self.exclude = exclude
        #: the whole conf, the decision's defaults filled in, and ``exclude`` (recorded in metrics.json)
        self.conf = {**self.seq.resolved("loops"), "exclude": exclude}
        self.encoder = encoder
        self._stream = LoopStream(exclude, self.seq)
        self.names: list[str] = []
        self.meta: dict = {}
        #: answers of earlier frames decided late (:meth:`take_late`)
        self._late: list[LoopResult] = []

    @property
    def frames(self) -> int:
        return len(self.names)

    @property
    def stream(self) -> LoopStream:
        """The engine (read it, do not step it: the detector's frame count would be off)."""
        return self._stream

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) the kernels now, so that the first frame's latency is its own."""
        tiny = LoopStream(1, self.seq.replace(n_inputs=64))
        for bits in ([0, 1, 2, 3], [4, 5, 6, 7], [0, 1, 2, 3]):
            tiny.step(np.array(bits, np.int64))

    def update(self, frame_or_sdr, name: str | None = None) -> LoopResult:
        """Learn the next frame and decide it: a loop closure onto an earlier frame, or a new place.

        ``frame_or_sdr``: an SDR row (1-row sparse matrix, bool vector or bit
        indices) or, with an encoder, an image (H x W or H x W x 3 array).
        """
        j = self.frames
        label = str(name) if name is not None else f"frame {j}"
        if _is_sdr(frame_or_sdr):
            if getattr(self.encoder, "waiting", 0):
                raise ValueError(f"{label}: an SDR while the encoder holds frames waiting for their SDRs; give "
                                 "images or SDRs, not both")
            f = self._stream.step(frame_or_sdr)
            self.names.append(label)
            return self._result(j, f)
        if self.encoder is None:
            raise ValueError(f"{label}: got an image ({np.asarray(frame_or_sdr).shape}) but the LoopDetector has no "
                             "encoder: pass SDR rows, or LoopDetector(encoder=...)")
        return self.update_encoded(self.encoder.push(frame_or_sdr), name)

    def update_encoded(self, rows, name: str | None = None) -> LoopResult | None:
        """The next frame, given what the encoder's ``push`` returned for it (the SDR rows of the frames now ready).

        :meth:`update` with an image is ``update_encoded(encoder.push(image))``;
        separate, so that a caller can time encoding and deciding apart. None
        when the frame's answer is not known yet: the first frames of a later
        session wait in a causal encoder for their statistics, and every frame
        of the earlier sessions is their candidate; their answers come with
        :meth:`take_late` once decided. (In the first session a waiting frame
        has no candidate, so its answer is known at once.)
        """
        j = self.frames
        self.names.append(str(name) if name is not None else f"frame {j}")
        return self._learn(sp.csr_matrix(rows), j)

    def new_session(self) -> None:
        """The next frame starts a new run of the robot (a session): what was learned stays, closures onto earlier
        sessions count, and nothing of the last frame carries over (:meth:`vpr.shosm.LoopStream.new_session`);
        frames still waiting in the encoder are decided first, and its causal window starts again."""
        if self.encoder is not None and hasattr(self.encoder, "new_session"):
            self._release(sp.csr_matrix(self.encoder.new_session()))
        self._stream.new_session()

    def take_late(self) -> list[LoopResult]:
        """The answers of earlier frames decided since the last call (frames that waited in the encoder)."""
        out, self._late = self._late, []
        return out

    def flush(self) -> None:
        """Learn the frames still waiting for their SDRs (a stream that ends before the encoder's delay)."""
        if self.encoder is not None and hasattr(self.encoder, "flush"):
            self._release(sp.csr_matrix(self.encoder.flush()))

    def _release(self, rows: sp.csr_matrix) -> None:
        """Decide the frames that waited in the encoder (the last ``rows.shape[0]`` frames pushed)."""
        if not rows.shape[0]:
            return
        r = self._learn(rows, self.frames - 1)
        if r is not None and self._stream.starts[-1] > 0:  # in a later session its answer was not given yet
            self._late.append(r)

    def _learn(self, rows: sp.csr_matrix, j: int) -> LoopResult | None:
        first = self._stream.frames
        later_session = self._stream.starts[-1] > 0
        last = None
        for r in range(rows.shape[0]):
            last = self._stream.step(rows.indices[rows.indptr[r]:rows.indptr[r + 1]])
            if first + r < j:
                if later_session:  # a frame that waited, with the earlier sessions as candidates: answered now
                    self._late.append(self._result(first + r, last))
                elif last.n_candidates:  # pragma: no cover - guarded by exclude > delay
                    raise RuntimeError("a frame decided late had candidates")
        if self._stream.frames == j + 1 and last is not None:
            return self._result(j, last)
        if j < 0 or later_session:
            return None  # answered later (take_late)
        # the frame waits for its SDR; it has no candidate yet (exclude > delay), so its answer is known
        none = np.zeros(0, np.int64)
        return LoopResult(j, self.names[j], -1, None, 0.0, False, 0.0, none, none.astype(np.float32))

    def _result(self, j: int, f) -> LoopResult:
        b = int(f.best)
        keep = np.lexsort((f.rows, -f.z))[: self.seq.top_k]
        return LoopResult(j, self.names[j], b, self.names[b] if b >= 0 else None, float(f.score), bool(f.accepted),
                          float(f.margin), f.rows[keep].astype(np.int64), f.z[keep])

    # ------------------------------------------------------------ files
    def save(self, path) -> Path:
        """Write the memory, the evidence and decision state, the names and the encoder's state (atomic ``.npz``)."""
        header, arrays = self._stream.state_dict()
        parts = {"s": arrays, "enc": self.encoder.state() if hasattr(self.encoder, "state") else {}}
        return save_state(path, _FORMAT, _FORMAT_VERSION,
                          {"conf": {**self.seq.flat(), "exclude": self.exclude}, "stream": header, "meta": self.meta},
                          parts, names=self.names)

    @classmethod
    def load(cls, path, encoder=None) -> LoopDetector:
        """Read a file written by :meth:`save`; the detector continues where it was saved.

        ``encoder``: a fresh encoder of the kind used before the restart (its
        state is restored from the file); ``meta`` says which one it was.

        Raises
        ------
        MemoryFileError
            Missing, corrupt or foreign file, or an unsupported format version.
        """
        with load_state(path, _FORMAT, _FORMAT_VERSION, "loop detector",
                        " (written by LoopDetector.save / `vpr loops - --state-out`)", ("s", "enc")) as \
                (header, parts, names):
            conf = dict(header["conf"])
            exclude = conf.pop("exclude")
            det = cls(encoder, exclude=exclude, **conf)
            det._stream = LoopStream.from_state(header["stream"], parts["s"])
            det.names = names
            if len(det.names) < det._stream.frames:
                raise ValueError(f"{len(det.names)} names for {det._stream.frames} frames")
            if encoder is not None and parts["enc"] and hasattr(encoder, "load_state"):
                encoder.load_state(parts["enc"])
            det.meta = header.get("meta", {})
        return det

    def __repr__(self) -> str:
        return f"LoopDetector(frames={self.frames}, exclude={self.exclude}, memory={self._stream.mem!r})"
