"""``vpr match``, ``vpr compare`` and ``vpr loops``: image folders, videos or lists in,
similarity matrices, matches, metrics and plots out.

Outputs in ``--out DIR`` (one method: in DIR; several: one sub-folder per method):
``similarity.npy`` (float32 db x query; a top-K sparse ``similarity_topk.npz`` for
large inputs), ``matches.csv`` (query, best_db, score, accepted, ...),
``similarity.png``; and in DIR ``pr.png`` (with ground truth), ``metrics.json``
and ``config.json`` (everything needed to repeat the run). Encodings are cached
in ``DIR/cache``.
"""
from __future__ import annotations

import argparse
import csv
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from vpr import evaluate, io, plots
from vpr.methods import DEFAULT_CONF, METHODS, MatchResult, loops, match, merge_conf

__all__ = ["add_arguments", "run_command", "run_compare", "run_loops", "metrics_table", "versions"]


# ------------------------------------------------------------------ arguments
def _coerce(method, conf):
    """Coerce string values (from the command line) to the type of the method's defaults."""
    from encoders.base import coerce_value

    defaults = DEFAULT_CONF[method]
    out = {}
    for k, v in conf.items():
        if k not in defaults:
            merge_conf(method, {k: v})  # raises with the list of valid keys
        out[k] = coerce_value(k, v, defaults[k]) if isinstance(v, str) else v
    return out


def method_confs(args) -> dict:
    """Per-method conf from ``--method-conf METHOD.key=value`` (repeatable)."""
    confs: dict = {}
    for item in args.method_conf or ():
        head, sep, value = str(item).partition("=")
        method, dot, key = head.partition(".")
        if not sep or not dot or not key:
            raise ValueError(f"--method-conf: expected METHOD.key=value, got {item!r}")
        if method not in METHODS:
            raise ValueError(f"--method-conf: unknown method {method!r}; available: {', '.join(METHODS)}")
        confs.setdefault(method, {})[key] = value
    return {m: _coerce(m, c) for m, c in confs.items()}


def _add_source_args(ap):
    ap.add_argument("--fps", type=float, help="videos: resample to this frame rate")
    ap.add_argument("--step", type=int, help="keep every STEP-th frame")
    ap.add_argument("--max-frames", type=int, help="read at most this many frames per source")


def add_arguments(ap: argparse.ArgumentParser, command: str) -> None:
    import encoders

    if command == "loops":
        ap.add_argument("seq", metavar="SEQ", help="image folder, video or image list")
    else:
        ap.add_argument("db", metavar="DB", help="database traverse: image folder, video or image list")
        ap.add_argument("query", metavar="QUERY", help="query traverse: image folder, video or image list")
    ap.add_argument("--out", required=True, help="output folder")
    if command == "compare":
        ap.add_argument("--methods", default="rshosm,seqslam,pairwise",
                        help="comma-separated methods (default: rshosm,seqslam,pairwise)")
    else:
        ap.add_argument("--method", default="rshosm", choices=METHODS, help="method (default: rshosm)")
    ap.add_argument("--method-conf", action="append", default=[], metavar="METHOD.KEY=VALUE",
                    help="method option, repeatable, e.g. seqslam.ds=20 or rshosm.p_extra=0.01")
    encoders.add_arguments(ap)
    _add_source_args(ap)
    gt = ap.add_argument_group("ground truth (optional; enables metrics and pr.png)")
    if command == "loops":
        ap.add_argument("--exclude", type=int, default=10,
                        help="ignore matches fewer than W frames back (default 10)")
        gt.add_argument("--gt", nargs="+", metavar="FILE",
                        help="positions CSV (frame,x,y or traverse,frame,x,y) with --radius")
    else:
        gt.add_argument("--tolerance", type=int, metavar="K", help="frame-aligned traverses: |i - j| <= K")
        gt.add_argument("--gt", nargs="+", metavar="FILE",
                        help="CSV of query,db pairs; or with --radius: one positions CSV per traverse "
                             "(frame,x,y), or one CSV with traverse,frame,x,y rows for both")
    gt.add_argument("--radius", type=float, help="match radius for position ground truth (same unit as x, y)")
    gt.add_argument("--gt-soft", type=float, metavar="R2",
                    help="also ignore pairs within this larger radius/tolerance (soft ground truth)")
    ap.add_argument("--verify", type=int, default=0, metavar="N",
                    help="geometric verification of each query's N best candidates (ORB + pycolmap)")
    ap.add_argument("--min-inliers", type=int, default=15, help="inliers needed to accept a verified match")
    ap.add_argument("--no-progress", action="store_true", help="no progress bars")


