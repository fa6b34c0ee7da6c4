"""Random-projection top-k sparsifier: dense descriptor -> SDR.

A dense descriptor ``x`` (D dims) is optionally standardised, multiplied by a
seeded Gaussian matrix ``W`` (D x n_bits) and the ``k`` largest projections
become the active bits. Random projection approximately preserves angles, and
keeping the winners of ``x @ W`` makes the overlap of two SDRs a monotone
(noisy) function of the descriptors' cosine similarity, which is what the
sequence memory and the pairwise overlap baseline consume.

The two-sided variant projects to ``n_bits / 2`` dims and activates the
``ceil(k/2)`` largest projections in the first half of the SDR and the
``floor(k/2)`` smallest in the second half, so it too has exactly ``k`` bits.

Standardisation (``standardise``):

- ``"none"``: the descriptor as it is.
- ``"fit"``: per-dim mean / std learned by :meth:`fit` (e.g. on one traverse,
  then encode that traverse). Removing the traverse's mean descriptor cancels
  global appearance change (season, illumination) that is shared by all its
  frames and otherwise dominates the top-k.
- ``"per_batch"``: mean / std of the batch being encoded (needs >= 2 frames);
  an SDR then depends on the other frames of the batch.
- ``"causal"``: each frame standardised by the mean / std of the last
  :data:`CAUSAL_WINDOW` frames of the batch up to and including it (the
  first :data:`CAUSAL_MIN` frames use the first ``CAUSAL_MIN``). For one
  stream that changes condition (loop closure over two traverses, ``vpr
  loops``): a fit on the whole stream mixes the conditions, a sliding window
  follows them, and only the past counts.

Encoding one frame at a time (:mod:`pipelines.stream`): ``vpr localize`` uses
:class:`RunningStandardiser` (the statistics of a sliding window of the frames
so far, with the fitted statistics as a prior); ``vpr loops -`` uses
:class:`CausalStandardiser`, the incremental form of ``"causal"``, which gives
the batch's SDRs exactly. For that, ``"causal"`` projections are computed row
by row in float64 in a fixed order (:func:`project_rows`), not with BLAS,
whose result for a row depends on how many rows are multiplied at once.

The registered ``projection`` encoder wraps a descriptor by name:
``descriptor="pixel"`` (SeqSLAM patch-normalised thumbnail), ``"hog"``
(scikit-image HOG) or ``"cnn"`` (pooled ONNX CNN features); ``descriptor_conf``
configures it. HOG and CNN descriptors are non-negative with a large mean
shared by all images; without standardisation that mean dominates the top-k,
so use ``standardise="fit"`` (or ``"per_batch"``) with them.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numba import njit

from vpr import sdr
from vpr.checks import physical_memory
from vpr.config import merge_conf
from vpr.imageproc import resize, to_grey
from vpr.standardise import (
    CAUSAL_MIN,
    CAUSAL_WINDOW,
    CausalStandardiser,
    RunningStandardiser,
    causal_standardised,
    window_standardised,
)

from .base import DescriptorEncoder, as_image_list, check_descriptors

__all__ = ["TopKProjection", "ProjectedEncoder", "ProjectionEncoder", "HogDescriptor", "RunningStandardiser",
           "CausalStandardiser", "project_rows", "CAUSAL_WINDOW", "CAUSAL_MIN"]

_STANDARDISE = ("none", "fit", "per_batch", "causal")


def _csr_rows(idx: np.ndarray, n_bits: int) -> sp.csr_matrix:
    """Bool CSR from an (N, k) array of distinct bit indices per row."""
    n, k = idx.shape
    idx = np.sort(idx, axis=1)
    indptr = np.arange(0, n * k + 1, k, dtype=np.int64)
    return sp.csr_matrix((np.ones(n * k, dtype=bool), idx.ravel().astype(np.int32), indptr),
                         shape=(n, n_bits))


class TopKProjection:
    """Seeded Gaussian random projection followed by top-k (exactly ``k`` bits per row).

    Parameters
    ----------
    n_bits : int
        SDR width.
    k : int
        Active bits per row.
    seed : int
        Seed of the projection matrix; the same seed and input dimension give
        the same matrix.
    two_sided : bool
        Top ``ceil(k/2)`` into the first half, bottom ``floor(k/2)`` into the
        second half (``n_bits`` must be even).
    standardise : {"none", "fit", "per_batch"}
        See the module docstring.
    """

    def __init__(self, n_bits: int = 2048, k: int = 40, seed: int = 0, two_sided: bool = False,
                 standardise: str = "none"):
        n_bits, k = int(n_bits), int(k)
        if n_bits <= 0:
            raise ValueError(f"n_bits must be positive, got {n_bits}")
        if two_sided and n_bits % 2:
            raise ValueError(f"n_bits must be even for two_sided, got {n_bits}")
        if not 1 <= k <= (n_bits // 2 if two_sided else n_bits):
            raise ValueError(f"k must be in [1, {n_bits // 2 if two_sided else n_bits}], got {k}")
        if two_sided and k < 2:
            raise ValueError(f"k must be >= 2 for two_sided, got {k}")
        if standardise not in _STANDARDISE:
            raise ValueError(f"standardise must be one of {_STANDARDISE}, got {standardise!r}")
        self.n_bits, self.k, self.seed = n_bits, k, int(seed)
        self.two_sided, self.standardise = bool(two_sided), standardise
        self.mean_: np.ndarray | None = None
        self.std_: np.ndarray | None = None
        self._W: np.ndarray | None = None

    def matrix(self, dim: int) -> np.ndarray:
        """The (dim, n_out) float32 projection matrix for input dimension ``dim``."""
        n_out = self.n_bits // 2 if self.two_sided else self.n_bits
        if self._W is None or self._W.shape[0] != dim:
            rng = np.random.default_rng(self.seed)
            self._W = rng.standard_normal((dim, n_out), dtype=np.float32)
        return self._W

    @staticmethod
    def _stats(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        mean = d.mean(axis=0, dtype=np.float64).astype(np.float32)
        std = d.std(axis=0, dtype=np.float64).astype(np.float32)
        # constant dims carry no information; leave them at zero instead of dividing by ~0
        std[std < 1e-6] = np.inf
        return mean, std

    def fit(self, desc) -> TopKProjection:
        """Learn the per-dim mean and std used by ``standardise="fit"``. Returns self."""
        d = check_descriptors(desc)
        if d.shape[0] < 2:
            raise ValueError(f"descriptors: fit needs at least 2 frames, got {d.shape[0]}")
        self.mean_, self.std_ = self._stats(d)
        return self

    def standardised(self, desc, stats: tuple | None = None) -> np.ndarray:
        """The descriptors after the configured standardisation (float32).

        ``stats``: a (mean, std) pair to use instead of the fitted one (for
        ``standardise="fit"``; see :class:`RunningStandardiser`), or, for
        ``"causal"``, the float64 statistics of the rows' window
        (:class:`CausalStandardiser`).
        """
        d = check_descriptors(desc)
        if self.standardise == "fit":
            mean, std = (self.mean_, self.std_) if stats is None else stats
            if mean is None:
                raise ValueError("standardise='fit' but the encoder was not fitted: call fit() first")
            if d.shape[1] != mean.size:
                raise ValueError(f"descriptors: fitted on {mean.size} dims, got {d.shape[1]}")
            return (d - mean) / std
        if self.standardise == "causal" and stats is not None:  # one window's statistics (CausalStandardiser)
            mean, std = stats
            return window_standardised(d.astype(np.float64), mean, std)
        if stats is not None:
            raise ValueError(f"statistics are only used with standardise='fit' or 'causal', not {self.standardise!r}")
        if self.standardise == "per_batch":
            if d.shape[0] < 2:
                raise ValueError(f"descriptors: standardise='per_batch' needs at least 2 frames, "
                                 f"got {d.shape[0]}")
            mean, std = self._stats(d)
            return (d - mean) / std
        if self.standardise == "causal":
            return causal_standardised(d)
        return d

    def project(self, desc, stats: tuple | None = None) -> np.ndarray:
        """Projections (frames, n_bits or n_bits/2): float32, or float64 row by row for ``"causal"``."""
        d = self.standardised(desc, stats)
        if self.standardise == "causal":  # the same SDR whether the frame comes alone or in a batch
            return project_rows(d, self.matrix(d.shape[1]))
        return d @ self.matrix(d.shape[1])

    def __call__(self, desc, stats: tuple | None = None) -> sp.csr_matrix:
        """SDR batch with exactly ``k`` bits per row (``stats``: see :meth:`standardised`).

        Ties (e.g. an all-zero descriptor) go to the lower bit index, so the
        result is deterministic.
        """
        p = self.project(desc, stats)
        if not self.two_sided:
            return sdr.from_topk(p, self.k)
        half = p.shape[1]
        k_top = (self.k + 1) // 2
        top = np.argsort(-p, axis=1, kind="stable")[:, :k_top]
        bottom = np.argsort(p, axis=1, kind="stable")[:, :self.k - k_top] + half
        return _csr_rows(np.concatenate([top, bottom], axis=1), self.n_bits)


@njit(cache=True, nogil=True)
def _project_rows(d, W, out):  # pragma: no cover - compiled
    n, dims = d.shape
    m = W.shape[1]
    for r0 in range(0, n, 16):  # 16 rows share each pass over W
        r1 = min(r0 + 16, n)
        for k in range(dims):
            for r in range(r0, r1):
                a = np.float64(d[r, k])
                if a != 0.0:
                    for c in range(m):
                        out[r, c] += a * W[k, c]


def project_rows(d, W) -> np.ndarray:
    """``d @ W`` in float64, each row summed over the dims in order: a row's result does not depend on the others.

    (BLAS splits and orders the sums by the shape of the whole product, so
    a frame projected alone and in a batch can differ in the last bits, and a
    top-k near a tie with them.)
    """
    d = np.ascontiguousarray(d, np.float32)
    W = np.ascontiguousarray(W, np.float32)
    if d.ndim != 2 or W.ndim != 2 or d.shape[1] != W.shape[0]:
        raise ValueError(f"project_rows: shapes {d.shape} and {W.shape} do not multiply")
    out = np.zeros((d.shape[0], W.shape[1]), np.float64)
    _project_rows(d, W, out)
    return out


class ProjectedEncoder(DescriptorEncoder):
    """Base of encoders whose SDR is the :class:`TopKProjection` of a dense descriptor.

    Subclasses implement :meth:`describe`; :meth:`encode` is
    ``encode_descriptors(describe(images))``.
    """

    default_conf = {
        "n_bits": 2048,
        "k": 40,
        "seed": 0,
        "two_sided": False,
        "standardise": "none",
    }

    def __init__(self, **conf):
        super().__init__(**conf)
        c = self.conf
        self.projection = TopKProjection(c["n_bits"], c["k"], c["seed"], c["two_sided"], c["standardise"])

    @property
    def n_bits(self) -> int:
        return self.projection.n_bits

    def check_memory(self, n_frames: int) -> None:
        """The projection matrix (dims x n_bits) and the frames' projections (frames x n_bits), float32, must fit."""
        phys = physical_memory()
        p = self.projection
        n_out = p.n_bits // 2 if p.two_sided else p.n_bits
        dim = int(getattr(self, "dim", 0) or 0)
        need = 4 * n_out * (dim + max(int(n_frames), 1))
        if phys is not None and need > phys:
            raise ValueError(f"--encoder-conf n_bits={p.n_bits}: the {self.name} encoder would need "
                             f"{need / 2**30:,.1f} GiB for {n_frames} frames (a projection of {dim} dims to {n_out} "
                             f"bits, and each frame's projection), more than this machine's {phys / 2**30:,.1f} GiB; "
                             "use fewer bits")

    def describe(self, images) -> np.ndarray:
        raise NotImplementedError

    def fit_descriptors(self, desc) -> ProjectedEncoder:
        """As :meth:`fit`, from precomputed descriptors."""
        self.projection.fit(desc)
        return self

    def encode_descriptors(self, desc, statistics: list | None = None) -> sp.csr_matrix:
        """Sparsify precomputed dense descriptors (frames, dims) without recomputing them."""
        return self.projection(desc, None if statistics is None else statistics[0])

    def statistics(self) -> list[tuple[np.ndarray, np.ndarray]]:
        p = self.projection
        return [] if p.mean_ is None else [(p.mean_, p.std_)]

    def set_statistics(self, stats: list) -> ProjectedEncoder:
        if len(stats) != 1:
            raise ValueError(f"{self.name}: expected the statistics of 1 block, got {len(stats)}")
        mean, std = stats[0]
        self.projection.mean_, self.projection.std_ = np.asarray(mean, np.float32), np.asarray(std, np.float32)
        return self


