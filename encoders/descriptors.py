"""``descriptors``: random-projection top-k SDRs of global descriptors computed elsewhere (descriptor files).

The frames of a descriptor file (:class:`vpr.sources.DescriptorSource`: a ``.npy`` of N x D, hloc's global-feature
``.h5``) carry their descriptor rows; this encoder's :meth:`describe` takes them as they are, and the projection's
``n_bits``, ``k`` and ``standardise`` (``fit``: on each traverse's own rows, as the ``projection`` encoder) make the
SDRs rSHOSM reads. ``seqslam-desc`` and ``pairwise`` read the descriptors themselves.
"""
from __future__ import annotations

import numpy as np

from .projection import ProjectedEncoder

__all__ = ["DescriptorsEncoder"]


class DescriptorsEncoder(ProjectedEncoder):
    """The :class:`TopKProjection` of given descriptor rows (``standardise="fit"`` by default)."""

    name = "descriptors"
    default_conf = {"standardise": "fit"}
    #: the descriptors' length, once the sources are known (:meth:`check_sources`; 0 before)
    dim = 0

    def describe(self, images) -> np.ndarray:
        rows = list(images)
        if not rows or any(np.ndim(r) != 1 for r in rows):
            shape = np.shape(rows[0]) if rows else ()
            raise ValueError(f"encoder descriptors reads descriptor files (.npy, .h5: one row a frame), not images "
                             f"(got a frame of shape {shape})")
        return np.asarray(np.stack(rows), np.float32)

    def warm_up(self) -> None:
        """Build the projection matrix of the descriptors' length, once it is known (:meth:`check_sources`)."""
        if self.dim:
            self.encode_descriptors(np.zeros((2, self.dim), np.float32))

    def check_sources(self, srcs, roles, chosen: str = "") -> None:
        """As every encoder's, and the traverses must be descriptor files of one length (one model's)."""
        dims = {}
        for src, role in zip(srcs, roles, strict=True):
            if src.has_images:
                raise ValueError(f"{role} {src.path}: encoder descriptors reads descriptor files (.npy, .h5), not a "
                                 f"{src.kind}")
            dims[f"{role} {src.path}"] = src.dim
        if len(set(dims.values())) > 1:
            raise ValueError("descriptors of different lengths (another model's?): "
                             + ", ".join(f"{k} {v}" for k, v in dims.items()))
        self.dim = next(iter(dims.values()), 0)
        super().check_sources(srcs, roles, chosen)
