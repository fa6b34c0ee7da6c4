"""ORB keypoints of one image and their matches (the first step of geometric verification)."""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vpr.checks import check_float, check_int
from vpr.imageproc import to_grey

__all__ = ["Keypoints", "extract_features", "match_features", "check_keypoints", "own_distances"]

_DESCRIPTOR_BYTES = 32  # ORB descriptors are 256 bits


@dataclass(frozen=True, eq=False)
class Keypoints:
    """ORB keypoints of one image: ``xy`` float64 (K, 2) in the original image's pixels, ``descriptors`` uint8
    (K, 32), ``scale`` float64 (sx, sy) from the original image to the detection frame, ``size`` the original image's
    (height, width).
    """

    xy: np.ndarray
    descriptors: np.ndarray
    scale: np.ndarray
    size: tuple[int, int] = (0, 0)

    def __len__(self) -> int:
        return int(self.xy.shape[0])

    @classmethod
    def empty(cls, scale=(1.0, 1.0), size: tuple[int, int] = (0, 0)) -> Keypoints:
        """No keypoints (a blank image, or none to read)."""
        return cls(np.zeros((0, 2)), np.zeros((0, _DESCRIPTOR_BYTES), np.uint8), np.asarray(scale, np.float64), size)

    def detection_xy(self) -> np.ndarray:
        """Keypoint positions in the detection (possibly upscaled) frame, (K, 2) float64."""
        # pixel centres: cv2.resize maps x_orig to (x_orig + 0.5) * s - 0.5
        return (self.xy + 0.5) * self.scale - 0.5


def check_keypoints(f, name: str) -> Keypoints:
    """``f`` if it is a :class:`Keypoints`, else a ValueError naming ``name``."""
    if not isinstance(f, Keypoints):
        raise ValueError(f"{name} must be a Keypoints object (see extract_features), got {type(f).__name__}")
    return f


def extract_features(image, n_features: int = 1000, min_side: int = 240, name: str = "image") -> Keypoints:
    """ORB keypoints and descriptors of a grey or BGR(A) image (:func:`vpr.imageproc.to_grey`).

    At most ``n_features`` keypoints; an image whose shorter side is below ``min_side`` is upscaled for detection and
    its keypoints mapped back (``docs/internals.md``). Returns :class:`Keypoints`, empty for a blank image; an invalid
    image raises ValueError starting with ``name``.
    """
    n_features = check_int(n_features, "n_features", 1)
    min_side = check_int(min_side, "min_side", 1)
    grey = to_grey(image, name)
    h, w = grey.shape
    if min(h, w) < min_side:
        f = min_side / min(h, w)
        size = (max(1, round(w * f)), max(1, round(h * f)))
        grey = cv2.resize(grey, size, interpolation=cv2.INTER_LINEAR)
    scale = np.array([grey.shape[1] / w, grey.shape[0] / h], dtype=np.float64)
    orb = cv2.ORB_create(nfeatures=n_features)
    keypoints, desc = orb.detectAndCompute(grey, None)
    if desc is None or len(keypoints) == 0:
        return Keypoints.empty(scale, (h, w))
    xy_det = np.array([kp.pt for kp in keypoints], dtype=np.float64).reshape(-1, 2)
    xy = (xy_det + 0.5) / scale - 0.5
    return Keypoints(xy, np.ascontiguousarray(desc, dtype=np.uint8), scale, (h, w))


def own_distances(f: Keypoints, which=None) -> np.ndarray:
    """Each keypoint's Hamming distance to the nearest other descriptor of its own image, float64 (K,) (inf: none);
    ``which``: only those keypoints' (indices), in that order.

    Small where a pattern repeats within the image (crossing stripes, tiles, a row of windows): such a keypoint matches
    wherever the pattern is, in any image.
    """
    f = check_keypoints(f, "f")
    idx = np.arange(len(f)) if which is None else np.asarray(which, np.intp).reshape(-1)
    out = np.full(idx.size, np.inf)
    if len(f) < 2 or not idx.size:
        return out
    knns = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(np.ascontiguousarray(f.descriptors[idx]), f.descriptors, k=2)
    for r, (i, knn) in enumerate(zip(idx, knns, strict=True)):
        other = [m for m in knn if m.trainIdx != i]
        if other:
            out[r] = other[0].distance
    return out


def match_features(f1: Keypoints, f2: Keypoints, ratio: float = 0.8, mutual: bool = True,
                   distinct: bool = False) -> np.ndarray:
    """Match ORB descriptors by Hamming distance with Lowe's ratio test.

    A match ``i -> j`` is kept below ``ratio`` times the distance to ``i``'s second neighbour in ``f2`` (none: kept);
    ``mutual`` also requires ``i`` to be ``j``'s nearest in ``f1``; ``distinct``: also below ``ratio`` times both
    keypoints' :func:`own_distances` (the ratio test against each keypoint's own image: a pattern repeated within an
    image matches nothing). Returns intp (M, 2) pairs ``(i, j)`` sorted by ``i``.
    """
    f1 = check_keypoints(f1, "f1")
    f2 = check_keypoints(f2, "f2")
    ratio = check_float(ratio, "ratio", 0.0, 1.0, open_min=True)
    empty = np.zeros((0, 2), dtype=np.intp)
    if len(f1) == 0 or len(f2) == 0:
        return empty
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=False)
    pairs = []
    for knn in matcher.knnMatch(f1.descriptors, f2.descriptors, k=2):
        if not knn:
            continue
        best = knn[0]
        if len(knn) > 1 and not best.distance < ratio * knn[1].distance:
            continue
        pairs.append((best.queryIdx, best.trainIdx, best.distance))
    if not pairs:
        return empty
    found = np.array(pairs)
    out, dist = found[:, :2].astype(np.intp), found[:, 2]
    if mutual:  # each matched f2 keypoint's own nearest in f1
        reverse = np.full(len(out), -1, dtype=np.intp)
        for m in matcher.match(np.ascontiguousarray(f2.descriptors[out[:, 1]]), f1.descriptors):
            reverse[m.queryIdx] = m.trainIdx
        keep = reverse == out[:, 0]
        out, dist = out[keep], dist[keep]
    if distinct and len(out):
        keep = (dist < ratio * own_distances(f1, out[:, 0])) & (dist < ratio * own_distances(f2, out[:, 1]))
        out = out[keep]
    return out[np.argsort(out[:, 0], kind="stable")]
