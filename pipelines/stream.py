"""Encoding a stream one frame at a time (``vpr localize``, ``vpr loops -``).

The batch commands standardise a traverse on its own frames
(``standardise="fit"``), which needs the whole traverse. Online that is
impossible; :class:`StreamEncoder` standardises each frame with
``"running"`` statistics (:class:`vpr.standardise.RunningStandardiser`:
the last ``window`` frames plus the database's statistics as a prior; a frame
whose SDR keeps :data:`vpr.sdr.UNMOVED_SHARE` of the frame before's bits, a
camera that stands, does not join them) or the database's own (``"db"``). An
encoder with ``standardise="causal"`` (the loop encoders of the presets) needs nothing from a database: its frames are
standardised as the batch does it (:class:`vpr.standardise.CausalStandardiser`),
so the SDRs equal the batch's, but the first ``CAUSAL_MIN`` frames wait for
each other (:meth:`StreamEncoder.push`). Encoders that do not standardise, or
that have no dense descriptor, encode each frame as they would a batch.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from encoders.base import BaseEncoder, DescriptorEncoder
from vpr.sdr import UNMOVED_SHARE, kept_share
from vpr.standardise import CAUSAL_MIN, CausalStandardiser, RunningStandardiser
from vpr.types import FrameEncoder

__all__ = ["StreamEncoder", "STANDARDISE", "PRIOR_FRAMES", "WINDOW"]

#: How a stream is standardised (``--query-standardise``).
STANDARDISE = ("running", "db")


#: Running standardisation of a query stream (``vpr localize``): the database's statistics weigh as this many
#: frames, and the statistics are those of the last :data:`WINDOW` frames (chosen in ``research/docs/localize.md``).
PRIOR_FRAMES = 10.0
WINDOW = 50


class StreamEncoder(FrameEncoder):
    """Encode one frame at a time with ``encoder`` (fitted on the database when it standardises).

    Parameters
    ----------
    encoder : an encoder from :func:`encoders.get`, with its database statistics
        set (:meth:`encoders.base.DescriptorEncoder.set_statistics`) when its
        conf says ``standardise="fit"``.
    standardise : {"running", "db"}
    prior_frames : float > 0
        Weight of the database's statistics in the running ones, in frames.
    window : int >= 2 or None
        Running statistics over the last ``window`` frames (None: all so far).
    """

    def __init__(self, encoder: BaseEncoder, standardise: str = "running", prior_frames: float = PRIOR_FRAMES,
                 window: int | None = WINDOW):
        if standardise not in STANDARDISE:
            raise ValueError(f"query standardise must be 'running' or 'db', got {standardise!r}")
        if encoder.conf.get("standardise") == "per_batch":
            raise ValueError("encoders with standardise=per_batch cannot encode one frame at a time; use "
                             "standardise=fit, causal or none")
        self.encoder = encoder
        self.standardise = standardise
        self.described = isinstance(encoder, DescriptorEncoder)
        self.causal = self.described and encoder.conf.get("standardise") == "causal"
        self._causal: list[CausalStandardiser] = []
        self._waiting: list[np.ndarray] = []
        fitted = self.described and encoder.conf.get("standardise") == "fit"
        if fitted and not encoder.statistics():
            raise ValueError(f"encoder {encoder.name} has standardise=fit but no fitted statistics (a map "
                             "written without them?)")
        self._running = [RunningStandardiser(m, s, prior_frames, window) for m, s in encoder.statistics()] \
            if fitted and standardise == "running" else []
        self._before: np.ndarray | None = None  # the last frame's active bits (running statistics)

    @property
    def delay(self) -> int:
        """Frames a frame may wait for its SDR (:meth:`push`): ``CAUSAL_MIN - 1`` with causal standardisation."""
        return CAUSAL_MIN - 1 if self.causal else 0

    @property
    def waiting(self) -> int:
        """Frames pushed whose SDRs :meth:`push` has not given yet."""
        return len(self._waiting)

    def warm_up(self) -> None:
        """Load models and build projection matrices now, so that the first frame's latency is its own."""
        if self.described:
            self.encoder.warm_up()

    def push(self, image) -> sp.csr_matrix:
        """The SDRs of the frames now ready, in order (0 or more rows; 1 row except with causal standardisation).

        With ``standardise="causal"`` the first ``CAUSAL_MIN - 1`` frames give
        none and the ``CAUSAL_MIN``-th gives all of them; every later frame
        gives its own at once. :meth:`flush` ends a shorter stream.
        """
        if not self.causal:
            return self.encode(image)
        desc = np.asarray(self.encoder.describe([image]), np.float32)
        blocks = self.encoder.blocks(desc)
        if not self._causal:
            self._causal = [CausalStandardiser() for _ in blocks]
        stats = [c.push(b[0]) for c, b in zip(self._causal, blocks, strict=True)]
        self._waiting.append(desc[0])
        if stats[0] is None:
            return sp.csr_matrix((0, self.encoder.n_bits), dtype=bool)
        return self._release(stats)

    def flush(self) -> sp.csr_matrix:
        """The SDRs of frames still waiting (a causal stream shorter than ``CAUSAL_MIN``), 0 or more rows."""
        stats = [c.flush() for c in self._causal]
        if not self._waiting or not stats or stats[0] is None:
            return sp.csr_matrix((0, self.encoder.n_bits), dtype=bool)
        return self._release(stats)

    def new_session(self) -> sp.csr_matrix:
        """A new run starts: the causal window forgets the last one (the SDRs of frames still waiting are returned,
        as :meth:`flush`); running query statistics start again from the database's."""
        out = self.flush() if self.causal else sp.csr_matrix((0, self.encoder.n_bits), dtype=bool)
        self._causal, self._waiting = [], []
        for r in self._running:
            r.reset()
        self._before = None
        return out

    def _release(self, stats) -> sp.csr_matrix:
        desc, self._waiting = np.stack(self._waiting), []
        return sp.csr_matrix(self.encoder.encode_descriptors(desc, stats), dtype=bool)

    def encode(self, image) -> sp.csr_matrix:
        """The SDR (1 row) of one frame; with running statistics, the frame joins them first."""
        if self.causal:
            raise ValueError(f"encoder {self.encoder.name} standardises causally: its frames may wait for later "
                             "ones; use push() and flush()")
        if not self.described:
            return sp.csr_matrix(self.encoder.encode([image]))
        desc = np.asarray(self.encoder.describe([image]), np.float32)
        if not self._running:
            return sp.csr_matrix(self.encoder.encode_descriptors(desc))
        stats = [r.update(b[0]) for r, b in zip(self._running, self.encoder.blocks(desc), strict=True)]
        x = sp.csr_matrix(self.encoder.encode_descriptors(desc, stats), dtype=bool)
        bits = x.indices.astype(np.int64)
        if self._before is not None and kept_share(bits, self._before) >= UNMOVED_SHARE:
            for r in self._running:  # the camera stands: the frame is no new sample of the places
                r.withdraw()
        self._before = bits
        return x

    def state(self) -> tuple[dict, dict]:
        """The running statistics as arrays (stored in ``--state-out`` files, so that a restart continues them)."""
        out = {}
        for i, c in enumerate(self._causal):
            out.update({f"c{i}_{k}": v for k, v in c.state()[1].items()})
        if self._waiting:
            out["c_waiting"] = np.stack(self._waiting)
        for i, r in enumerate(self._running):
            st = r.state()[1]
            out[f"q_sum_{i}"], out[f"q_sq_{i}"] = st["sum"], st["sq"]
            out["q_n"] = st["n"]
            if "recent" in st:
                out[f"q_recent_{i}"] = st["recent"]
        if self._before is not None:
            out["q_before"] = self._before
        return {}, out

    def load_state(self, header: dict, arrays: dict) -> StreamEncoder:
        """Continue the running statistics of :meth:`state` (no-op when ``arrays`` holds none)."""
        if self.causal and "c0_frames" in arrays:
            n = len({k.split("_")[0] for k in arrays if k.startswith("c") and k[1:].split("_")[0].isdigit()})
            self._causal = [CausalStandardiser().load_state({}, {k: arrays[f"c{i}_{k}"] for k in ("frames", "s", "q")})
                            for i in range(n)]
            self._waiting = list(np.asarray(arrays["c_waiting"], np.float32)) if "c_waiting" in arrays else []
        if not self._running or "q_n" not in arrays:
            return self
        for i, r in enumerate(self._running):
            st = {"n": arrays["q_n"], "sum": arrays[f"q_sum_{i}"], "sq": arrays[f"q_sq_{i}"]}
            if f"q_recent_{i}" in arrays:
                st["recent"] = arrays[f"q_recent_{i}"]
            r.load_state({}, st)
        self._before = np.asarray(arrays["q_before"], np.int64) if "q_before" in arrays else None
        return self
