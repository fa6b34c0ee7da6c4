"""Study: realism of the procedural renders: how hard is pairwise place recognition on them?

For every ordered pair of traverses of a scene (default ``two_seasons``), and
for each traverse against a re-render of itself with the same conditions but
another traverse seed (different speed variation, lateral offset, yaw jitter,
exposure and sensor noise: the "same-condition pair"), images are reduced to
OpenSeqSLAM's 64 x 32 patch-normalised grey descriptors and compared with
cosine similarity. The table gives recall@1, recall@5, the area under the
precision-recall curve (best match per query) and the recall@1 of random
guessing.

Run ``python -m research.studies.realism [--spec two_seasons] [--size 320x240]`` (log: ``research/docs/benchmarks.md``).
The renders are good test data when cross-condition recall@1 lies in
0.2 .. 0.8 (hard but not hopeless) and same-condition recall@1 is > 0.9.
"""
from __future__ import annotations

import argparse
import copy
import sys

import numpy as np

from vpr.evaluate import auc_pr, recall_at_k
from vpr.imageproc import seqslam_descriptors
from vpr.io import save_json
from vpr.render import gt_matrix, load_spec, render_scene
from vpr.similarity import cosine

__all__ = ["realism_table", "format_table", "main"]

RERUN_SUFFIX = "_rerun"


def realism_table(spec="two_seasons", size=None, n_frames=None, radius: float = 5.0, rerun_seed_offset: int = 1000,
                  progress: bool = True) -> list[dict]:
    """Render ``spec`` plus same-condition re-renders and evaluate every traverse pair.

    Parameters
    ----------
    spec : str, Path or dict
        Scene spec (file, builtin name or dictionary).
    size : (int, int), optional
        Render size override (width, height).
    n_frames : int, optional
        Frame count override per traverse.
    radius : float
        Ground-truth radius in metres; pairs between ``radius`` and
        ``2 radius`` are ignored (soft ground truth).
    rerun_seed_offset : int
        Added to each traverse seed for its same-condition re-render.
    progress : bool
        Progress bars while rendering.

    Returns
    -------
    list of dict
        One row per (database, query) pair with keys ``db``, ``query``,
        ``kind`` ("same condition" or "cross condition"), ``n_db``, ``n_query``,
        ``recall@1``, ``recall@5``, ``auc``, ``chance@1``.
    """
    if not radius > 0:
        raise ValueError(f"radius: must be > 0 metres, got {radius!r}")
    s = load_spec(spec)
    base = [t["name"] for t in s["traverses"]]
    reruns = []
    for t in s["traverses"]:
        r = copy.deepcopy(t)
        r["name"] = t["name"] + RERUN_SUFFIX
        r["seed"] = t["seed"] + int(rerun_seed_offset)
        reruns.append(r)
    s["traverses"] = s["traverses"] + reruns
    scene = render_scene(s, size=size, n_frames=n_frames, progress=progress)
    desc = {t.name: seqslam_descriptors(t.images) for t in scene.traverses}
    pairs = [(a, b, "cross condition") for a in base for b in base if a != b]
    pairs += [(a, a + RERUN_SUFFIX, "same condition") for a in base]
    rows = []
    for db, q in ((a, b) for a, b, _ in pairs):
        kind = "same condition" if q == db + RERUN_SUFFIX else "cross condition"
        S = cosine(desc[db], desc[q])
        hard = gt_matrix(scene[db], scene[q], radius)
        soft = gt_matrix(scene[db], scene[q], 2 * radius)
        has = hard.any(axis=0)
        rows.append({
            "db": db, "query": q, "kind": kind, "n_db": S.shape[0], "n_query": S.shape[1],
            "recall@1": recall_at_k(S, hard, soft, k=1),
            "recall@5": recall_at_k(S, hard, soft, k=5),
            "auc": auc_pr(S, hard, soft, matching="single"),
            # a random database frame among those not ignored hits a true match this often
            "chance@1": float(np.mean(hard[:, has].sum(0) / (S.shape[0] - (soft & ~hard)[:, has].sum(0)))),
        })
    return rows


def format_table(rows: list[dict]) -> str:
    """Plain-text table of :func:`realism_table` rows."""
    head = (f"{'database':<22} {'query':<22} {'pair':<16} {'N_db':>5} {'N_q':>5} "
            f"{'R@1':>6} {'R@5':>6} {'AUC':>6} {'chance':>7}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r['db']:<22} {r['query']:<22} {r['kind']:<16} {r['n_db']:>5} {r['n_query']:>5} "
                     f"{r['recall@1']:>6.3f} {r['recall@5']:>6.3f} {r['auc']:>6.3f} {r['chance@1']:>7.4f}")
    return "\n".join(lines)


def _size(text):
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None
    return (w, h)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m research.studies.realism", description=__doc__.split("\n\n")[0])
    ap.add_argument("--spec", default="two_seasons", help="scene spec file or builtin name (default two_seasons)")
    ap.add_argument("--size", type=_size, default=None, metavar="WxH", help="render size (default: the spec's)")
    ap.add_argument("--frames", type=int, default=None, help="frames per traverse (default: the spec's)")
    ap.add_argument("--radius", type=float, default=5.0, help="ground-truth radius in metres (default 5)")
    ap.add_argument("--json", default=None, help="also write the rows to this JSON file")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    a = ap.parse_args(argv)
    rows = realism_table(a.spec, size=a.size, n_frames=a.frames, radius=a.radius, progress=not a.quiet)
    print(format_table(rows))
    cross = [r["recall@1"] for r in rows if r["kind"] == "cross condition"]
    same = [r["recall@1"] for r in rows if r["kind"] == "same condition"]
    ok = all(0.2 <= v <= 0.8 for v in cross) and all(v > 0.9 for v in same)
    print(f"\ncross-condition R@1 in [{min(cross, default=float('nan')):.3f}, {max(cross, default=float('nan')):.3f}] "
          f"(target 0.2..0.8); same-condition R@1 >= {min(same, default=float('nan')):.3f} (target > 0.9): "
          f"{'OK' if ok else 'OUT OF TARGET'}")
    if a.json:
        save_json(a.json, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
