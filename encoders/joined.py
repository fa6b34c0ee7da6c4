"""Joined encoders: the SDRs of several encoders side by side in one SDR.

``encoders.get("pixel+cnn", **conf)`` builds a :class:`JoinedEncoder` whose
parts are ``pixel`` and ``cnn``. Its SDR is the horizontal concatenation of the
parts' SDRs (``n_bits`` = the sum of the parts' widths, active bits = the sum
of their ``k``), so a place is recognised when any of the parts' descriptors
still matches: on Nordland's 64x32 frames the CNN part fails and the pixel part
carries the match, on camera images the CNN part adds invariance (see
``research/docs/experiments.md``, "Default preset").

Configuration
-------------
``PART.key=value`` sets ``key`` of one part (``pixel.k=100``, ``cnn.n_bits=1024``);
a key without a prefix is given to every part (``standardise=fit``) and must
be known to all of them. ``conf["standardise"]`` reads ``"fit"`` when any
part fits, so callers that check it fit the joined encoder on each traverse.
A part named twice (``pixel+pixel``) is addressed as
``pixel``, ``pixel#2``. Unless set, the parts share the width of one encoder's
default SDR and its density: ``n_bits`` is 2,048 split evenly and ``k`` is each
part's default ``k`` divided by the number of parts (rounded up), so the joined
SDR fits the sequence memory's default ``n_inputs`` of 2,048.
``describe`` (joined key) chooses the dense descriptor:

- ``"balanced"`` (default): every part's descriptor L2-normalised per frame and
  divided by sqrt(number of parts), then concatenated. The joined descriptor
  has unit norm and each part contributes equally to a cosine similarity,
  which is what SeqSLAM on the encoder's descriptors (``seqslam-desc``) and
  ``pairwise`` on descriptors need; without it the 2,048 patch-normalised pixels
  (norm ~45) would drown the unit-norm CNN descriptor. Each part's SDR is
  computed from its block, which changes it only by a per-frame scale: top-k is
  unaffected by it, and the per-dimension standardisation of
  ``standardise="fit"`` nearly so (patch-normalised pixels and L2-normalised
  CNN features have an almost constant norm).
- ``"raw"``: the parts' descriptors concatenated as they are; the parts' SDRs
  are then exactly those of the parts alone.

Parts without a dense descriptor (e.g. ``orb``) make the joined encoder
descriptor-less: :meth:`JoinedEncoder.describe` raises, and :meth:`encode`
encodes every part from the images.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

from .base import BaseEncoder, DescriptorEncoder, as_image_list, check_descriptors

__all__ = ["JoinedEncoder", "DescribedJoinedEncoder", "joined_class", "split_name"]

_DESCRIBE = ("balanced", "raw")
#: SDR width the parts share unless ``n_bits`` is set (the sequence memory's default ``n_inputs``)
TOTAL_BITS = 2048


def split_name(name: str) -> tuple[list[str], list[str]]:
    """``"pixel+cnn"`` -> (part encoder names, conf prefixes), e.g. ``(["pixel", "cnn"], ["pixel", "cnn"])``.

    Raises
    ------
    ValueError
        Fewer than two parts or an empty part (``"pixel+"``).
    """
    parts = [p.strip() for p in str(name).split("+")]
    if len(parts) < 2 or not all(parts):
        raise ValueError(f"joined encoder {name!r}: expected two or more encoder names joined by '+', "
                         f"e.g. 'pixel+cnn'")
    prefixes, seen = [], {}
    for p in parts:
        seen[p] = seen.get(p, 0) + 1
        prefixes.append(p if seen[p] == 1 else f"{p}#{seen[p]}")
    return parts, prefixes


def joined_class(name: str) -> type[JoinedEncoder]:
    """A :class:`JoinedEncoder` subclass bound to the parts of ``name`` (``"pixel+cnn"``).

    ``encoders.get_class("pixel+cnn")(**conf)`` then works like any registered
    encoder class. Unknown part names raise ValueError (from the registry).
    """
    from . import get_class  # lazy: the registry imports this module

    parts, _ = split_name(name)
    classes = [get_class(p) for p in parts]  # raises for an unknown part, listing the known ones
    # only when every part has a dense descriptor is the joined encoder a DescriptorEncoder
    described = all(issubclass(c, DescriptorEncoder) for c in classes)
    base = DescribedJoinedEncoder if described else JoinedEncoder
    return type(base.__name__ + "_" + "_".join(parts), (base,), {"parts": tuple(parts), "name": "+".join(parts)})


class JoinedEncoder(BaseEncoder):
    """Concatenation of the SDRs (and dense descriptors) of several encoders.

    Use :func:`joined_class` or ``encoders.get("pixel+cnn", ...)``; see the
    module docstring for the conf keys.

    Attributes
    ----------
    encoders : list of BaseEncoder
        The parts, in the order of the name.
    prefixes : list of str
        Conf prefix of each part.
    """

    #: part encoder names, set by :func:`joined_class`
    parts: tuple = ()
    name = "joined"
    default_conf = {"describe": "balanced"}

    def __init__(self, **conf):
        import encoders  # the registry imports this module: a top-level import would be circular

        if len(self.parts) < 2:
            raise ValueError("JoinedEncoder needs parts: use encoders.get('pixel+cnn', ...) or joined_class()")
        names, prefixes = split_name("+".join(self.parts))
        classes = [encoders.get_class(n) for n in names]
        own = {k: conf[k] for k in conf if k in self.default_conf}
        shared = {k: v for k, v in conf.items() if "." not in k and k not in self.default_conf}
        per_part: dict = {p: {} for p in prefixes}
        for key, value in conf.items():
            if "." not in key:
                continue
            prefix, _, sub = key.partition(".")
            if prefix not in per_part or not sub:
                raise ValueError(f"{self.name}: conf key {key!r} names no part; parts: {prefixes} "
                                 f"(e.g. {prefixes[0]}.k=100)")
            per_part[prefix][sub] = value
        n = len(names)
        part_confs = []
        for i, (cls, prefix) in enumerate(zip(classes, prefixes, strict=True)):
            defaults = {}
            for c in reversed(cls.__mro__):
                defaults.update(getattr(c, "default_conf", {}) or {})
            unknown = sorted(k for k in shared if k not in defaults)
            if unknown:
                raise ValueError(f"{self.name}: conf key(s) {unknown} without a part prefix must be known to "
                                 f"every part, {prefix!r} does not know them; use {prefix}.KEY=VALUE for one part")
            pc = {}
            # one encoder's default width and density, shared out over the parts
            if "n_bits" in defaults:
                pc["n_bits"] = TOTAL_BITS // n + (TOTAL_BITS % n if i == n - 1 else 0)
            if "k" in defaults:
                pc["k"] = max(1, math.ceil(int(defaults["k"]) / n))
            pc.update(shared)
            pc.update(per_part[prefix])
            part_confs.append(pc)
        super().__init__(**own)
        if self.conf["describe"] not in _DESCRIBE:
            raise ValueError(f"{self.name}: describe must be one of {_DESCRIBE}, got {self.conf['describe']!r}")
        self.prefixes = prefixes
        self.encoders = []
        for cls, pc, prefix in zip(classes, part_confs, prefixes, strict=True):
            try:
                self.encoders.append(cls(**pc))
            except ValueError as e:  # name the part: "pixel+cnn: part pixel (pixel.KEY): k must be ..."
                raise ValueError(f"{self.name}: part {prefix} ({prefix}.KEY): {e}") from e
        # the full configuration, flat as given on the command line, for config.json and caches
        for prefix, enc in zip(prefixes, self.encoders, strict=True):
            for k, v in enc.conf.items():
                self.conf[f"{prefix}.{k}"] = v
        # callers decide whether to fit a traverse by conf["standardise"] == "fit";
        # fitting a part that does not standardise is harmless, so "fit" if any part needs it. Passing
        # the conf back to get() gives the same encoder: the part keys override this shared one.
        std = [e.conf["standardise"] for e in self.encoders if "standardise" in e.conf]
        if std and ("fit" in std or len(set(std)) == 1):
            self.conf["standardise"] = "fit" if "fit" in std else std[0]
        self._dims: list[int] | None = None

    def check_memory(self, n_frames: int) -> None:
        """Each part's arrays must fit (the message names the part's option, ``pixel.n_bits``)."""
        for prefix, enc in zip(self.prefixes, self.encoders, strict=True):
            try:
                enc.check_memory(n_frames)
            except ValueError as e:
                raise ValueError(str(e).replace("--encoder-conf ", f"--encoder-conf {prefix}.", 1)) from None

    # ----------------------------------------------------------------- SDRs
    @property
    def n_bits(self) -> int:
        """Sum of the parts' SDR widths."""
        return sum(e.n_bits for e in self.encoders)

    @property
    def offsets(self) -> list[int]:
        """First bit of each part in the joined SDR."""
        return [int(v) for v in np.cumsum([0] + [e.n_bits for e in self.encoders[:-1]])]

    def describe(self, images) -> np.ndarray:
        bad = [p for p, e in zip(self.prefixes, self.encoders, strict=True) if not isinstance(e, DescriptorEncoder)]
        raise NotImplementedError(f"encoder {self.name!r} has no dense descriptor: part(s) {bad} have none")

    def fit(self, images) -> JoinedEncoder:
        """Fit every part on ``images``. Returns self."""
        frames = as_image_list(images)
        for e in self.encoders:
            e.fit(frames)
        return self

    def encode(self, images) -> sp.csr_matrix:
        """Joined SDR batch, bool CSR (frames, :attr:`n_bits`)."""
        frames = as_image_list(images)
        return sp.hstack([e.encode(frames) for e in self.encoders], format="csr", dtype=bool)

    def __repr__(self) -> str:
        inner = ", ".join(f"{p}={e!r}" for p, e in zip(self.prefixes, self.encoders, strict=True))
        return f"JoinedEncoder[{self.name}](describe={self.conf['describe']!r}, {inner})"


