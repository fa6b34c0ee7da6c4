"""A query driven faster or slower than the map at the same frame rate: speed models of rSHOSM-seq's evidence.

The evidence follows a query that moves one map frame per frame, and admits
a repeated (``stay``) or a skipped (``skip``) map frame at a cost of 0.05
each (:class:`vpr.shosm.EvidenceConf`). A query driven twice as fast skips
at every frame; half as fast, it stays at every other. Compared, per stream:

- ``same``: today's evidence (stay 0.05, skip 0.05);
- ``free``: one evidence with both transitions free (stay 0, skip 0);
- ``same+faster``, ``same+faster+slower``: the evidence of each model
  (``faster``: skip 0; ``slower``: stay 0) computed apart and merged by the
  largest z-score per pair, as SeqSLAM searches several velocities.

Streams (no stamps, no positions: the query's frames are taken as they come):
Gardens Point day_left (map) against day_right, every frame (1x), every 2nd
(2x) and the map every 2nd against every query frame (0.5x); Nordland summer
every 10th file against winter every 10th (1x), 20th (2x) and 5th (0.5x).
Right: within 2 frames (Gardens Point) or one map frame (10 files) of the
query's own frame. Printed per stream and model: AP, accepted, P(acc),
R(acc) of ``accept_path`` (the localisation decision, `vpr compare`'s) on
the merged z-scores. Default preset, ``rshosm-seq``, one run (deterministic).

Usage: python -m studies.speed_models [--data DIR] [--out DIR]
"""
from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
import warnings
from pathlib import Path

import numpy as np

from pipelines.cli import main as vpr
from vpr.evaluate import average_precision
from vpr.shosm.decide import accept_path

#: model -> (stay, skip)
MODELS = {"same": (0.05, 0.05), "faster": (0.05, 0.0), "slower": (0.0, 0.05), "free": (0.0, 0.0)}
COMBOS = ("same", "free", "same+faster", "same+faster+slower")


def _folder(root: Path, name: str, files: list[Path], number) -> tuple[Path, np.ndarray]:
    """A folder of links to ``files`` and each file's position along the route (``number(file)``)."""
    out = root / name
    out.mkdir(parents=True, exist_ok=True)
    for f in files:
        if not (out / f.name).exists():
            (out / f.name).symlink_to(f.resolve())
    return out, np.array([number(f) for f in files], np.float64)


def _streams(data: Path, root: Path):
    gp, nl = data / "gardens_point_day", data / "nordland_trimmed"
    left, right = sorted((gp / "day_left").iterdir()), sorted((gp / "day_right").iterdir())
    summer, winter = sorted((nl / "summer").iterdir()), sorted((nl / "winter").iterdir())
    gp_n = lambda f: int(f.stem.removeprefix("Image"))  # noqa: E731
    nl_n = lambda f: int(f.stem.split("-")[-1]) // 10  # noqa: E731
    yield "Gardens Point 1x", _folder(root, "gp_left", left, gp_n), _folder(root, "gp_right", right, gp_n), 2
    yield "Gardens Point 2x", _folder(root, "gp_left", left, gp_n), _folder(root, "gp_right2", right[::2], gp_n), 2
    yield "Gardens Point 0.5x", _folder(root, "gp_left2", left[::2], gp_n), _folder(root, "gp_right", right, gp_n), 2
    s10 = _folder(root, "nl_summer10", summer[::10], nl_n)
    yield "Nordland 1x", s10, _folder(root, "nl_winter10", winter[::10], nl_n), 10
    yield "Nordland 2x", s10, _folder(root, "nl_winter20", winter[::20], nl_n), 10
    yield "Nordland 0.5x", s10, _folder(root, "nl_winter5", winter[::5], nl_n), 10


def _similarity(db: Path, query: Path, model: str, root: Path) -> np.ndarray:
    out = root / "runs" / f"{db.name}-{query.name}-{model}"
    if not (out / "rshosm-seq" / "similarity.npy").exists():
        stay, skip = MODELS[model]
        argv = ["compare", db, query, "--out", out, "--cache", root / "cache", "--methods", "rshosm-seq",
                "--method-conf", f"rshosm-seq.stay={stay}", "--method-conf", f"rshosm-seq.skip={skip}",
                "--no-progress"]
        with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings(action="ignore"):
            if vpr([str(a) for a in argv]):
                raise SystemExit(f"vpr compare {db} {query} failed")
    return np.load(out / "rshosm-seq" / "similarity.npy")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "datasets",
                    help="the folder holding gardens_point_day/ and nordland_trimmed/")
    ap.add_argument("--out", type=Path, default=None, help="work folder (default: a temporary one)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        root = args.out or Path(tmp)
        print("AP, accepted, P(acc), R(acc) of rshosm-seq (default preset), query frames as they come")
        print(f"| stream | {' | '.join(COMBOS)} |")
        print("|---|" + "---|" * len(COMBOS))
        for name, (db, x_db), (query, x_q), radius in _streams(args.data, root):
            gt = np.abs(x_db[:, None] - x_q[None, :]) <= radius
            cells = []
            for combo in COMBOS:
                S = None
                for model in combo.split("+"):
                    M = _similarity(db, query, model, root)
                    S = M if S is None else np.maximum(S, M)
                d = accept_path(S)
                best, acc = np.asarray(d.best), np.asarray(d.accepted, bool)
                right = gt[best, np.arange(best.size)] & (best >= 0)
                n, tp = int(acc.sum()), int((acc & right).sum())
                p = f"{tp / n:.3f}" if n else "-"
                cells.append(f"{average_precision(S, gt):.3f}, {n}, {p}, {tp / best.size:.2f}")
            print(f"| {name} | {' | '.join(cells)} |", flush=True)


if __name__ == "__main__":
    main()
