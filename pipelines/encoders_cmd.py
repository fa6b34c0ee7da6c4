"""``vpr encoders list`` and ``vpr encoders test``: how an image encoder fares on the synthetic scenes.

``list`` prints every registered encoder with its default conf. ``test`` renders
the builtin scenes of :mod:`vpr.render` (or the ``--scenes`` given), encodes
every traverse with one encoder and scores it for every ordered pair of a
scene's traverses (database conditions -> query conditions) with

* ``pairwise``: the SDR overlap of single frames;
* ``rshosm-seq``: the sequence memory learned on the database traverse.

A scene with a single traverse (``loop_revisits``) is scored as loop closure
against its own past (pairwise only: ``rshosm-seq`` matches two traverses).
Ground truth: :func:`vpr.render.gt_matrix` with a hard radius (default 5 m);
pairs within twice that are soft (ignored). Metrics: average precision (AP,
non-interpolated, over the evaluated pairs) and recall@1. An encoder whose conf
has ``standardise=fit`` is fitted on each traverse before encoding it, which
removes the appearance shared by a whole traverse (season, daylight).

Writes ``metrics.json`` and ``metrics.png`` (AP and R@1 per scene and pair) to
``--out`` and prints the table.
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp

import encoders
from pipelines.args import add_common_arguments
from vpr import evaluate, methods, render
from vpr import io as _io
from vpr.evaluate import recall_at_k
from vpr.types import EncodedTraverse

__all__ = ["COMMANDS", "EncoderTest", "add_arguments", "run_command", "list_encoders", "format_list",
           "test_encoder", "format_table"]

COMMANDS = {"encoders": "list the image encoders, or test one on the synthetic scenes (AP, R@1)"}
METHODS = ("pairwise", "rshosm-seq")


@dataclass
class EncoderTest:
    """Settings of :func:`test_encoder` (``vpr encoders test``)."""

    encoder: str
    out: Path
    conf: dict = field(default_factory=dict)
    scenes: list = field(default_factory=render.builtin_specs)
    size: tuple = (160, 120)
    n_frames: int | None = None
    radius: float = 5.0

    def __post_init__(self):
        if not self.scenes:
            raise ValueError("scenes: need at least one scene")
        if self.n_frames is not None and int(self.n_frames) < 2:
            raise ValueError(f"frames: need at least 2 per traverse, got {self.n_frames}")
        if not self.radius > 0:
            raise ValueError(f"radius: must be > 0 metres, got {self.radius!r}")
        self.out = Path(self.out)
        self.size = (int(self.size[0]), int(self.size[1]))


def similarity(method: str, db_sdr: sp.csr_matrix, q_sdr: sp.csr_matrix):
    """db x query similarity of ``method`` on two SDR traverses."""
    names = list(range(max(db_sdr.shape[0], q_sdr.shape[0])))
    return methods.get(method).match(EncodedTraverse(names[: db_sdr.shape[0]], sdr=db_sdr),
                                     EncodedTraverse(names[: q_sdr.shape[0]], sdr=q_sdr)).similarity


def average_precision(S, gt_hard, gt_soft=None, mask=None) -> float:
    """AP over the evaluated pairs, NaN when no evaluated pair is a true match."""
    hard = gt_hard.toarray() if sp.issparse(gt_hard) else np.asarray(gt_hard, bool)
    if not (hard if mask is None else hard & np.asarray(mask, bool)).any():
        return float("nan")
    return evaluate.average_precision(S, gt_hard, gt_soft, mask=mask)


# ------------------------------------------------------------------------------------- list
def list_encoders() -> dict:
    """Every registered encoder's name -> default conf (merged over its base classes, as the encoder does)."""
    out = {}
    for name in encoders.available():
        conf: dict = {}
        for cls in reversed(encoders.get_class(name).__mro__):
            conf.update(getattr(cls, "default_conf", {}) or {})
        out[name] = conf
    return out


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


