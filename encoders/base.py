"""Base classes of the image encoders: configuration merging, input checks, and the two kinds of encoder.

Each encoder is a small class with a ``default_conf`` dict (as in hloc); the
user's configuration is merged over the defaults of the class and all its
bases. Values given as strings (``--encoder-conf key=value`` on the command
line) are coerced to the type of the default they replace
(:func:`vpr.config.merge_conf`).

Two kinds:

- :class:`BaseEncoder`: images in, SDRs out (``encode``), e.g. ORB votes.
- :class:`DescriptorEncoder`: the SDR is computed from a dense descriptor
  (``describe`` -> ``fit_descriptors`` -> ``encode_descriptors``), so a
  pipeline describes each frame once, fits per-dimension statistics on a whole
  traverse (``standardise="fit"``) and keeps the descriptor for methods that
  read it (``seqslam-desc``). Its fitted statistics can be read and restored
  (:meth:`DescriptorEncoder.statistics`), and overridden per call, which is
  how :mod:`pipelines.stream` encodes one frame at a time.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from vpr.config import merge_conf
from vpr.imageproc import to_uint8

__all__ = ["BaseEncoder", "DescriptorEncoder", "as_image_list", "check_descriptors"]


def as_image_list(images, name: str = "images") -> list[np.ndarray]:
    """Validate a batch of images and return a list of uint8 arrays.

    ``images`` is a sequence of (H, W) grey, (H, W, 3) BGR or (H, W, 4) BGRA
    arrays, or one (N, H, W) grey / (N, H, W, C) colour array. 16-bit and
    float images are converted to uint8 (see :func:`vpr.imageproc.to_uint8`).

    Raises
    ------
    ValueError
        An empty batch, a single image passed without a batch axis, or a frame
        that is empty, of the wrong rank or dtype (the message names the frame
        as ``images[i]``).
    """
    if isinstance(images, np.ndarray):
        if images.ndim == 3 and images.shape[-1] in (3, 4):
            # an (H, W, 3) colour image would otherwise be read as H grey frames 3 pixels wide
            raise ValueError(f"{name}: got one array of shape {images.shape}; pass a single colour "
                             "image as [image] or a batch as (N, H, W, C)")
        if images.ndim not in (3, 4):
            raise ValueError(f"{name}: expected a sequence of images or an (N, H, W[, C]) array, "
                             f"got an array of shape {images.shape}")
        frames = list(images)
    elif isinstance(images, (str, bytes)) or not hasattr(images, "__iter__"):
        raise ValueError(f"{name}: expected a sequence of images, got {type(images).__name__}")
    else:
        frames = list(images)
    if not frames:
        raise ValueError(f"{name}: empty batch (no frames)")
    return [to_uint8(f, name=f"{name}[{i}]") for i, f in enumerate(frames)]


def check_descriptors(desc, name: str = "descriptors", dim: int | None = None) -> np.ndarray:
    """Validate a dense (frames, dims) descriptor array; returns float32.

    Raises
    ------
    ValueError
        Wrong rank, empty, a dimension other than ``dim``, or a non-finite
        value (the message names the first bad frame).
    """
    d = np.asarray(desc)
    if d.ndim == 1:
        d = d[None, :]
    if d.ndim != 2 or d.size == 0:
        raise ValueError(f"{name}: expected a non-empty 2-D (frames x dims) array, got shape {d.shape}")
    if d.dtype.kind not in "fiub":
        raise ValueError(f"{name}: expected numbers, got dtype {d.dtype}")
    d = d.astype(np.float32, copy=False)
    if dim is not None and d.shape[1] != dim:
        raise ValueError(f"{name}: expected {dim} dims per frame, got {d.shape[1]}")
    bad = ~np.isfinite(d).all(axis=1)
    if bad.any():
        raise ValueError(f"{name}: frame {int(np.flatnonzero(bad)[0])}: NaN or infinite value")
    return d


class BaseEncoder:
    """An image encoder: images in, SDR batch (bool CSR, frames x ``n_bits``) out.

    Subclasses set ``default_conf`` and implement :meth:`encode` and, where
    they have a dense descriptor, :meth:`describe`. Configuration is merged
    over the defaults of every class in the hierarchy; unknown keys raise.

    Parameters
    ----------
    **conf
        Overrides of ``default_conf``. Strings are coerced to the default's type.
    """

    default_conf: dict = {}
    name: str = "base"

    def __init__(self, **conf):
        defaults: dict = {}
        for cls in reversed(type(self).__mro__):
            defaults.update(getattr(cls, "default_conf", {}) or {})
        self.conf = merge_conf(defaults, conf, f"{self.name} encoder")

    @property
    def n_bits(self) -> int:
        """Width of the SDRs produced by :meth:`encode`."""
        raise NotImplementedError

    def check_memory(self, n_frames: int) -> None:
        """Refuse, before any work, a conf whose arrays for ``n_frames`` frames cannot fit in this machine's memory.

        ValueError naming the option and the size; the default has nothing to check.
        """

    def check_sources(self, srcs, roles, chosen: str = "") -> None:
        """Refuse, before reading a frame, sources this encoder cannot encode: too short for statistics fitted on
        them (``standardise=fit``), or too long for memory (:meth:`check_memory`). ``chosen``: the options that
        chose the frames (``--max-frames 1``), named in the message."""
        how = self.conf.get("standardise")
        for src, role in zip(srcs, roles, strict=True):
            n = len(src.indices())
            if how in ("fit", "per_batch") and n < 2:
                raise ValueError(f"{role} {src.path}: {n} frame(s) to read{f' with {chosen}' if chosen else ''}; "
                                 f"encoder {self.name} with standardise={how} is fitted on the traverse and needs at "
                                 "least 2 (more frames, or --encoder-conf standardise=none)")
        self.check_memory(max((len(s.indices()) for s in srcs), default=0))

    def fit(self, images) -> BaseEncoder:
        """Learn statistics from ``images`` (default: nothing to learn). Returns self."""
        as_image_list(images)
        return self

    def describe(self, images) -> np.ndarray:
        """Dense float32 descriptor, (frames, dims)."""
        raise NotImplementedError(f"encoder {self.name!r} has no dense descriptor")

    def encode(self, images) -> sp.csr_matrix:
        """SDR batch, bool CSR (frames, ``n_bits``)."""
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"{type(self).__name__}({', '.join(f'{k}={v!r}' for k, v in self.conf.items())})"


class DescriptorEncoder(BaseEncoder):
    """An encoder whose SDR is the sparsification of a dense descriptor (frames x dims).

    Subclasses implement :meth:`describe`, :meth:`fit_descriptors`,
    :meth:`encode_descriptors` and the statistics hooks; :meth:`fit` and
    :meth:`encode` are built on them. The SDR may depend on per-dimension
    statistics (mean, std) of one or more blocks of the descriptor (one block
    per sparsified part: one for a plain encoder, one per part of a joined
    one), fitted by :meth:`fit_descriptors` when ``standardise="fit"``.
    """

    def warm_up(self) -> None:
        """Load models and build projection matrices now (two tiny frames described and sparsified), so that the
        first frame's latency is its own."""
        self.encode_descriptors(self.describe([np.zeros((48, 64, 3), np.uint8)] * 2))

    def describe(self, images) -> np.ndarray:
        """Dense float32 descriptor, (frames, dims)."""
        raise NotImplementedError

    def fit_descriptors(self, desc) -> DescriptorEncoder:
        """Learn the standardisation statistics from precomputed descriptors. Returns self."""
        raise NotImplementedError

    def encode_descriptors(self, desc, statistics: list | None = None) -> sp.csr_matrix:
        """SDR batch from precomputed descriptors; ``statistics`` (one (mean, std) per block) override the
        fitted ones for this call."""
        raise NotImplementedError

    def blocks(self, desc) -> list[np.ndarray]:
        """The descriptor cut into the blocks that have their own statistics (default: one)."""
        return [check_descriptors(desc, name=f"{self.name} descriptors")]

    def statistics(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The fitted (mean, std) of every block; empty when nothing was fitted."""
        raise NotImplementedError

    def set_statistics(self, stats: list) -> DescriptorEncoder:
        """Restore statistics read from :meth:`statistics` (e.g. stored in a map). Returns self."""
        raise NotImplementedError

    def fit(self, images) -> DescriptorEncoder:
        """Learn the standardisation statistics from ``images``, describing them once. Returns self."""
        return self.fit_descriptors(self.describe(images))

    def encode(self, images) -> sp.csr_matrix:
        return self.encode_descriptors(self.describe(images))