class HogDescriptor:
    """Whole-image HOG (scikit-image) of the grey image resized to ``size`` (w, h).

    Parameters
    ----------
    size : tuple of int
        (width, height) the image is resized to before HOG.
    orientations, pixels_per_cell, cells_per_block : int
        As in :func:`skimage.feature.hog` (square cells and blocks).
    """

    default_conf = {"size": (128, 64), "orientations": 9, "pixels_per_cell": 16, "cells_per_block": 2}

    def __init__(self, **conf):
        self.conf = merge_conf(self.default_conf, conf, "hog descriptor")
        w, h = self.conf["size"]
        ppc, cpb = self.conf["pixels_per_cell"], self.conf["cells_per_block"]
        if min(w, h) < ppc * cpb:
            raise ValueError(f"hog: size {self.conf['size']} smaller than one block ({ppc * cpb} px)")

    def describe(self, images) -> np.ndarray:
        from skimage.feature import hog  # scikit-image is slow to import; only HOG needs it

        c = self.conf
        frames = as_image_list(images)
        out = [hog(resize(to_grey(f, f"images[{i}]"), c["size"]), orientations=c["orientations"],
                   pixels_per_cell=(c["pixels_per_cell"],) * 2, cells_per_block=(c["cells_per_block"],) * 2,
                   block_norm="L2-Hys", feature_vector=True)
               for i, f in enumerate(frames)]
        return np.asarray(out, dtype=np.float32)


