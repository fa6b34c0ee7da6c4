"""``vpr render``: render a procedural scene specification to image folders and ground truth.

The rendering itself is :func:`vpr.render.write_scene`; this module adds the
command line and the printed summary.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from pipelines.args import add_common_arguments
from vpr import render

__all__ = ["COMMANDS", "add_arguments", "run_command", "run_render", "parse_size"]

COMMANDS = {"render": "render a procedural scene specification to image folders and ground truth"}


def parse_size(text: str) -> tuple[int, int]:
    """``"320x240"`` -> ``(320, 240)`` (an argparse ``type``)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, e.g. 320x240, got {text!r}") from None
    return (w, h)


def add_arguments(parser: argparse.ArgumentParser, command: str = "render") -> None:
    """Add the arguments of ``vpr render`` to ``parser``."""
    parser.add_argument("spec", help="scene spec: a JSON file or a builtin name (two_seasons, loop_revisits, ...)")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--preview", action="store_true", help="also write contact_sheet.png")
    parser.add_argument("--video", action="store_true", help="also write one mp4 video per traverse")
    parser.add_argument("--traverse", action="append", default=None, metavar="NAME",
                        help="render only this traverse (repeatable)")
    parser.add_argument("--size", type=parse_size, default=None, metavar="WxH", help="override the image size")
    parser.add_argument("--frames", type=int, default=None, metavar="N",
                        help="override the number of frames per traverse")
    parser.add_argument("--seed", type=int, default=None, help="override the world seed")
    add_common_arguments(parser)
    parser.add_argument("--quiet", dest="no_progress", action="store_true", help="the same as --no-progress")


def run_render(spec, out: str | Path, preview: bool = False, video: bool = False, traverses=None,
               size: tuple[int, int] | None = None, n_frames: int | None = None, seed: int | None = None,
               progress: bool = True) -> dict:
    """Render ``spec`` into ``out`` (see :func:`vpr.render.write_scene`), print a summary, return its result."""
    s = render.write_scene(spec, out, preview=preview, video=video, traverses=traverses, size=size,
                           n_frames=n_frames, seed=seed, progress=progress)
    for name, t in s["traverses"].items():
        extra = f", video {t['video']}" if t["video"] else ""
        print(f"{name}: {t['frames']} frames in {t['folder']}{extra}")
    print(f"ground truth: {s['ground_truth']}")
    print(f"scene: {s['scene']}")
    if s["loop_pairs"]:
        print(f"loop closures: {s['loop_pairs']}")
    if s["preview"]:
        print(f"contact sheet: {s['preview']}")
    return s


def run_command(args) -> int:
    run_render(args.spec, args.out, preview=args.preview, video=args.video, traverses=args.traverse,
               size=args.size, n_frames=args.frames, seed=args.seed, progress=not args.no_progress)
    return 0
