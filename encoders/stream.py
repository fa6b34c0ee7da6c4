"""Encoding a stream one frame at a time with an encoder fitted on a database (``vpr localize``).

The batch commands standardise a traverse on its own frames
(``standardise="fit"``), which needs the whole traverse. Online that is
impossible; :class:`StreamEncoder` standardises each frame with
``"running"`` statistics (:class:`encoders.projection.RunningStandardiser`:
the last ``window`` frames plus the database's statistics as a prior) or the
database's own (``"db"``). Encoders that do not standardise, or that have no
dense descriptor, encode each frame as they would a batch.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .base import BaseEncoder, DescriptorEncoder
from .projection import RunningStandardiser

__all__ = ["StreamEncoder", "STANDARDISE"]

#: How a stream is standardised (``--query-standardise``).
STANDARDISE = ("running", "db")


class StreamEncoder:
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

    def __init__(self, encoder: BaseEncoder, standardise: str = "running", prior_frames: float = 10.0,
                 window: int | None = 50):
        if standardise not in STANDARDISE:
            raise ValueError(f"query standardise must be 'running' or 'db', got {standardise!r}")
        if encoder.conf.get("standardise") in ("per_batch", "causal"):
            raise ValueError(f"encoders with standardise={encoder.conf['standardise']} cannot encode one frame at "
                             "a time; use standardise=fit or none")
        self.encoder = encoder
        self.standardise = standardise
        self.described = isinstance(encoder, DescriptorEncoder)
        fitted = self.described and encoder.conf.get("standardise") == "fit"
        if fitted and not encoder.statistics():
            raise ValueError(f"encoder {encoder.name} has standardise=fit but no fitted statistics (a map "
                             "written without them?)")
        self._running = [RunningStandardiser(m, s, prior_frames, window) for m, s in encoder.statistics()] \
            if fitted and standardise == "running" else []

    def warm_up(self) -> None:
        """Load models and build projection matrices now, so that the first frame's latency is its own."""
        if self.described:
            self.encoder.encode_descriptors(self.encoder.describe([np.zeros((48, 64, 3), np.uint8)]))

    def encode(self, image) -> sp.csr_matrix:
        """The SDR (1 row) of one frame; with running statistics, the frame joins them first."""
        if not self.described:
            return sp.csr_matrix(self.encoder.encode([image]))
        desc = np.asarray(self.encoder.describe([image]), np.float32)
        if not self._running:
            return sp.csr_matrix(self.encoder.encode_descriptors(desc))
        stats = [r.update(b[0]) for r, b in zip(self._running, self.encoder.blocks(desc), strict=True)]
        return sp.csr_matrix(self.encoder.encode_descriptors(desc, stats))

    def state(self) -> dict:
        """The running statistics as arrays (stored in ``--state-out`` files, so that a restart continues them)."""
        out = {}
        for i, r in enumerate(self._running):
            st = r.state()
            out[f"q_sum_{i}"], out[f"q_sq_{i}"] = st["sum"], st["sq"]
            out["q_n"] = st["n"]
            if "recent" in st:
                out[f"q_recent_{i}"] = st["recent"]
        return out

    def load_state(self, arrays: dict) -> StreamEncoder:
        """Continue the running statistics of :meth:`state` (no-op when ``arrays`` holds none)."""
        if not self._running or "q_n" not in arrays:
            return self
        for i, r in enumerate(self._running):
            st = {"n": arrays["q_n"], "sum": arrays[f"q_sum_{i}"], "sq": arrays[f"q_sq_{i}"]}
            if f"q_recent_{i}" in arrays:
                st["recent"] = arrays[f"q_recent_{i}"]
            r.load_state(st)
        return self