class ProjectionEncoder(ProjectedEncoder):
    """Random-projection top-k SDRs of a named dense descriptor.

    Conf (besides :class:`ProjectedEncoder`'s ``n_bits``, ``k``, ``seed``,
    ``two_sided``, ``standardise``):

    descriptor : {"pixel", "hog", "cnn"}
        The wrapped descriptor; ``"pixel"`` and ``"cnn"`` are the
        :meth:`describe` of those encoders.
    descriptor_conf : dict
        Conf of the wrapped descriptor (JSON when given as a string).
    """

    name = "projection"
    default_conf = {"descriptor": "pixel", "descriptor_conf": {}}

    def __init__(self, **conf):
        super().__init__(**conf)
        name, dconf = self.conf["descriptor"], self.conf["descriptor_conf"]
        if name == "hog":
            self.descriptor = HogDescriptor(**dconf)
        elif name in ("pixel", "cnn"):
            from . import get  # lazy: the registry imports this module

            self.descriptor = get(name, **dconf)
        else:
            raise ValueError(f"projection: descriptor must be 'pixel', 'hog' or 'cnn', got {name!r}")

    @property
    def dim(self) -> int:
        """Length of the wrapped descriptor (the descriptor's own ``dim``, else one tiny describe)."""
        d = getattr(self.descriptor, "dim", None)
        if isinstance(d, (int, np.integer)):
            return int(d)
        return int(self.descriptor.describe([np.zeros((64, 64, 3), np.uint8)]).shape[1])

    def describe(self, images) -> np.ndarray:
        """The wrapped dense descriptor, float32 (frames, dims)."""
        return self.descriptor.describe(images)
