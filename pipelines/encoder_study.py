"""Encoder study: pairwise place recognition with each encoder on the synthetic scenes.

For every built-in scene of :mod:`vpr.render` (``data/synthetic``), the first
traverse is the database and every other traverse a query set; each encoder
turns both into SDRs, the normalised overlap (:func:`vpr.similarity.overlap`,
db x query) is the similarity, and recall@1 and the area under the
precision-recall curve are measured against :func:`vpr.render.gt_matrix`
(hard radius, default 5 m; pairs within twice that are soft, i.e. ignored). A
scene with a single traverse is evaluated as loop closure against its own past
(:func:`vpr.render.loop_pairs`), ignoring pairs of the same pass.

Encoders with ``+fit`` use per-traverse standardisation: the encoder is fitted
on the traverse it then encodes (``standardise="fit"``), which removes the
appearance shared by all frames of a traverse (season, daylight).

Outputs in ``--out``: ``encoder_study.json`` (all numbers), ``recall_at_1.png``
and ``auc.png`` (bars per scene:condition and encoder); the table is printed.

Usage: python -m pipelines.encoder_study [--scenes two_seasons,...] [--size 160x120] [--frames N]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

# label -> (registry name, conf); "+fit" labels are fitted per traverse
VARIANTS = {
    "pixel": ("pixel", {}),
    "pixel+fit": ("pixel", {"standardise": "fit"}),
    "hog+fit": ("projection", {"descriptor": "hog", "standardise": "fit"}),
    "orb": ("orb", {}),
    "orb-grid": ("orb", {"mode": "grid"}),
    "cnn": ("cnn", {}),
    "cnn+fit": ("cnn", {"standardise": "fit"}),
}


def encode_traverse(enc, images, fit: bool):
    """SDRs of one traverse; fitted on that traverse first when ``fit``."""
    if hasattr(enc, "encode_descriptors"):
        # describe once: fitting and encoding share the dense descriptors
        desc = enc.describe(images)
        if fit:
            enc.fit_descriptors(desc)
        return enc.encode_descriptors(desc)
    return enc.fit(images).encode(images) if fit else enc.encode(images)


def evaluate_pair(S, gt_hard, gt_soft, mask=None) -> dict:
    from vpr.evaluate import auc_pr, recall_at_k

    return {"recall@1": recall_at_k(S, gt_hard, gt_soft, k=1, mask=mask),
            "auc": auc_pr(S, gt_hard, gt_soft, mask=mask)}


def run_study(scenes, variants, size=(160, 120), n_frames=None, radius=5.0, log=print) -> dict:
    """Evaluate every encoder variant on every scene.

    Parameters
    ----------
    scenes : list of str
        Scene names or spec paths for :func:`vpr.render.render_scene`.
    variants : dict
        Label -> (registry name, conf), e.g. :data:`VARIANTS`.
    size : (int, int)
        Rendered frame size (w, h).
    n_frames : int, optional
        Frames per traverse; default: the spec's own frame rate.
    radius : float
        Hard ground-truth radius in metres; pairs closer than ``2 * radius``
        but not within ``radius`` are soft (ignored).

    Returns
    -------
    dict
        ```{"results": {group: {label: {"recall@1": .., "auc": ..}}}, "seconds": {label: s},
        "group_frames": {group: (n_db, n_query)}}``, where a group is ``"scene:query traverse"``.
    """
    import encoders
    from vpr import render
    from vpr.similarity import overlap

    results: dict = {}
    frames: dict = {}
    seconds = {label: 0.0 for label in variants}
    for scene_name in scenes:
        scene = render.render_scene(scene_name, size=size, n_frames=n_frames)
        trs = scene.traverses
        if len(trs) == 1:
            # single stream: loop closure against its own past, skipping the
            # frames of the same pass that loop_pairs does not count as revisits
            tr = trs[0]
            hard = render.loop_pairs(tr, radius)
            excl = tr.loop_length / 2 if tr.loop_length else 10.0 * radius
            d = tr.route_pos
            mask = np.triu(np.abs(d[:, None] - d[None, :]) >= excl, k=1)
            pairs = [(f"{scene_name}:{tr.name}", 0, 0, hard, render.loop_pairs(tr, 2 * radius) | hard, mask)]
        else:
            pairs = [(f"{scene_name}:{trs[qi].name}", 0, qi, render.gt_matrix(trs[0], trs[qi], radius),
                      render.gt_matrix(trs[0], trs[qi], 2 * radius), None) for qi in range(1, len(trs))]
        for group, di, qi, *_ in pairs:
            frames[group] = (len(trs[di]), len(trs[qi]))
        for label, (name, conf) in variants.items():
            enc = encoders.get(name, **conf)
            fit = conf.get("standardise") == "fit"
            t = time.perf_counter()
            sdrs = [encode_traverse(enc, tr.images, fit) for tr in trs]
            seconds[label] += time.perf_counter() - t
            for group, di, qi, hard, soft, mask in pairs:
                S = overlap(sdrs[di], sdrs[qi])
                results.setdefault(group, {})[label] = evaluate_pair(S, hard, soft, mask)
        log(f"  {scene_name}: {len(trs)} traverse(s) of {', '.join(str(len(t)) for t in trs)} frames done")
    return {"results": results, "seconds": seconds, "group_frames": frames}


def format_table(results: dict, metric: str) -> str:
    labels = list(dict.fromkeys(lab for g in results.values() for lab in g))
    width = max(len(g) for g in results) + 2
    lines = [f"{metric:{width}s}" + "".join(f"{lab:>10s}" for lab in labels)]
    for group, row in results.items():
        lines.append(f"{group:{width}s}" + "".join(
            f"{row[lab][metric]:10.2f}" if lab in row else f"{'-':>10s}" for lab in labels))
    means = [np.mean([row[lab][metric] for row in results.values() if lab in row]) for lab in labels]
    lines.append(f"{'mean':{width}s}" + "".join(f"{m:10.2f}" for m in means))
    return "\n".join(lines)


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--size: expected WIDTHxHEIGHT, got {text!r}") from None
    if w < 16 or h < 16:
        raise argparse.ArgumentTypeError(f"--size: at least 16x16, got {text!r}")
    return w, h


def main(argv=None) -> int:
    from vpr import render

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenes", default="all", help="comma-separated scene names, or 'all'")
    p.add_argument("--encoders", default=",".join(VARIANTS),
                   help=f"comma-separated subset of {', '.join(VARIANTS)}")
    p.add_argument("--size", type=_size, default=(160, 120), help="frame size WIDTHxHEIGHT")
    p.add_argument("--frames", type=int, default=None, help="frames per traverse (default: the spec's)")
    p.add_argument("--radius", type=float, default=5.0, help="hard ground-truth radius in metres")
    p.add_argument("--out", type=Path, default=Path("results/encoder_study"))
    args = p.parse_args(argv)

    scenes = render.builtin_specs() if args.scenes == "all" else [s.strip() for s in args.scenes.split(",")]
    unknown = [e for e in args.encoders.split(",") if e not in VARIANTS]
    if unknown:
        p.error(f"--encoders: unknown {unknown}; choose from {list(VARIANTS)}")
    if args.frames is not None and args.frames < 2:
        p.error("--frames must be >= 2")
    if not args.radius > 0:
        p.error("--radius must be positive")
    variants = {e: VARIANTS[e] for e in args.encoders.split(",")}

    print(f"encoder study: scenes {scenes}, frames {args.size[0]}x{args.size[1]}, "
          f"{args.frames or 'native'} per traverse, hard radius {args.radius} m (soft {2 * args.radius} m)")
    out = run_study(scenes, variants, size=args.size, n_frames=args.frames, radius=args.radius)
    for metric in ("recall@1", "auc"):
        print()
        print(format_table(out["results"], metric))
    print("\nencoding seconds (all scenes): " + ", ".join(f"{k} {v:.1f}" for k, v in out["seconds"].items()))

    from vpr.io import save_json
    from vpr.plots import plot_bars

    save_json(args.out / "encoder_study.json",
              {"scenes": scenes, "size": list(args.size), "frames": args.frames, "radius": args.radius,
               "variants": {k: {"encoder": n, "conf": c} for k, (n, c) in variants.items()}, **out})
    for metric, fname in (("recall@1", "recall_at_1.png"), ("auc", "auc.png")):
        table = {g: {lab: v[metric] for lab, v in row.items()} for g, row in out["results"].items()}
        plot_bars(table, args.out / fname, ylabel=metric, title=f"pairwise {metric} per encoder")
    print(f"wrote {args.out}/encoder_study.json, recall_at_1.png, auc.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
