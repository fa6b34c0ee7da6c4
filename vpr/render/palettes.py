"""Colours and noise shared by the world's surfaces and its objects."""
from __future__ import annotations

import cv2
import numpy as np

__all__ = ["FACADE_PALETTE", "VIVID", "CORRIDOR_WALLS", "smooth_noise"]

# BGR albedos
FACADE_PALETTE = np.array([
    [0.22, 0.30, 0.52],  # red brick
    [0.50, 0.64, 0.76],  # sandstone
    [0.80, 0.82, 0.83],  # white render
    [0.52, 0.53, 0.54],  # grey concrete
    [0.72, 0.60, 0.48],  # pastel blue
    [0.46, 0.74, 0.84],  # pastel yellow
    [0.28, 0.28, 0.30],  # dark stone
    [0.50, 0.62, 0.52],  # sage
    [0.40, 0.48, 0.66],  # terracotta
], np.float32)
VIVID = np.array([[0.15, 0.15, 0.70], [0.20, 0.55, 0.15], [0.65, 0.35, 0.10], [0.10, 0.70, 0.85],
                   [0.45, 0.15, 0.45], [0.10, 0.10, 0.10]], np.float32)
CORRIDOR_WALLS = np.array([[0.78, 0.86, 0.88], [0.70, 0.80, 0.70], [0.82, 0.74, 0.62], [0.80, 0.80, 0.80],
                            [0.62, 0.78, 0.86]], np.float32)


def smooth_noise(rng, shape, scale):
    """Value noise with feature size ~``scale`` pixels, zero mean, unit-ish std."""
    h, w = shape
    sh, sw = max(2, int(np.ceil(h / scale)) + 2), max(2, int(np.ceil(w / scale)) + 2)
    small = rng.standard_normal((sh, sw)).astype(np.float32)
    big = cv2.resize(small, (int(sw * scale), int(sh * scale)), interpolation=cv2.INTER_CUBIC)
    return big[:h, :w]
