"""SeqSLAM-style pixel descriptor: grey thumbnail with patch normalisation.

:meth:`PixelEncoder.describe` is OpenSeqSLAM's preprocessing (grey, resize to
``size`` = 64 x 32, normalise every ``patch`` x ``patch`` block to zero mean and
unit std) flattened row-major: a 2048-dim float32 vector with the defaults,
computed by :func:`vpr.imageproc.seqslam_descriptors` (the project's one
implementation). SeqSLAM and cosine baselines use it directly.

:meth:`PixelEncoder.encode` sparsifies that descriptor with the random
projection top-k of :mod:`encoders.projection` (conf ``n_bits``, ``k``,
``seed``, ``two_sided``, ``standardise``), so ``get("pixel")`` and
``get("projection", descriptor="pixel")`` give the same SDRs.
"""
from __future__ import annotations

import numpy as np

from vpr.imageproc import seqslam_descriptors

from .base import as_image_list
from .projection import ProjectedEncoder

__all__ = ["PixelEncoder"]


class PixelEncoder(ProjectedEncoder):
    """Patch-normalised thumbnail descriptor, sparsified by random-projection top-k.

    Conf: ``size`` (width, height) of the thumbnail, default (64, 32);
    ``patch`` side of the normalisation blocks, default 8; plus the projection
    keys of :class:`encoders.projection.ProjectedEncoder`.
    """

    name = "pixel"
    default_conf = {"size": (64, 32), "patch": 8}

    def __init__(self, **conf):
        super().__init__(**conf)
        size = self.conf["size"]
        if len(size) != 2 or min(size) < 1:
            raise ValueError(f"pixel: size must be (width, height) >= 1, got {self.conf['size']}")
        if self.conf["patch"] < 1:
            raise ValueError(f"pixel: patch must be >= 1, got {self.conf['patch']}")

    @property
    def dim(self) -> int:
        """Length of the dense descriptor (width * height)."""
        w, h = self.conf["size"]
        return w * h

    def describe(self, images) -> np.ndarray:
        """Flattened patch-normalised thumbnails, float32 (frames, width * height)."""
        return seqslam_descriptors(as_image_list(images), self.conf["size"], self.conf["patch"])