# --------------------------------------------------------------- ground truth
def _combined_positions(path, traverse):
    """Rows ``traverse,frame,x,y[,...]`` (as written by ``vpr render``) of one traverse."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"ground truth file not found: {path}")
    rows = {}
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None:
            raise ValueError(f"{path}: empty ground truth file")
        cols = [h.strip().lower() for h in header]
        need = {"traverse", "frame", "x", "y"}
        if not need <= set(cols):
            raise ValueError(f"{path}:1: expected a header with columns {sorted(need)}, got {header}")
        ti, fi, xi, yi = (cols.index(c) for c in ("traverse", "frame", "x", "y"))
        for line_no, row in enumerate(reader, start=2):
            if not row or row[0].startswith("#"):
                continue
            if len(row) != len(cols):
                raise ValueError(f"{path}:{line_no}: expected {len(cols)} columns, got {len(row)}")
            if row[ti] != traverse:
                continue
            try:
                rows[int(row[fi])] = (float(row[xi]), float(row[yi]))
            except ValueError:
                raise ValueError(f"{path}:{line_no}: frame must be an integer and x, y numbers") from None
    if not rows:
        raise ValueError(f"{path}: no rows for traverse {traverse!r}")
    return rows


def _xy_for(rows, indices, path, traverse):
    missing = [i for i in indices if i not in rows]
    if missing:
        raise ValueError(f"{path}: no position for frame {missing[0]} of traverse {traverse!r}")
    return np.array([rows[i] for i in indices])


def build_gt(args, db_ex, q_ex, db_src, q_src):
    """(gt_hard, gt_soft) from the arguments, or (None, None) without ground truth."""
    from vpr import groundtruth

    n_db, n_q = len(db_ex.features), len(q_ex.features)
    tol = getattr(args, "tolerance", None)
    if tol is not None:
        if args.gt:
            raise ValueError("give either --tolerance or --gt, not both")
        db_i, q_i = np.asarray(db_ex.indices), np.asarray(q_ex.indices)
        hard = np.abs(db_i[:, None] - q_i[None, :]) <= tol
        soft = np.abs(db_i[:, None] - q_i[None, :]) <= args.gt_soft if args.gt_soft is not None else None
        return hard, soft
    if not args.gt:
        if args.radius is not None:
            raise ValueError("--radius needs --gt FILE")
        return None, None
    if len(args.gt) > 2:
        raise ValueError(f"--gt takes one or two files, got {len(args.gt)}")
    if args.radius is None:
        if len(args.gt) != 1:
            raise ValueError("two --gt files are positions files and need --radius")
        hard = groundtruth.load_pairs_csv(args.gt[0], n_db, n_q, db_names=db_ex.features.names,
                                          q_names=q_ex.features.names, db_indices=db_ex.indices,
                                          q_indices=q_ex.indices)
        if args.gt_soft is not None:
            raise ValueError("--gt-soft needs position ground truth (--radius) or --tolerance")
        return hard, None
    if len(args.gt) == 2:
        kw = dict(db_names=db_ex.features.names, q_names=q_ex.features.names, db_indices=db_ex.indices,
                  q_indices=q_ex.indices)
        hard = groundtruth.gt_from_position_files(args.gt[0], args.gt[1], args.radius, **kw)
        soft = (groundtruth.gt_from_position_files(args.gt[0], args.gt[1], args.gt_soft, **kw)
                if args.gt_soft is not None else None)
        return hard, soft
    db_xy = _xy_for(_combined_positions(args.gt[0], db_src.name), db_ex.indices, args.gt[0], db_src.name)
    q_xy = _xy_for(_combined_positions(args.gt[0], q_src.name), q_ex.indices, args.gt[0], q_src.name)
    hard = evaluate.gt_from_positions(db_xy, q_xy, args.radius)
    soft = evaluate.gt_from_positions(db_xy, q_xy, args.gt_soft) if args.gt_soft is not None else None
    return hard, soft


# ------------------------------------------------------------------- outputs
def versions() -> dict:
    import cv2
    import scipy

    import vpr

    return {"vpr": vpr.__version__, "python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "opencv": cv2.__version__}


def write_similarity(folder: Path, S) -> str:
    if sp.issparse(S):
        with io.atomic_path(folder / "similarity_topk.npz") as tmp:
            sp.save_npz(tmp, sp.csr_matrix(S, dtype=np.float32))
        return "similarity_topk.npz"
    io.save_npy(folder / "similarity.npy", np.asarray(S, dtype=np.float32))
    return "similarity.npy"


def write_matches(folder: Path, res: MatchResult, db_names, q_names, extra: dict | None = None) -> None:
    extra = extra or {}
    with io.atomic_open(folder / "matches.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["query", "query_name", "best_db", "db_name", "score", "accepted", *extra])
        for j in range(len(q_names)):
            b = int(res.best_db[j])
            w.writerow([j, q_names[j], b, db_names[b] if b >= 0 else "", f"{res.score[j]:.6g}",
                        int(bool(res.accepted[j])), *(v[j] for v in extra.values())])


def _at(G, rows, cols) -> np.ndarray:
    if sp.issparse(G):
        return np.asarray(sp.csr_matrix(G)[rows, cols]).ravel() != 0
    return np.asarray(G)[rows, cols].astype(bool)


def accepted_precision(best_db, accepted, gt_hard, gt_soft=None) -> dict:
    """Precision and recall of the accepted best matches (one decision per query).

    A best match that is only a soft pair counts neither as right nor as wrong.
    """
    best_db = np.asarray(best_db)
    q = np.flatnonzero(np.asarray(accepted, bool) & (best_db >= 0))
    correct = _at(gt_hard, best_db[q], q)
    if gt_soft is not None:
        keep = correct | ~_at(gt_soft, best_db[q], q)
        q, correct = q[keep], correct[keep]
    n_with_match = int((np.asarray((gt_hard != 0).sum(axis=0)).ravel() > 0).sum())
    return {"n_accepted": int(q.size), "precision_accepted": float(correct.mean()) if q.size else 1.0,
            "recall_accepted": float(correct.sum() / max(1, n_with_match))}


def method_metrics(res: MatchResult, gt_hard, gt_soft, mask=None):
    """(metrics dict, (precision, recall) or None without ground truth)."""
    m = {"seconds": round(res.seconds, 4)}
    if gt_hard is None:
        return m, None
    ev, (prec, rec, _) = evaluate.evaluate(res.similarity, gt_hard, gt_soft, mask=mask, return_curve=True)
    m.update({k: float(v) for k, v in ev.items()})
    if mask is None:
        m.update(accepted_precision(res.best_db, res.accepted, gt_hard, gt_soft))
    return m, (prec, rec)


def metrics_table(methods: dict) -> str:
    keys = [("auc_pr", "AUC"), ("recall_at_100p", "R@100P"), ("recall_at_1", "R@1"),
            ("precision_accepted", "P(acc)"), ("seconds", "seconds")]
    lines = [f"{'method':<22}" + "".join(f"{h:>10}" for _, h in keys)]
    for name, m in methods.items():
        cells = "".join(f"{m[k]:10.3f}" if isinstance(m.get(k), (int, float)) else f"{'-':>10}" for k, _ in keys)
        lines.append(f"{name:<22}{cells}")
    return "\n".join(lines)


# ----------------------------------------------------------------- pipeline
def _sources(args, paths):
    from vpr.sources import open_source

    return [open_source(p, fps=args.fps, step=args.step, max_frames=args.max_frames) for p in paths]


def _extract_all(args, srcs, methods, method_conf, out: Path):
    import encoders
    from pipelines.extract import extract

    encoder = encoders.get(args.encoder, **encoders.parse_conf(args.encoder_conf))
    need_sdr = any(m.startswith("rshosm") or (m == "pairwise" and method_conf.get(m, {}).get("on", "sdr") == "sdr")
                   for m in methods)
    seq_desc = merge_conf("seqslam", method_conf.get("seqslam")).get("descriptor") if "seqslam" in methods else None
    need_desc = seq_desc == "encoder" or ("pairwise" in methods and
                                          method_conf.get("pairwise", {}).get("on") == "descriptor")
    need_pixels = seq_desc == "pixel"
    exs = [extract(s, encoder, need_sdr=need_sdr, need_desc=need_desc, need_pixels=need_pixels,
                   thumbs=args.verify > 0, cache_dir=out / "cache", progress=not args.no_progress) for s in srcs]
    return encoder, exs




def run_compare(args, methods: list[str]) -> dict:
    """Encode DB and QUERY once, run every method, write the outputs; return metrics.json's content."""
    if args.verify < 0:
        raise ValueError(f"--verify must be >= 0, got {args.verify}")
    for m in methods:
        if m not in METHODS:
            raise ValueError(f"unknown method {m!r}; available: {', '.join(METHODS)}")
    out = Path(args.out)
    confs = method_confs(args)
    db_src, q_src = _sources(args, [args.db, args.query])
    encoder, (db_ex, q_ex) = _extract_all(args, [db_src, q_src], methods, confs, out)
    gt_hard, gt_soft = build_gt(args, db_ex, q_ex, db_src, q_src)
    single = len(methods) == 1
    results, metrics, curves = {}, {}, {}
    verifier = None
    if args.verify:
        from vpr.verify import Verifier

        # one verifier for all methods: features and pair inliers are computed once
        verifier = Verifier(db_ex.thumbs, q_ex.thumbs, min_inliers=args.min_inliers)
    for m in methods:
        res = match(m, db_ex.features, q_ex.features, confs.get(m), progress=not args.no_progress)
        results[m] = res
        folder = out if single else out / m
        folder.mkdir(parents=True, exist_ok=True)
        sim_file = write_similarity(folder, res.similarity)
        metrics[m], curve = method_metrics(res, gt_hard, gt_soft)
        if curve is not None:
            curves[m] = curve
        metrics[m]["similarity_file"] = str(Path(folder.name if not single else ".") / sim_file)
        extra = {}
        if args.verify:
            t0 = time.perf_counter()
            vr = verifier.verify(res.similarity, args.verify, progress=not args.no_progress)
            # seconds: the method's plus verification (pairs shared with earlier methods are cached)
            verified = MatchResult(m + "+verify", vr.similarity(), vr.best_db, vr.score, vr.accepted,
                                   res.seconds + time.perf_counter() - t0, res.conf)
            extra = {"verified_db": vr.best_db.tolist(), "inliers": vr.score.astype(int).tolist(),
                     "verified": vr.accepted.astype(int).tolist()}
            metrics[m + "+verify"], curve = method_metrics(verified, gt_hard, gt_soft)
            if curve is not None:
                curves[m + "+verify"] = curve
        write_matches(folder, res, db_ex.features.names, q_ex.features.names, extra)
        plots.plot_similarity(res.similarity, folder / "similarity.png", best_db=res.best_db,
                              accepted=res.accepted, gt_hard=gt_hard, title=f"{m}: database x query")
    if curves:
        plots.plot_pr(curves, out / "pr.png", title=f"{db_src.name} vs {q_src.name} ({encoder.name})")
    report = {
        "methods": metrics,
        "params": {"command": args.command, "db": str(args.db), "query": str(args.query),
                   "encoder": encoder.name, "encoder_conf": encoder.conf,
                   "method_conf": {m: results[m].conf for m in methods},
                   "n_db": len(db_ex.features), "n_query": len(q_ex.features),
                   "encode_seconds": {"db": db_ex.seconds, "query": q_ex.seconds},
                   "cached": {"db": db_ex.cached, "query": q_ex.cached},
                   "skipped": {"db": db_ex.skipped, "query": q_ex.skipped},
                   "ignored_files": {"db": db_ex.ignored, "query": q_ex.ignored},
                   "ground_truth": _gt_desc(args)},
        "versions": versions(),
    }
    io.save_json(out / "metrics.json", report)
    io.save_json(out / "config.json", {"argv": sys.argv[1:], **{k: v for k, v in vars(args).items()}})
    return report