# ------------------------------------------------------------------------------------- test
def _encode(enc, images, fit: bool) -> sp.csr_matrix:
    """SDRs of one traverse; fitted on that traverse first when ``fit``."""
    if hasattr(enc, "encode_descriptors"):
        desc = enc.describe(images)  # describe once: fitting and encoding share the descriptors
        if fit:
            enc.fit_descriptors(desc)
        return enc.encode_descriptors(desc)
    return enc.fit(images).encode(images) if fit else enc.encode(images)


def _pairs(scene, radius: float) -> list[tuple]:
    """(db index, query index, gt_hard, gt_soft, mask) of every evaluated traverse pair of a scene."""
    trs = scene.traverses
    if len(trs) == 1:
        # loop closure against the own past, skipping frames of the same pass (as render.loop_pairs)
        tr = trs[0]
        hard = render.loop_pairs(tr, radius)
        excl = tr.loop_length / 2 if tr.loop_length else 10.0 * radius
        d = tr.route_pos
        mask = np.triu(np.abs(d[:, None] - d[None, :]) >= excl, k=1)
        return [(0, 0, hard, render.loop_pairs(tr, 2 * radius) | hard, mask)]
    return [(a, b, render.gt_matrix(trs[a], trs[b], radius), render.gt_matrix(trs[a], trs[b], 2 * radius), None)
            for a in range(len(trs)) for b in range(len(trs)) if a != b]


def test_encoder(cfg: EncoderTest, log=print) -> dict:
    """Render, encode and score; write ``metrics.json`` and ``metrics.png`` to ``cfg.out``; return the document.

    Raises
    ------
    ValueError
        Unknown encoder, conf key or scene (the message names it).
    """
    enc = encoders.get(cfg.encoder, **cfg.conf)
    fit = enc.conf.get("standardise") == "fit"
    rows, seconds = [], {"encode": 0.0, **{m: 0.0 for m in METHODS}}
    for name in cfg.scenes:
        scene = render.render_scene(name, size=cfg.size, n_frames=cfg.n_frames)
        scene_name = scene.spec.get("name", str(name))
        t = time.perf_counter()
        sdrs = [_encode(enc, tr.images, fit) for tr in scene.traverses]
        seconds["encode"] += time.perf_counter() - t
        for a, b, hard, soft, mask in _pairs(scene, cfg.radius):
            row = {"scene": scene_name, "db": scene.traverses[a].name, "query": scene.traverses[b].name,
                   "n_db": sdrs[a].shape[0], "n_query": sdrs[b].shape[0]}
            for method in METHODS:
                if method == "rshosm-seq" and a == b:
                    row[method] = None  # a sequence memory matches two traverses, not one against itself
                    continue
                t = time.perf_counter()
                S = similarity(method, sdrs[a], sdrs[b])
                seconds[method] += time.perf_counter() - t
                row[method] = {"ap": average_precision(S, hard, soft, mask),
                               "recall_at_1": recall_at_k(S, hard, soft, k=1, mask=mask)}
            rows.append(row)
        log(f"  {scene_name}: {len(scene.traverses)} traverse(s), {len(rows)} pairs so far")
    doc = {"encoder": cfg.encoder, "conf": enc.conf, "fit_per_traverse": fit,
           "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(cfg).items()},
           "methods": list(METHODS), "rows": rows, "seconds": seconds}
    _io.save_json(cfg.out / "metrics.json", doc)
    _plot(rows, cfg.out / "metrics.png", f"{cfg.encoder} on the synthetic scenes")
    return doc


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
    p = sub.add_parser("test", help="score one encoder on the synthetic scenes (pairwise and rshosm-seq)",
                       description=__doc__.split("\n\n")[1])
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
        doc = test_encoder(cfg)
    except ValueError as e:
        print(f"vpr encoders test: {e}", file=sys.stderr)
        return 2
    print(format_table(doc["rows"]))
    print(f"wrote {cfg.out / 'metrics.json'}, {cfg.out / 'metrics.png'}")
    return 0
