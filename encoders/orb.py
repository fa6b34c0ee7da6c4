"""Sparsified ORB / BRIEF: binary local descriptors -> LSH votes -> top-k SDR.

Two ways to get 256-bit binary descriptors from OpenCV's ORB:

- ``mode="keypoints"``: ORB's own FAST keypoints over its scale pyramid, with
  their orientation (rotation-invariant ORB).
- ``mode="grid"``: BRIEF-style, upright descriptors on a fixed grid. OpenCV's
  contrib BRIEF is not in opencv-python-headless, so these are ORB
  descriptors computed at ``grid`` = (columns, rows) fixed keypoints with
  angle 0 on a single pyramid level. Every image gives the same number of
  descriptors, so blank or low-texture images still vote.

Image size: ORB needs room for its 31-pixel patches, so images are rescaled to
a working size. In keypoint mode an image whose longer side exceeds
``max_side`` is shrunk to it (speed) and one whose shorter side is below
``min_side`` is enlarged to it (a 64 x 32 thumbnail has almost no FAST corners
otherwise). In grid mode every image is resized to ``grid_size`` (w, h) and
padded by reflection so the grid can reach the borders.

Sparsification: bit-sampling locality-sensitive hashing. Table ``t`` reads
``hash_bits`` fixed, seeded bit positions of a descriptor; descriptors within
a small Hamming distance fall into the same bucket of a table with high
probability. The bucket key, the table index and (unless ``cells`` is (1, 1))
the keypoint's coarse image cell are hashed to one of ``n_bits`` bins; every
descriptor votes once per table. The ``k`` bins with most votes are the SDR.
Ties go to the lower bin index; since bins are hashed keys, this is a fixed
pseudo-random order shared by all images, so among equal votes both of two
images keep the same buckets (as in min-hashing).

Rows with fewer than ``k`` voted bins (few keypoints) keep only the voted
bins, and an image with no keypoint at all (blank, in keypoint mode) gives an
**empty row**, which overlaps nothing. All other rows have exactly ``k`` bits.
"""
from __future__ import annotations

import cv2
import numpy as np
import scipy.sparse as sp

from vpr.imageproc import to_grey

from .base import BaseEncoder, as_image_list

__all__ = ["OrbEncoder"]

_MODES = ("keypoints", "grid")


def _mix64(x: np.ndarray) -> np.ndarray:
    """splitmix64 finaliser: a well-spread 64-bit hash of uint64 keys."""
    with np.errstate(over="ignore"):
        x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return x ^ (x >> np.uint64(31))


