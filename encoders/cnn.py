"""ONNX CNN descriptor, sparsified by random-projection top-k.

Any ONNX image model with one 4-D float input (N, 3, H, W) runs through
onnxruntime; the chosen output, a feature map (N, C, h, w), is pooled to a
C-dim descriptor (GeM by default, or average / max) and L2-normalised. An
output that is already 2-D (N, D) is used as the descriptor without pooling.
:meth:`CnnEncoder.encode` sparsifies the descriptor with
:class:`encoders.projection.TopKProjection`.

The default model is EfficientNet-Lite0 with ImageNet weights truncated after
block 10 (stride 16, 112 channels), exported by
``encoders/models/export_efficientnet_lite0.py`` (licence in
``encoders/models/NOTICE.md``). Its preprocessing is the one of the
``efficientnet-lite-pytorch`` package's example: RGB in [0, 1] normalised with
the ImageNet mean / std. Images arrive as BGR (or grey) uint8 and are converted
to RGB, resized to ``input_size`` and normalised with ``mean`` / ``std``
(given in RGB order on the [0, 1] scale).

Only onnxruntime is needed at run time; ``threads`` sets its intra-op thread
count (1 for the one-thread benchmark).

Pooled features of an ImageNet network share a large component common to all
images, so with ``standardise="none"`` the SDRs of different places overlap
almost as much as those of the same place; per-traverse standardisation
(``standardise="fit"``, then ``fit`` on the traverse before encoding it)
removes it and is recommended (measured by the encoder study, ``vpr encoders test``).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from vpr.imageproc import to_bgr
from vpr.interrupts import import_held

from .base import as_image_list
from .projection import ProjectedEncoder

__all__ = ["CnnEncoder", "DEFAULT_MODEL", "shrink_image"]

DEFAULT_MODEL = Path(__file__).resolve().parent / "models" / "efficientnet_lite0_block10.onnx"
_POOLING = ("gem", "avg", "max")


def shrink_image(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize to ``size`` (w, h): area halvings while >= 2x the target, then bilinear.

    OpenCV's area resampling is fast for exact factors of 2 but several times
    slower for arbitrary ones; after the halvings the remaining factor is below
    2, where bilinear sampling already touches every source pixel, so the
    result stays close to a one-step area shrink (the tests bound the
    difference) at a fraction of the cost.
    """
    w, h = size
    while img.shape[1] >= 2 * w and img.shape[0] >= 2 * h:
        img = cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2), interpolation=cv2.INTER_AREA)
    if img.shape[1] == w and img.shape[0] == h:
        return img
    # one side may still be >= 2x on very elongated images: area there
    interp = cv2.INTER_LINEAR if img.shape[1] < 2 * w and img.shape[0] < 2 * h else cv2.INTER_AREA
    return cv2.resize(img, (w, h), interpolation=interp)


