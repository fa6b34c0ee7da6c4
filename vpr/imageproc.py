"""Image normalisation shared by encoders, SeqSLAM and the renderer's checks.

Images are NumPy arrays in OpenCV's layout: (H, W) grey or (H, W, 3) BGR or (H, W, 4) BGRA; uint8 or uint16 (scaled
down to 8 bit) or float in [0, 1].
"""
from __future__ import annotations

import cv2
import numpy as np

__all__ = ["to_uint8", "to_grey", "to_bgr", "resize", "patch_normalise", "seqslam_preprocess",
           "seqslam_descriptors", "depth_bits"]


def depth_bits(img) -> int:
    """The bits a 16-bit image uses: 10, 12, 14 or 16, the fewest that hold its largest value (a 12-bit camera's
    frames are stored in 16 bits)."""
    top = int(np.max(img)) if np.size(img) else 0
    return next((b for b in (10, 12, 14) if top < (1 << b)), 16)


def to_uint8(img, name: str = "image", bits: int | None = None) -> np.ndarray:
    """Validate ``img`` and convert it to uint8 with 1, 3 or 4 channels (last axis).

    16-bit images are scaled from ``bits`` bits (default :func:`depth_bits`). Empty, wrong rank, channels or dtype, or
    NaN raise ValueError starting with ``name``.
    """
    a = np.asarray(img)
    if a.size == 0:
        raise ValueError(f"{name}: empty image (shape {a.shape})")
    if a.ndim not in (2, 3):
        raise ValueError(f"{name}: expected a 2-D grey or 3-D colour image, got shape {a.shape}")
    if a.ndim == 3 and a.shape[2] not in (1, 3, 4):
        raise ValueError(f"{name}: expected 1, 3 or 4 channels, got {a.shape[2]}")
    if a.dtype == np.uint8:
        return a
    if a.dtype == np.uint16:
        return np.minimum(a >> ((bits or depth_bits(a)) - 8), 255).astype(np.uint8)
    if a.dtype == bool:
        return a.astype(np.uint8) * 255
    if a.dtype.kind == "f":
        if not np.isfinite(a).all():
            raise ValueError(f"{name}: NaN or infinite pixel values")
        return np.clip(np.round(a * 255.0), 0, 255).astype(np.uint8)
    if a.dtype.kind in "iu":
        if a.min() < 0 or a.max() > 255:
            raise ValueError(f"{name}: integer pixel values outside 0..255 (dtype {a.dtype})")
        return a.astype(np.uint8)
    raise ValueError(f"{name}: unsupported pixel dtype {a.dtype}")


def to_grey(img, name: str = "image") -> np.ndarray:
    """uint8 grey (H, W) from grey, BGR or BGRA input of any supported dtype."""
    a = to_uint8(img, name)
    if a.ndim == 2:
        return a
    if a.shape[2] == 1:
        return a[:, :, 0]
    code = cv2.COLOR_BGR2GRAY if a.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
    return cv2.cvtColor(a, code)


def to_bgr(img, name: str = "image", bits: int | None = None) -> np.ndarray:
    """uint8 BGR (H, W, 3) from grey, BGR or BGRA input of any supported dtype (``bits``: :func:`to_uint8`)."""
    a = to_uint8(img, name, bits)
    if a.ndim == 2 or a.shape[2] == 1:
        return cv2.cvtColor(a.reshape(a.shape[0], a.shape[1]), cv2.COLOR_GRAY2BGR)
    if a.shape[2] == 4:
        return cv2.cvtColor(a, cv2.COLOR_BGRA2BGR)
    return a


def resize(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize to ``size`` = (width, height); area interpolation when shrinking."""
    w, h = int(size[0]), int(size[1])
    if img.shape[1] == w and img.shape[0] == h:
        return img
    shrink = w < img.shape[1] or h < img.shape[0]
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


def patch_normalise(grey: np.ndarray, patch: int = 8) -> np.ndarray:
    """Normalise each non-overlapping ``patch`` x ``patch`` block to zero mean, unit std.

    As in OpenSeqSLAM's patch normalisation; flat blocks become 0. Borders that do not fill a whole block are
    normalised as a smaller block. ``grey`` is one image (H, W) or a stack (N, H, W) of equal-size images, normalised
    image by image in one vectorised pass. Returns float32 of the same shape.
    """
    g = np.asarray(grey, dtype=np.float32)
    if g.ndim not in (2, 3):
        raise ValueError(f"patch_normalise: expected (H, W) or (N, H, W), got shape {g.shape}")
    single = g.ndim == 2
    if single:
        g = g[None]
    n, h, w = g.shape
    out = np.empty_like(g)
    hh, ww = (h // patch) * patch, (w // patch) * patch
    if hh and ww:
        blocks = g[:, :hh, :ww].reshape(n, hh // patch, patch, ww // patch, patch)
        mu = blocks.mean(axis=(2, 4), keepdims=True)
        sd = blocks.std(axis=(2, 4), keepdims=True)
        nb = np.where(sd > 1e-6, (blocks - mu) / np.maximum(sd, 1e-6), 0.0)
        out[:, :hh, :ww] = nb.reshape(n, hh, ww)
    # ragged borders (rare: only when the size is not a multiple of the patch)
    for ys, xs in ((slice(hh, h), slice(0, w)), (slice(0, hh), slice(ww, w))):
        if ys.stop > ys.start and xs.stop > xs.start:
            for i in range(n):
                for y0 in range(ys.start, ys.stop, patch):
                    for x0 in range(xs.start, xs.stop, patch):
                        b = g[i, y0:min(y0 + patch, ys.stop), x0:min(x0 + patch, xs.stop)]
                        s = b.std()
                        out[i, y0:y0 + b.shape[0], x0:x0 + b.shape[1]] = (b - b.mean()) / s if s > 1e-6 else 0.0
    return out[0] if single else out


def seqslam_preprocess(img, size: tuple[int, int] = (64, 32), patch: int = 8,
                       name: str = "image") -> np.ndarray:
    """OpenSeqSLAM's image preprocessing: grey, resize to ``size`` (w, h), patch-normalise.

    Returns a float32 (h, w) array; equal to one row of :func:`seqslam_descriptors`.
    """
    return patch_normalise(resize(to_grey(img, name), size), patch)


def seqslam_descriptors(images, size: tuple[int, int] = (64, 32), patch: int = 8,
                        name: str = "images") -> np.ndarray:
    """The SeqSLAM pixel descriptor of every image: :func:`seqslam_preprocess` flattened row-major.

    The one implementation behind the ``pixel`` encoder and SeqSLAM on images. ``images``: any layout :func:`to_grey`
    takes, each resized to ``size`` (width, height), normalised in ``patch`` blocks. Returns float32 (n_images, width
    * height); no images or an invalid one raise ValueError naming ``name[i]``.
    """
    w, h = int(size[0]), int(size[1])
    thumbs = [resize(to_grey(im, f"{name}[{i}]"), (w, h)) for i, im in enumerate(images)]
    if not thumbs:
        raise ValueError(f"{name}: no images")
    return patch_normalise(np.stack(thumbs), patch).reshape(len(thumbs), w * h)