class DescribedJoinedEncoder(JoinedEncoder, DescriptorEncoder):
    """A :class:`JoinedEncoder` whose parts all have a dense descriptor: a :class:`DescriptorEncoder` too.

    A pipeline describes each frame once, fits on the traverse's descriptors
    and keeps them for ``seqslam-desc`` or ``pairwise`` on descriptors. Each
    part's block of the joined descriptor has its own statistics.
    """

    @property
    def dims(self) -> list[int]:
        """Descriptor length of each part (the parts' ``dim``, else one tiny describe)."""
        if self._dims is None:
            dims = []
            for e in self.encoders:
                d = getattr(e, "dim", None)
                if not isinstance(d, (int, np.integer)):
                    d = e.describe([np.zeros((64, 64, 3), np.uint8)]).shape[1]
                dims.append(int(d))
            self._dims = dims
        return self._dims

    @property
    def dim(self) -> int:
        """Length of the joined dense descriptor."""
        return sum(self.dims)

    def join_descriptors(self, part_descs) -> np.ndarray:
        """Joined descriptor from each part's own ``describe`` output (a list, in part order).

        Lets a caller that cached the parts' descriptors build the joined one
        without recomputing them.
        """
        if len(part_descs) != len(self.encoders):
            raise ValueError(f"{self.name}: expected {len(self.encoders)} descriptor arrays, got {len(part_descs)}")
        blocks = [check_descriptors(d, name=f"descriptors of part {p!r}")
                  for p, d in zip(self.prefixes, part_descs, strict=True)]
        if len({b.shape[0] for b in blocks}) != 1:
            raise ValueError(f"{self.name}: the parts' descriptors have different frame counts "
                             f"{[b.shape[0] for b in blocks]}")
        self._dims = [b.shape[1] for b in blocks]
        if self.conf["describe"] == "balanced":
            scale = 1.0 / math.sqrt(len(blocks))
            blocks = [b * (scale / np.maximum(np.linalg.norm(b, axis=1, keepdims=True), 1e-12)) for b in blocks]
        return np.concatenate(blocks, axis=1).astype(np.float32, copy=False)

    def split_descriptors(self, desc) -> list[np.ndarray]:
        """The joined descriptor cut back into the parts' blocks (views)."""
        d = check_descriptors(desc, name=f"{self.name} descriptors", dim=self.dim)
        return np.split(d, np.cumsum(self.dims)[:-1], axis=1)

    def describe(self, images) -> np.ndarray:
        """Joined dense descriptor, float32 (frames, sum of the parts' dims); see ``describe`` in the conf."""
        frames = as_image_list(images)
        return self.join_descriptors([e.describe(frames) for e in self.encoders])

    def fit_descriptors(self, desc) -> DescribedJoinedEncoder:
        """Fit every part on its block of ``desc`` (the parts' ``standardise="fit"``). Returns self."""
        for e, block in zip(self.encoders, self.split_descriptors(desc), strict=True):
            e.fit_descriptors(block)
        return self

    def encode_descriptors(self, desc, statistics: list | None = None) -> sp.csr_matrix:
        """Joined SDR batch from a joined descriptor, without recomputing the descriptors.

        ``statistics``: one (mean, std) per part, overriding the fitted ones for this call.
        """
        blocks = self.split_descriptors(desc)
        if statistics is not None and len(statistics) != len(blocks):
            raise ValueError(f"{self.name}: expected the statistics of {len(blocks)} parts, got {len(statistics)}")
        stats = [None] * len(blocks) if statistics is None else [[s] for s in statistics]
        return sp.hstack([e.encode_descriptors(b, st) for e, b, st in zip(self.encoders, blocks, stats, strict=True)],
                         format="csr", dtype=bool)

    def blocks(self, desc) -> list[np.ndarray]:
        return self.split_descriptors(desc)

    def statistics(self) -> list[tuple[np.ndarray, np.ndarray]]:
        parts = [e.statistics() for e in self.encoders]
        return [s for p in parts for s in p] if all(parts) else []

    def set_statistics(self, stats: list) -> DescribedJoinedEncoder:
        if len(stats) != len(self.encoders):
            raise ValueError(f"{self.name}: expected the statistics of {len(self.encoders)} parts, got {len(stats)}")
        for e, st in zip(self.encoders, stats, strict=True):
            e.set_statistics([st])
        return self

    def fit(self, images) -> DescribedJoinedEncoder:
        """Fit every part on ``images``, describing them once. Returns self."""
        return self.fit_descriptors(self.describe(images))

    def encode(self, images) -> sp.csr_matrix:
        return self.encode_descriptors(self.describe(images))
