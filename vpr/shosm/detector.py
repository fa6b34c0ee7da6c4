"""Online loop closure for a robot: one frame in, "I have been here before, at frame i" (or not) out."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.sparse as sp

from vpr.checks import check_int
from vpr.statefile import MemoryFileError, read_file, write_file
from vpr.types import Decision, FrameEncoder, StreamDetector

from .conf import LOOP_EXCLUDE, RshosmSeqConf
from .confirm import warm_up as warm_up_confirmation
from .loops import LoopStream

__all__ = ["LoopDetector"]

_FORMAT = "vpr.LoopDetector"
_FORMAT_VERSION = 6


def _is_sdr(x) -> bool:
    if sp.issparse(x):
        return True
    a = np.asarray(x)
    return a.dtype == bool or (a.ndim == 1 and a.dtype.kind in "iu")


class LoopDetector(StreamDetector):
    """Loop closure within one stream, learned online, one frame at a time.

    ``encoder``: encodes the images :meth:`update` takes (without it, SDR rows; ``docs/internals.md``); ``conf``:
    rSHOSM-seq's conf, ``**flat`` keys over it (its ``top_k``: the earlier frames an answer lists); ``exclude``:
    frames closer are not candidates; ``opinion(decider)``: a second decider around the loop rule, as
    :class:`LoopStream` takes it (``vpr loops -``: geometry). ``names``: the frames' names; ``meta``: caller metadata
    :meth:`save` stores.
    """

    def __init__(self, encoder: FrameEncoder | None = None, conf: RshosmSeqConf | None = None,
                 exclude: int = LOOP_EXCLUDE, opinion=None, **flat):
        self.seq = RshosmSeqConf.of(conf, **flat)
        exclude = check_int(exclude, "LoopDetector: exclude", 1)
        delay = int(encoder.delay) if encoder is not None else 0
        if exclude <= delay:
            raise ValueError(f"LoopDetector: exclude {exclude} must exceed the encoder's delay of {delay} frames "
                             "(its first frames wait for each other; they must not be candidates of each other)")
        self.exclude = exclude
        #: the whole conf, the decision's defaults filled in, and ``exclude`` (recorded in metrics.json)
        self.conf = {**self.seq.resolved("loops"), "exclude": exclude}
        self.encoder = encoder
        self.opinion = opinion
        self.stream = LoopStream(exclude, self.seq, opinion=opinion)
        self.names: list[str] = []
        self.meta: dict = {}
        self._late: list[Decision] = []

    @property
    def starts(self) -> list[int]:
        return list(self.stream.starts)

    @property
    def waiting(self) -> int:
        return self.stream.waiting

    @property
    def top_k(self) -> int | None:
        return self.seq.top_k

    def opinion_report(self) -> dict | None:
        return self.stream.decider.report() if self.opinion is not None else None

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) the kernels now, so that the first frame's latency is its own."""
        tiny = LoopStream(1, self.seq.replace(n_inputs=64))
        for bits in ([0, 1, 2, 3], [4, 5, 6, 7], [0, 1, 2, 3]):
            tiny.step(np.array(bits, np.int64))
        warm_up_confirmation()

    def update(self, frame_or_sdr, name: str | None = None) -> Decision | None:
        """Learn the next frame and decide it: a loop closure onto an earlier frame, or a new place.

        ``frame_or_sdr``: an SDR row (1-row sparse matrix, bool vector or bit indices) or, with an encoder, an image.
        The decision's ``column`` lists the earlier frames with evidence. None while its decision waits: a closure is
        confirmed by the frames after it (``LoopConf.confirm_frames``), and the frames after a waiting closure wait
        with it; their decisions come with :meth:`take_late`, in frame order.
        """
        label = str(name) if name is not None else f"frame {self.frames}"
        if _is_sdr(frame_or_sdr):
            if self.encoder is not None and self.encoder.waiting:
                raise ValueError(f"{label}: an SDR while the encoder holds frames waiting for their SDRs; give "
                                 "images or SDRs, not both")
            self.names.append(label)
            return self._hand_out(self.stream.step(frame_or_sdr)[1], self.frames - 1)
        if self.encoder is None:
            raise ValueError(f"{label}: got an image ({np.asarray(frame_or_sdr).shape}) but the LoopDetector has no "
                             "encoder: pass SDR rows, or LoopDetector(encoder=...)")
        return self.update_encoded(self.encoder.push(frame_or_sdr), name)

    def update_encoded(self, rows, name: str | None = None) -> Decision | None:
        """The next frame, given what the encoder's ``push`` returned for it (the SDR rows of the frames now ready).

        Separate from :meth:`update`, so that a caller can time encoding and deciding apart. None when the frame's
        answer is not known yet: the first frames of a later session wait in a causal encoder for their statistics,
        and every frame of the earlier sessions is their candidate; a closure waits for the frames after it (as
        :meth:`update`); their answers come with :meth:`take_late` once decided. (In the first session a frame waiting
        in the encoder has no candidate, so its answer is known at once.)
        """
        j = self.frames
        self.names.append(str(name) if name is not None else f"frame {j}")
        return self._learn(sp.csr_matrix(rows), j)

    def new_session(self) -> None:
        """The next frame starts a new run of the robot (:meth:`vpr.shosm.LoopStream.new_session`); frames still
        waiting in the encoder are decided first, and its causal window starts again."""
        if self.encoder is not None:
            self._release(sp.csr_matrix(self.encoder.new_session()))
        self._late.extend(self.stream.new_session())

    def take_late(self) -> list[Decision]:
        """The answers of earlier frames decided since the last call (frames that waited in the encoder or for the
        frames after a closure), in frame order."""
        out, self._late = self._late, []
        return out

    def flush(self, closures: bool = True) -> None:
        """The stream ends: learn the frames still waiting for their SDRs (a stream that ends before the encoder's
        delay) and, with ``closures``, decide the closures still waiting with the frames after them it has (False:
        they wait on, for frames after a :meth:`save` and :meth:`load`); the answers come with :meth:`take_late`."""
        if self.encoder is not None:
            self._release(sp.csr_matrix(self.encoder.flush()))
        if closures:
            self._late.extend(self.stream.finish())

    def _release(self, rows: sp.csr_matrix) -> None:
        """Decide the frames that waited in the encoder (the last ``rows.shape[0]`` frames pushed)."""
        if not rows.shape[0]:
            return
        d = self._learn(rows, self.frames - 1)
        if d is not None and self.stream.starts[-1] > 0:  # in a later session its answer was not given yet
            self._late.append(d)

    def _learn(self, rows: sp.csr_matrix, j: int) -> Decision | None:
        later_session = self.stream.starts[-1] > 0
        settled = []
        for r in range(rows.shape[0]):
            settled.extend(self.stream.step(rows.indices[rows.indptr[r]:rows.indptr[r + 1]])[1])
        out = self._hand_out(settled, j)
        if out is None and self.stream.frames < j + 1 and j >= 0 and not later_session:
            # the frame waits for its SDR; it has no candidate yet (exclude > delay), so its answer is known
            return Decision(-1, 0.0, False, 0.0, j)
        return out

    def _hand_out(self, settled: list[Decision], j: int) -> Decision | None:
        """Frame ``j``'s decision if final now; the other decisions made final go to :meth:`take_late`, but those of
        first-session frames answered while they waited in the encoder (no candidate: a new place; a first-session frame
        without candidates is final when learned, so only those come after their own call)."""
        out = None
        first = self.stream.starts[1] if len(self.stream.starts) > 1 else None
        for d in settled:
            if d.frame == j:
                out = d
            elif not ((first is None or d.frame < first) and d.column is not None and d.column.n == 0):
                self._late.append(d)
        return out

    # ------------------------------------------------------------ files
    def save(self, path) -> Path:
        """Write the stream, the names and the encoder's state (one atomic ``.npz``)."""
        header, arrays = self.stream.state()
        enc_header, enc_arrays = self.encoder.state() if self.encoder is not None else ({}, {})
        return write_file(path, _FORMAT, _FORMAT_VERSION,
                          {"conf": {**self.seq.flat(), "exclude": self.exclude}, "stream": header, "meta": self.meta,
                           "enc": enc_header, "opinion": self.opinion is not None},
                          {"s": arrays, "enc": enc_arrays}, names=self.names)

    @classmethod
    def saved_meta(cls, path) -> dict:
        """The caller metadata of a file written by :meth:`save`, and ``"opinion"``: whether it decided with one."""
        with read_file(path, _FORMAT, _FORMAT_VERSION, "loop detector",
                       " (written by LoopDetector.save / `vpr loops - --state-out`)", ()) as (header, _, _):
            return {**header.get("meta", {}), "opinion": bool(header.get("opinion", False))}

    @classmethod
    def load(cls, path, encoder: FrameEncoder | None = None, opinion=None) -> LoopDetector:
        """Read a file written by :meth:`save`; the detector continues where it was saved.

        ``encoder``: a fresh one of the kind used before (``meta`` says which), its state restored; ``opinion``: as
        the detector was made with (:meth:`saved_meta` says whether). A missing, corrupt, foreign or too new file,
        or one saved with an opinion loaded without (or the reverse), raises MemoryFileError.
        """
        with read_file(path, _FORMAT, _FORMAT_VERSION, "loop detector",
                       " (written by LoopDetector.save / `vpr loops - --state-out`)", ("s", "enc")) as \
                (header, parts, names):
            saved = bool(header.get("opinion", False))
            if saved != (opinion is not None):
                raise MemoryFileError(f"{path}: a loop detector saved {'with' if saved else 'without'} a second "
                                      f"opinion on its closures, loaded {'without' if saved else 'with'} one")
            conf = dict(header["conf"])
            exclude = conf.pop("exclude")
            det = cls(encoder, exclude=exclude, opinion=opinion, **conf)
            det.stream.load_state(header["stream"], parts["s"])
            det.names = names
            if len(det.names) < det.stream.frames:
                raise ValueError(f"{len(det.names)} names for {det.stream.frames} frames")
            if encoder is not None:
                encoder.load_state(header.get("enc", {}), parts["enc"])
            det.meta = header.get("meta", {})
        return det

    def __repr__(self) -> str:
        return f"LoopDetector(frames={self.frames}, exclude={self.exclude}, memory={self.stream.mem!r})"