class OrbEncoder(BaseEncoder):
    """ORB or grid-BRIEF descriptors hashed into an SDR.

    Conf
    ----
    mode : {"keypoints", "grid"}
    n_features : int
        ORB keypoint budget (keypoint mode).
    fast_threshold : int
        FAST corner threshold (keypoint mode); lower finds more corners on
        low-contrast images.
    n_levels, scale_factor : int, float
        ORB scale pyramid (keypoint mode); fewer levels are faster.
    max_side, min_side : int
        Working-size limits in keypoint mode (see module docstring).
    grid : (int, int)
        Grid columns and rows (grid mode).
    grid_size : (int, int)
        Working (w, h) in grid mode.
    n_tables, hash_bits : int
        LSH tables and bits sampled per table (<= 63).
    cells : (int, int)
        Coarse cells (columns, rows) combined with the hash; (1, 1) ignores
        where a descriptor was found.
    n_bits, k, seed : int
        SDR width, active bits, seed of the bit sampling and bin hash.
    """

    name = "orb"
    default_conf = {
        "mode": "keypoints",
        "n_features": 500,
        "fast_threshold": 20,
        "n_levels": 4,
        "scale_factor": 1.2,
        "max_side": 640,
        "min_side": 240,
        "grid": (16, 8),
        "grid_size": (256, 128),
        "n_tables": 8,
        "hash_bits": 8,
        "cells": (8, 4),
        "n_bits": 2048,
        "k": 40,
        "seed": 0,
    }

    _PATCH = 31

    def __init__(self, **conf):
        super().__init__(**conf)
        c = self.conf
        if c["mode"] not in _MODES:
            raise ValueError(f"orb: mode must be one of {_MODES}, got {c['mode']!r}")
        if not 1 <= c["hash_bits"] <= 63:
            raise ValueError(f"orb: hash_bits must be in [1, 63], got {c['hash_bits']}")
        if c["scale_factor"] <= 1.0:
            raise ValueError(f"orb: scale_factor must be > 1, got {c['scale_factor']}")
        for key in ("n_tables", "n_features", "n_bits", "max_side", "min_side", "n_levels"):
            if c[key] < 1:
                raise ValueError(f"orb: {key} must be >= 1, got {c[key]}")
        for key in ("grid", "cells", "grid_size"):
            if len(c[key]) != 2 or min(c[key]) < 1:
                raise ValueError(f"orb: {key} must be two positive integers, got {c[key]}")
        if c["min_side"] > c["max_side"]:
            raise ValueError(f"orb: min_side {c['min_side']} > max_side {c['max_side']}")
        if not 1 <= c["k"] <= c["n_bits"]:
            raise ValueError(f"orb: k must be in [1, {c['n_bits']}], got {c['k']}")
        rng = np.random.default_rng(c["seed"])
        self._positions = np.stack([rng.choice(256, c["hash_bits"], replace=False)
                                    for _ in range(c["n_tables"])])
        self._salt = np.uint64(rng.integers(0, 2**63, dtype=np.int64))
        if c["mode"] == "keypoints":
            self._orb = cv2.ORB_create(nfeatures=c["n_features"], scaleFactor=c["scale_factor"],
                                       nlevels=c["n_levels"], fastThreshold=c["fast_threshold"],
                                       edgeThreshold=self._PATCH, patchSize=self._PATCH)
        else:
            # a single level: the grid keypoints are all at scale 0
            self._orb = cv2.ORB_create(nfeatures=c["grid"][0] * c["grid"][1], nlevels=1,
                                       edgeThreshold=self._PATCH, patchSize=self._PATCH)
            gw, gh = c["grid_size"]
            gx, gy = c["grid"]
            # cell centres of the grid in the unpadded working image
            xs = (np.arange(gx) + 0.5) * gw / gx
            ys = (np.arange(gy) + 0.5) * gh / gy
            self._grid_xy = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)

    @property
    def n_bits(self) -> int:
        return self.conf["n_bits"]

    # -- descriptors -------------------------------------------------------

    def _keypoint_descriptors(self, grey: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = self.conf
        h, w = grey.shape
        scale = 1.0
        if max(h, w) > c["max_side"]:
            scale = c["max_side"] / max(h, w)
        elif min(h, w) < c["min_side"]:
            scale = c["min_side"] / min(h, w)
        if scale != 1.0:
            size = (max(1, round(w * scale)), max(1, round(h * scale)))
            grey = cv2.resize(grey, size, interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
        kps, des = self._orb.detectAndCompute(grey, None)
        if des is None or not kps:
            return np.zeros((0, 32), np.uint8), np.zeros((0, 2), np.float32)
        xy = np.array([kp.pt for kp in kps], dtype=np.float32) / np.array(grey.shape[::-1], np.float32)
        return des, xy

    def _grid_descriptors(self, grey: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        gw, gh = self.conf["grid_size"]
        grey = cv2.resize(grey, (gw, gh), interpolation=cv2.INTER_AREA
                          if grey.shape[1] > gw or grey.shape[0] > gh else cv2.INTER_LINEAR)
        m = self._PATCH + 2
        padded = cv2.copyMakeBorder(grey, m, m, m, m, cv2.BORDER_REFLECT_101)
        kps = [cv2.KeyPoint(float(x + m), float(y + m), self._PATCH, 0.0, 0.0, 0)
               for x, y in self._grid_xy]
        kps, des = self._orb.compute(padded, kps)
        if des is None or len(kps) != len(self._grid_xy):
            raise RuntimeError("orb: OpenCV dropped grid keypoints; the padding is too small")
        xy = (np.array([kp.pt for kp in kps], np.float32) - m) / np.array([gw, gh], np.float32)
        return des, xy

    def _votes(self, des: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """Bin index of every (descriptor, table) vote, int64 (n_desc * n_tables,)."""
        c = self.conf
        if des.shape[0] == 0:
            return np.zeros(0, np.int64)
        bits = np.unpackbits(des, axis=1)                               # (M, 256)
        sampled = bits[:, self._positions].astype(np.uint64)            # (M, T, b)
        weights = np.uint64(1) << np.arange(c["hash_bits"], dtype=np.uint64)
        keys = (sampled * weights).sum(axis=2, dtype=np.uint64)         # (M, T)
        cx, cy = c["cells"]
        cell = (np.minimum((xy[:, 0] * cx).astype(np.int64), cx - 1)
                + cx * np.minimum((xy[:, 1] * cy).astype(np.int64), cy - 1))
        table = np.arange(c["n_tables"], dtype=np.uint64)
        # (table, cell) fill the high bits above the bucket key, then all is hashed
        code = (keys | ((cell[:, None].astype(np.uint64) * np.uint64(c["n_tables"]) + table)
                        << np.uint64(c["hash_bits"])))
        return (_mix64(code ^ self._salt) % np.uint64(c["n_bits"])).astype(np.int64).ravel()

    def _all_votes(self, images) -> list[np.ndarray]:
        frames = as_image_list(images)
        extract = self._grid_descriptors if self.conf["mode"] == "grid" else self._keypoint_descriptors
        return [self._votes(*extract(to_grey(f, f"images[{i}]"))) for i, f in enumerate(frames)]

    # -- public ------------------------------------------------------------

    def describe(self, images) -> np.ndarray:
        """LSH vote histogram, float32 (frames, ``n_bits``): a bag of hashed binary words."""
        votes = self._all_votes(images)
        return np.stack([np.bincount(v, minlength=self.n_bits) for v in votes]).astype(np.float32)

    def encode(self, images) -> sp.csr_matrix:
        """SDR batch: the ``k`` most voted bins per frame (fewer only when fewer were voted)."""
        counts = self.describe(images)
        k = self.conf["k"]
        top = np.argsort(-counts, axis=1, kind="stable")[:, :k]
        keep = np.take_along_axis(counts, top, axis=1) > 0
        top = np.where(keep, top, np.iinfo(np.int64).max)
        top.sort(axis=1)
        lengths = keep.sum(axis=1)
        indptr = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
        indices = top[np.arange(k)[None, :] < lengths[:, None]].astype(np.int32)
        return sp.csr_matrix((np.ones(indices.size, bool), indices, indptr),
                             shape=(counts.shape[0], self.n_bits))
