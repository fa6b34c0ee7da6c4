"""What a run writes: similarity matrices, matches, per-method files, the metrics table and ``metrics.json``.

Every file is written atomically (:mod:`vpr.io`): an interrupted run leaves
only complete files. ``DIR/metrics.json`` and ``DIR/pr.png`` hold every method
run into ``DIR`` on the same inputs, merged under a lock (:func:`merge_metrics`).
"""
from __future__ import annotations

import contextlib
import csv
import json
import platform
import time
import warnings
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from vpr import evaluate, io, methods, plots
from vpr.similarity import TOP_K, topk_sparse
from vpr.types import MatchResult

__all__ = ["MATCH_COLUMNS", "GT_COLUMNS", "DENSE_FILE_BYTES", "versions", "write_similarity", "write_matches",
           "write_method", "merge_metrics", "warn", "claim_methods", "check_pairs", "write_ranked"]


def warn(msg: str) -> None:
    """A one-line warning of the run (``vpr: warning: ...`` on the command line)."""
    warnings.warn(msg, UserWarning, stacklevel=3)


def versions() -> dict:
    """Versions of the libraries behind a result (recorded in ``metrics.json``)."""
    import cv2
    import scipy

    import vpr

    return {"vpr": vpr.__version__, "python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "opencv": cv2.__version__}


#: A dense similarity larger than this (a 4,096 x 4,096 float32) is written as its top-K per query.
DENSE_FILE_BYTES = 64 * 2**20


def write_similarity(folder: Path, S) -> str:
    """Write ``S`` as ``similarity.npy`` (dense, up to :data:`DENSE_FILE_BYTES`) or ``similarity_topk.npz`` (sparse,
    or a larger dense ``S`` cut to its :data:`vpr.similarity.TOP_K` best per query); returns the file name."""
    if not sp.issparse(S) and np.asarray(S).size * 4 > DENSE_FILE_BYTES:
        A = np.asarray(S)
        S = topk_sparse(lambda q0, q1: A[:, q0:q1], A.shape[0], A.shape[1], TOP_K).tocoo()
        keep = np.isfinite(S.data)  # a loop matrix's excluded pairs (-inf) are never matched: not stored
        S = sp.csr_matrix((S.data[keep], (S.row[keep], S.col[keep])), shape=S.shape)
    if sp.issparse(S):
        with io.atomic_path(folder / "similarity_topk.npz") as tmp:
            sp.save_npz(tmp, sp.csr_matrix(S, dtype=np.float32))
        return "similarity_topk.npz"
    io.save_npy(folder / "similarity.npy", np.asarray(S, dtype=np.float32))
    return "similarity.npy"


#: The columns of every command's ``matches.csv``, in order (extra columns follow them).
MATCH_COLUMNS = ("query", "query_name", "best_db", "db_name", "score", "accepted")
#: With ground truth, next: whether the best match is right (1, 0; empty: no best match or a soft-only pair),
#: and a true database frame of the query (the middle one; -1 and empty: it has none).
GT_COLUMNS = ("right", "true_db", "true_name")


def write_matches(folder: Path, res: MatchResult, db_names, q_names, extra: dict | None = None,
                  best_names=None, query_ids=None, gt=None, name_of=None) -> None:
    """``matches.csv``: one row per query with its best database frame, score, decision and ``extra`` columns.

    The schema of every command (:data:`MATCH_COLUMNS`, then :data:`GT_COLUMNS`
    with ground truth, then ``extra``'s columns); ``best_names``: the name of
    each query's best frame, where the database's names are not all at hand
    (``db_names`` None; ``name_of(frame)`` names a true frame then);
    ``query_ids``: the queries' numbers where they do not start at 0 (a
    resumed online run); ``gt``: (gt_hard, gt_soft, mask) as evaluated.
    """
    extra = dict(extra or {})
    if gt is not None:
        right, truth = evaluate.outcomes(res.best, *gt)
        name = name_of or (lambda b: db_names[b])
        extra = {"right": ["" if r < 0 else int(r) for r in right], "true_db": truth.tolist(),
                 "true_name": ["" if t < 0 else name(int(t)) for t in truth], **extra}
    with io.atomic_open(folder / "matches.csv", "w", newline="", encoding="utf-8", errors="surrogateescape") as fh:
        w = csv.writer(fh, lineterminator="\n")  # LF: awk, cut and diff read it as it is
        w.writerow([*MATCH_COLUMNS, *extra])
        for j in range(len(q_names)):
            b = int(res.best[j])
            name = "" if b < 0 else best_names[j] if best_names is not None else db_names[b]
            q = j if query_ids is None else query_ids[j]
            w.writerow([q, q_names[j], b, name, f"{res.score[j]:.6g}", int(bool(res.accepted[j])),
                        *(v[j] for v in extra.values())])


def check_pairs(pairs: int, n_db: int, db) -> None:
    """Refuse ``--pairs N`` beyond the database's ``n_db`` frames (``db``), before any work: hloc's pairs file
    (:func:`write_ranked`) is named for N."""
    if pairs > n_db:
        raise ValueError(f"--pairs {pairs}: more pairs per query than the database's {n_db} frames ({db}); at most "
                         f"{n_db}")


def write_ranked(folder: Path, res: MatchResult, db_names, q_names, top: int = 0, pairs: int = 0,
                 mat: bool = False) -> None:
    """The files the field's tools read, of one method's result: ``top.csv`` (each query's ``top`` best database
    frames, best first, with their scores), hloc's ``pairs-query-METHOD{pairs}.txt`` (``query_name db_name``, the
    ``pairs`` best of each query, as hloc's ``pairs_from_retrieval`` writes them) and, with ``mat``,
    ``similarity.mat`` (MATLAB: ``S`` database x query, ``best`` each query's best database frame counted from 1, 0
    for none, ``score``, ``accepted``)."""
    from vpr.verify import top_candidates  # the ranking: decreasing similarity, ties by lower index

    n = max(int(top), int(pairs))
    if n:
        idx = top_candidates(res.similarity, min(n, len(db_names)))
        S = res.similarity.tocsc() if sp.issparse(res.similarity) else res.similarity
        if top:
            with io.atomic_open(folder / "top.csv", "w", newline="", encoding="utf-8", errors="surrogateescape") as fh:
                w = csv.writer(fh, lineterminator="\n")
                w.writerow(["query", "query_name", "rank", "db", "db_name", "score"])
                for j, row in enumerate(idx):
                    for r, b in enumerate(row[:top]):
                        if b >= 0:
                            w.writerow([j, q_names[j], r + 1, int(b), db_names[b], f"{float(S[b, j]):.6g}"])
        if pairs:
            spaced = next((x for x in (*q_names, *db_names) if any(c.isspace() for c in x)), None)
            if spaced is not None:
                warn(f"{folder}: no hloc pairs file: the frame name {spaced!r} holds white space, which hloc's pairs "
                     "files separate names by")
            else:
                lines = [f"{q_names[j]} {db_names[b]}\n" for j, row in enumerate(idx) for b in row[:pairs] if b >= 0]
                with io.atomic_open(folder / f"pairs-query-{res.method}{pairs}.txt", "w", encoding="utf-8",
                                    errors="surrogateescape") as fh:
                    fh.writelines(lines)
    if mat:
        import scipy.io

        with io.atomic_path(folder / "similarity.mat") as tmp:
            scipy.io.savemat(tmp, {"S": res.similarity, "best": res.best + 1, "score": res.score,
                                   "accepted": res.accepted.astype(np.uint8)}, do_compression=True)


def write_stream_pairs(folder: Path, res: MatchResult, names, n: int, starts=(0,)) -> Path:
    """hloc's pairs file of one stream, what structure from motion of a video needs: each frame with its ``n`` next
    frames of its session, and each accepted loop closure (frame, the earlier frame it closes onto); one pair a line,
    each once, in frame order: ``pairs-sequential{n}-loops.txt``."""
    bounds = [*sorted({0, *(int(a) for a in starts)}), len(names)]
    end = np.repeat(bounds[1:], np.diff(bounds))  # each frame's session end
    pairs = {(j, k) for j in range(len(names)) for k in range(j + 1, min(j + 1 + int(n), int(end[j])))}
    pairs |= {(int(b), j) for j, (b, a) in enumerate(zip(res.best, res.accepted, strict=True)) if a and b >= 0}
    path = folder / f"pairs-sequential{n}-loops.txt"
    with io.atomic_open(path, "w", encoding="utf-8", errors="surrogateescape") as fh:
        fh.writelines(f"{names[a]} {names[b]}\n" for a, b in sorted(pairs, key=lambda p: (max(p), min(p))))
    return path


def write_method(folder: Path, res: MatchResult, evaluated: tuple, db_names, q_names, truth: tuple = (None, None, None),
                 verification: tuple | None = None, title: str = "", loops: bool = False,
                 matches: dict | None = None) -> dict:
    """Write one method's files in its folder; return its metrics entries (``m`` and ``m+verify``, ``m`` the method
    of ``res``).

    ``evaluated``: the (metrics, curve) of :func:`vpr.evaluate.method_metrics` for ``res``; ``truth``: (gt_hard,
    gt_soft, mask) as evaluated. With ``verification`` (verifier, candidates, progress), each query's best candidates
    are re-ordered by geometric inliers (:meth:`vpr.verify.Verifier.verify`): the entry ``m+verify`` evaluates that
    matrix and its decisions. ``matches``: what ``matches.csv`` adds (an online run's): ``columns`` (more
    columns), and ``best_names``, ``query_ids``, ``name_of`` of :func:`write_matches`. The files the field's tools read
    are :func:`write_ranked`'s.
    """
    names = dict(matches or {})
    columns = names.pop("columns", None)
    m = res.method
    gt_hard, gt_soft, mask = truth
    verifier, verify, progress = verification or (None, 0, False)
    sim_file = write_similarity(folder, res.similarity)
    entries = {}
    metrics, curve = evaluated
    metrics["similarity_file"] = f"{folder.name}/{sim_file}"
    entries[m] = (metrics, curve)
    extra = {}
    if verifier is not None:
        t0 = time.perf_counter()
        vr = verifier.verify(res.similarity, verify, progress=progress)
        verified = vr.result(res, res.seconds + time.perf_counter() - t0)  # pairs verified before are cached
        extra = {"verified_db": vr.best_db.tolist(),
                 "verified_name": [db_names[b] if b >= 0 else "" for b in vr.best_db],
                 "inliers": np.where(vr.best_db >= 0, vr.score, -1).astype(int).tolist(),
                 "verified": vr.accepted.astype(int).tolist()}
        if gt_hard is not None:  # whether each verified match is right, as GT_COLUMNS say of the best match
            right, _ = evaluate.outcomes(vr.best_db, gt_hard, gt_soft, mask)
            extra["verified_right"] = ["" if r < 0 else int(r) for r in right]
        vm, vcurve = evaluate.method_metrics(verified, gt_hard, gt_soft)
        vm["seconds"] = round(verified.seconds, 4)
        vm["similarity_file"] = metrics["similarity_file"]
        entries[m + "+verify"] = (vm, vcurve)
    write_matches(folder, res, db_names, q_names, {**extra, **(columns or {})},
                  gt=None if gt_hard is None else (gt_hard, gt_soft, mask), **names)
    name_of = names.get("name_of")
    rows = list(db_names) if db_names is not None else [name_of(i) for i in range(res.similarity.shape[0])]
    io.save_json(folder / "frames.json", {"rows": rows, "columns": list(q_names)}, indent=None)
    plots.plot_similarity(res.similarity, folder / "similarity.png", best_db=res.best, accepted=res.accepted,
                          gt_hard=gt_hard, gt_soft=gt_soft, title=title or f"{m}: database x query",
                          value_label=methods.get_class(m).score_label if m in methods.available() else "similarity",
                          axis_labels=("earlier frame", "frame") if loops else ("database", "query"), mask=mask)
    out = {}
    for name, (mm, c) in entries.items():
        if c is not None:
            fname = "pr_curve_verify.npz" if name.endswith("+verify") else "pr_curve.npz"
            with io.atomic_path(folder / fname) as tmp:
                with open(tmp, "wb") as fh:
                    keep = evaluate.thin_pr(c[0], c[1])
                    np.savez(fh, precision=np.asarray(c[0], np.float64)[keep],
                             recall=np.asarray(c[1], np.float64)[keep])
            mm["pr_curve"] = f"{folder.name}/{fname}"
        out[name] = mm
    return out


def _jsonable(o):
    return o.item() if isinstance(o, np.generic) else o.tolist() if isinstance(o, np.ndarray) else str(o)


def claim_methods(out: Path, names) -> contextlib.ExitStack:
    """Hold ``out``'s lock of each method in ``names`` for a run (:func:`vpr.io.claimed`); close it when done.

    Runs of other methods into one ``out`` go on side by side (their
    metrics are merged); a second run of the same method into it while the
    first runs is refused, rather than silently replacing its files.
    """
    stack = contextlib.ExitStack()
    try:
        for m in names:
            stack.enter_context(io.claimed(Path(out) / f".{m}.lock", f"--out {out}: {m}"))
    except BaseException:
        stack.close()
        raise
    return stack


def merge_metrics(out: Path, report: dict, pr_title: str) -> dict:
    """Merge this run's ``report`` into ``out/metrics.json`` and redraw ``out/pr.png``; return the merged report.

    Runs on the same inputs (``params["inputs"]``) add or replace their
    methods; a metrics.json of other inputs is replaced (with a warning). The
    read-modify-write holds a lock (``out/.metrics.lock``), so that concurrent
    runs into one folder keep each other's methods.
    """
    with io.locked(out / ".metrics.lock"):
        old = None
        path = out / "metrics.json"
        if path.is_file():
            try:
                old = json.loads(path.read_text(encoding="utf-8"))
            except ValueError:
                warn(f"{path}: unreadable, replaced")
        merged = report
        if isinstance(old, dict) and isinstance(old.get("methods"), dict):
            # compared as JSON: tuples and NumPy scalars of this run read back as lists and numbers
            same = json.loads(json.dumps(report["params"]["inputs"], default=_jsonable))
            if old.get("params", {}).get("inputs") == same:
                merged = {**report, "methods": {**old["methods"], **report["methods"]}}
                merged["params"] = {**report["params"], "method_conf": {**old["params"].get("method_conf", {}),
                                                                        **report["params"]["method_conf"]}}
            else:
                warn(f"{path} held results of other inputs or settings "
                     f"({', '.join(old['methods'])}); replaced by this run's")
        curves = {}
        for name, m in merged["methods"].items():
            f = m.get("pr_curve")
            if f and (out / f).is_file():
                try:
                    with np.load(out / f) as z:
                        curves[name] = (z["precision"], z["recall"])
                except (OSError, ValueError, KeyError):
                    pass  # a damaged curve file is not drawn; the metrics stay
        io.save_json(path, merged)
        if curves:
            plots.plot_pr(curves, out / "pr.png", title=pr_title)
    return merged