def _gt_desc(args):
    return {k: getattr(args, k, None) for k in ("tolerance", "gt", "radius", "gt_soft")}


def run_loops(args) -> dict:
    """One traverse: loop closures with ``args.method``; writes the same outputs as ``match``."""
    out = Path(args.out)
    confs = method_confs(args)
    (src,) = _sources(args, [args.seq])
    encoder, (ex,) = _extract_all(args, [src], [args.method], confs, out)
    res = loops(args.method, ex.features, exclude=args.exclude, conf=confs.get(args.method),
                progress=not args.no_progress)
    out.mkdir(parents=True, exist_ok=True)
    sim_file = write_similarity(out, res.similarity)
    gt_hard = mask = None
    if args.gt:
        if args.radius is None:
            raise ValueError("loops: --gt needs --radius")
        if len(args.gt) != 1:
            raise ValueError("loops: --gt takes one positions file")
        xy = _loop_positions(args.gt[0], src.name, ex.indices)
        gt_hard = evaluate.gt_from_positions(xy, xy, args.radius)
        mask = evaluate.loop_closure_mask(len(ex.features), exclude=args.exclude)
    metrics = {}
    metrics[args.method], curve = method_metrics(res, gt_hard, None, mask=mask)
    metrics[args.method]["similarity_file"] = sim_file
    write_matches(out, res, ex.features.names, ex.features.names)
    plots.plot_similarity(res.similarity, out / "similarity.png", best_db=res.best_db, accepted=res.accepted,
                          gt_hard=gt_hard, title=f"{args.method}: loop closures")
    if gt_hard is not None:
        plots.plot_pr({args.method: curve}, out / "pr.png",
                      title=f"loop closures in {src.name}")
    report = {"methods": metrics,
              "params": {"command": "loops", "seq": str(args.seq), "exclude": args.exclude,
                         "encoder": encoder.name, "encoder_conf": encoder.conf, "method_conf": res.conf,
                         "n_frames": len(ex.features), "encode_seconds": ex.seconds, "skipped": ex.skipped,
                         "ground_truth": _gt_desc(args)},
              "versions": versions()}
    io.save_json(out / "metrics.json", report)
    io.save_json(out / "config.json", {"argv": sys.argv[1:], **vars(args)})
    return report


def _loop_positions(path, traverse, indices):
    """Positions from ``frame,x,y`` or ``traverse,frame,x,y`` files."""
    from vpr import groundtruth

    with open(path, encoding="utf-8") as fh:
        first = fh.readline().lower()
    if "traverse" in first:
        return _xy_for(_combined_positions(path, traverse), indices, path, traverse)
    keys, xy = groundtruth.load_positions_csv(path)
    rows = {int(k) if not isinstance(k, str) else k: tuple(v) for k, v in zip(keys, xy)}
    return _xy_for(rows, indices, path, traverse)


def run_command(args) -> int:
    if args.command == "loops":
        report = run_loops(args)
    else:
        methods = [m.strip() for m in args.methods.split(",") if m.strip()] if args.command == "compare" \
            else [args.method]
        if not methods:
            raise ValueError("--methods is empty")
        report = run_compare(args, methods)
    print(metrics_table(report["methods"]))
    print(f"wrote {args.out}/metrics.json")
    return 0
