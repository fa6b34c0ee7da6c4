"""``vpr encoders list`` and ``vpr encoders test``: the encoders, and how one fares on the rendered scenes.

``list`` prints every registered encoder with its default conf. ``test``
scores one on the scenes (:func:`pipelines.scenes.score_encoder`: AP and R@1 of
:data:`vpr.presets.ENCODER_TEST_METHODS` for every traverse pair), prints the table and
writes ``metrics.json`` and ``metrics.png`` to ``--out``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import encoders
from pipelines.args import add_common_arguments
from pipelines.scenes import METHODS, EncoderTest, list_encoders, score_encoder
from vpr import io as _io
from vpr import render
from vpr.report import write_table

__all__ = ["COMMANDS", "add_arguments", "run_command", "format_list", "format_table"]

COMMANDS = {"encoders": "list the image encoders, or test one on the synthetic scenes (AP, R@1)"}


def format_list(confs: dict) -> str:
    """The encoders with their default confs, how to join them, and the presets that name them."""
    from vpr import presets

    width = max(len(n) for n in confs) + 2
    lines = [f"{name:{width}s}" + ", ".join(f"{k}={v!r}" for k, v in conf.items()) for name, conf in confs.items()]
    lines += ["", "joined encoders: any parts with '+', e.g. --encoder pixel+cnn (one SDR: the parts' bits side by "
              "side); --encoder-conf pixel.k=150 sets one part, k=100 every part", "",
              "presets (--preset NAME; the encoder and conf a run takes when no --encoder is given):"]
    for name in presets.available():
        p = presets.get(name)
        conf = ", ".join(f"{k}={v!r}" for k, v in p["encoder_conf"].items())
        lines.append(f"  {name:10s}{p['encoder']} ({conf}); methods {', '.join(p['methods'])}; loops "
                     f"{p['loop_method']}: {p['use']}")
    return "\n".join(lines)


def _label(row) -> str:
    return f"{row['scene']}: {row['db']}" if row["db"] == row["query"] else \
        f"{row['scene']}: {row['db']} -> {row['query']}"


def _plot(rows, path, title):
    from vpr.plots import plot_bars

    metrics = (("AP", "ap"), ("R@1", "recall_at_1"))
    # line breaks keep the long pair names of neighbouring bars apart
    table = {_label(r).replace(": ", "\n").replace(" -> ", "\n-> "):
             {f"{m} {k}": r[m][key] for m in METHODS if r[m] for k, key in metrics} for r in rows}
    plot_bars(table, path, ylabel="AP / R@1", title=title)


def format_table(rows) -> str:
    """Plain-text table: one line per scene and traverse pair, AP and R@1 of each method."""
    width = max(len(_label(r)) for r in rows) + 2
    head = "".join(f"{m + ' ' + k:>16s}" for m in METHODS for k in ("AP", "R@1"))
    lines = [f"{'scene: database -> query':{width}s}{head}"]
    for r in rows:
        cells = "".join(f"{'-':>16s}" * 2 if r[m] is None else f"{r[m]['ap']:16.3f}{r[m]['recall_at_1']:16.3f}"
                        for m in METHODS)
        lines.append(f"{_label(r):{width}s}{cells}")
    means = "".join(f"{np.nanmean([r[m][key] for r in rows if r[m]] or [np.nan]):16.3f}"
                    for m in METHODS for key in ("ap", "recall_at_1"))
    lines.append(f"{'mean':{width}s}{means}")
    return "\n".join(lines)


# -------------------------------------------------------------------------------------- CLI
def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--size: expected WIDTHxHEIGHT, got {text!r}") from None
    if w < 16 or h < 16:
        raise argparse.ArgumentTypeError(f"--size: at least 16x16, got {text!r}")
    return w, h


def add_arguments(parser: argparse.ArgumentParser, command: str = "encoders") -> None:
    """Sub-commands ``list`` and ``test`` of ``vpr encoders``."""
    sub = parser.add_subparsers(dest="encoders_action", metavar="{list,test}", required=True)
    add_common_arguments(sub.add_parser("list", help="registered encoders and their default confs"))
    p = sub.add_parser("test", help="score one encoder on the synthetic scenes (frame by frame and as sequences)",
                       description=score_encoder.__doc__.split("\n\n")[0])
    p.add_argument("--encoder", required=True, help=f"encoder name ({', '.join(encoders.available())})")
    p.add_argument("--encoder-conf", action="append", default=[], metavar="KEY=VALUE",
                   help="encoder conf override, repeatable (e.g. standardise=fit)")
    p.add_argument("--scenes", default=None,
                   help=f"comma-separated scene names or spec files (default: all builtin: "
                        f"{','.join(render.builtin_specs())})")
    p.add_argument("--size", type=_size, default=(160, 120), metavar="WxH", help="frame size (default 160x120)")
    p.add_argument("--frames", type=int, default=None, help="frames per traverse (default: the spec's)")
    p.add_argument("--radius", type=float, default=5.0, help="hard ground-truth radius in metres (default 5)")
    p.add_argument("--out", type=Path, required=True, help="output folder (metrics.json, metrics.png)")
    add_common_arguments(p)


def run_command(args) -> int:
    """Run ``vpr encoders list|test`` for parsed ``args``; return the exit status."""
    if args.encoders_action == "list":
        print(format_list(list_encoders()))
        return 0
    try:
        cfg = EncoderTest(encoder=args.encoder, out=args.out, conf=encoders.parse_conf(args.encoder_conf),
                          scenes=render.builtin_specs() if args.scenes is None else
                          [s.strip() for s in args.scenes.split(",") if s.strip()],
                          size=args.size, n_frames=args.frames, radius=args.radius)
        print(f"encoder {cfg.encoder} {cfg.conf or ''}: scenes {', '.join(map(str, cfg.scenes))}, "
              f"{cfg.size[0]}x{cfg.size[1]}, {cfg.n_frames or 'native'} frames per traverse")
        doc = score_encoder(cfg)
    except ValueError as e:
        print(f"vpr encoders test: {e}", file=sys.stderr)
        return 2
    _io.save_json(cfg.out / "metrics.json", doc)
    _plot(doc["rows"], cfg.out / "metrics.png", f"{cfg.encoder} on the synthetic scenes")
    print(format_table(doc["rows"]))
    header = [(f"{m}.{k}", f"{m} {lab}") for m in METHODS for k, lab in (("ap", "AP"), ("recall_at_1", "R@1"))]
    write_table(cfg.out, f"vpr encoders test: {cfg.encoder}", header,
                       [(_label(r), [c for m in METHODS for c in (["-", "-"] if r[m] is None else
                                                                 [f"{r[m]['ap']:.3f}", f"{r[m]['recall_at_1']:.3f}"])])
                        for r in doc["rows"]], [("AP and R@1 per scene", cfg.out / "metrics.png")],
                       [f"encoder {cfg.encoder} {cfg.conf or ''} on the rendered scenes "
                        f"{', '.join(map(str, cfg.scenes))} (frames rendered in memory: no frames to show)"])
    print(f"wrote {cfg.out / 'metrics.json'}, {cfg.out / 'metrics.png'}, {cfg.out / 'report.html'}")
    return 0