class CnnEncoder(ProjectedEncoder):
    """Pooled ONNX CNN features, sparsified by random-projection top-k.

    Conf (besides the projection keys ``n_bits``, ``k``, ``seed``,
    ``two_sided``, ``standardise``):

    model : str
        Path of the ONNX file; empty for the bundled EfficientNet-Lite0.
    output : str
        Output name; empty for the model's first output.
    input_size : (int, int)
        (width, height) the images are resized to.
    mean, std : (float, float, float)
        RGB normalisation on the [0, 1] scale.
    pooling : {"gem", "avg", "max"}
    gem_p : float
        GeM exponent (p = 1 is average pooling of the clamped map).
    normalise : bool
        L2-normalise the pooled descriptor.
    threads : int
        onnxruntime intra-op threads.
    batch_size : int
        Frames per onnxruntime call (1 was fastest on one thread).
    """

    name = "cnn"
    default_conf = {
        "model": "",
        "output": "",
        "input_size": (224, 224),
        "mean": (0.485, 0.456, 0.406),
        "std": (0.229, 0.224, 0.225),
        "pooling": "gem",
        "gem_p": 3.0,
        "normalise": True,
        "threads": 1,
        "batch_size": 1,
    }

    def __init__(self, **conf):
        super().__init__(**conf)
        ort = import_held("onnxruntime")  # its extension turns a Ctrl-C while it loads into an ImportError

        c = self.conf
        if c["pooling"] not in _POOLING:
            raise ValueError(f"cnn: pooling must be one of {_POOLING}, got {c['pooling']!r}")
        if c["gem_p"] <= 0:
            raise ValueError(f"cnn: gem_p must be positive, got {c['gem_p']}")
        if len(c["input_size"]) != 2 or min(c["input_size"]) < 1:
            raise ValueError(f"cnn: input_size must be (width, height), got {c['input_size']}")
        if len(c["mean"]) != 3 or len(c["std"]) != 3 or min(c["std"]) <= 0:
            raise ValueError(f"cnn: mean and std need 3 values (std > 0), got {c['mean']}, {c['std']}")
        if c["threads"] < 1 or c["batch_size"] < 1:
            raise ValueError("cnn: threads and batch_size must be >= 1")
        path = Path(c["model"]) if c["model"] else DEFAULT_MODEL
        if not path.is_file():
            raise ValueError(f"cnn: model file not found: {path}")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = c["threads"]
        opts.inter_op_num_threads = 1
        opts.log_severity_level = 3
        try:
            self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        except Exception as e:  # onnxruntime raises its own exception types
            raise ValueError(f"cnn: cannot load ONNX model {path}: {e}") from e
        inputs = self.session.get_inputs()
        if len(inputs) != 1:
            raise ValueError(f"cnn: model {path.name} must have exactly one input, has {len(inputs)}")
        inp = inputs[0]
        if len(inp.shape) != 4:
            raise ValueError(f"cnn: model input {inp.name!r} must be 4-D (N, 3, H, W), got shape {inp.shape}")
        if inp.type != "tensor(float)":
            raise ValueError(f"cnn: model input {inp.name!r} must be float32, got {inp.type}")
        if isinstance(inp.shape[1], int) and inp.shape[1] != 3:
            raise ValueError(f"cnn: model input {inp.name!r} must have 3 channels, got {inp.shape[1]}")
        w, h = c["input_size"]
        for axis, want in ((2, h), (3, w)):
            if isinstance(inp.shape[axis], int) and inp.shape[axis] != want:
                raise ValueError(f"cnn: model input is fixed to {inp.shape[2]}x{inp.shape[3]} (HxW) "
                                 f"but input_size is {w}x{h} (WxH)")
        names = [o.name for o in self.session.get_outputs()]
        out = c["output"] or names[0]
        if out not in names:
            raise ValueError(f"cnn: unknown output {out!r}; the model's outputs are {names}")
        self.model_path, self.input_name, self.output_name = path, inp.name, out
        std = np.asarray(c["std"], np.float32)
        # (v / 255 - mean) / std as one multiply-add per RGB channel
        self._scale = 1.0 / (255.0 * std)
        self._offset = -np.asarray(c["mean"], np.float32) / std

    def preprocess(self, frames: list[np.ndarray]) -> np.ndarray:
        """uint8 frames -> normalised float32 RGB batch (N, 3, H, W)."""
        size = tuple(self.conf["input_size"])
        bgr = np.stack([shrink_image(to_bgr(f, f"images[{i}]"), size) for i, f in enumerate(frames)])
        x = np.empty((len(frames), 3, size[1], size[0]), np.float32)
        # plane by plane: BGR -> RGB, channel-first and (v / 255 - mean) / std in one pass each
        for c in range(3):
            np.multiply(bgr[..., 2 - c], self._scale[c], out=x[:, c])
            x[:, c] += self._offset[c]
        return x

    def pool(self, fmap: np.ndarray) -> np.ndarray:
        """Pool an (N, C, h, w) map (or pass an (N, D) output) to float32 (N, C)."""
        fmap = np.asarray(fmap, np.float32)
        if fmap.ndim == 2:
            d = fmap
        elif fmap.ndim == 4:
            flat = fmap.reshape(fmap.shape[0], fmap.shape[1], -1)
            pooling = self.conf["pooling"]
            if pooling == "avg":
                d = flat.mean(axis=2)
            elif pooling == "max":
                d = flat.max(axis=2)
            else:
                p = self.conf["gem_p"]
                d = np.power(np.power(np.maximum(flat, 1e-6), p).mean(axis=2), 1.0 / p)
        else:
            raise ValueError(f"cnn: output {self.output_name!r} has shape {fmap.shape}; "
                             "expected (N, C, h, w) or (N, D)")
        if self.conf["normalise"]:
            d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        return d.astype(np.float32)

    def describe(self, images) -> np.ndarray:
        """Pooled (and L2-normalised) CNN features, float32 (frames, channels)."""
        frames = as_image_list(images)
        bs = self.conf["batch_size"]
        out = []
        for s in range(0, len(frames), bs):
            x = self.preprocess(frames[s:s + bs])
            fmap = self.session.run([self.output_name], {self.input_name: x})[0]
            out.append(self.pool(fmap))
        return np.concatenate(out, axis=0)

    @property
    def dim(self) -> int:
        """Descriptor length (the output's channel count), from a tiny forward pass."""
        w, h = self.conf["input_size"]
        return self.describe([np.zeros((h, w, 3), np.uint8)]).shape[1]
