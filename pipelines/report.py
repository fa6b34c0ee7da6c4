"""``DIR/report.html``: the run's page, built from what the run wrote and the frames of its sources.

Every command that writes ``metrics.json`` writes it last (:func:`write_report`):
the printed table (as ``metrics.json`` holds it), ``pr.png`` and each
method's ``similarity.png``, and each method's decisions from its
``matches.csv`` as strips of thumbnails (query | best match | true match),
worst first and at most :data:`LIMIT` per method (:func:`vpr.report.choose`;
the page says how many of each outcome it shows). Frames are read again from
the sources by their names; a frame that cannot be read is shown as such.
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

from pipelines.outputs import TABLE, table_cells
from vpr import io, report
from vpr.sources import decode_image

__all__ = ["write_report", "write_table_report", "LIMIT"]

#: Strips per method: the page of a 50,000-frame run stays a few MB.
LIMIT = 120


def _frames(srcs):
    """``read(names) -> {name: image}``: frames of the sources by name (``SESSION/NAME`` too), or image paths."""
    where = {}
    for src in srcs:
        try:
            names = src.names()
        except ValueError:  # paths on stdin: read by their paths
            continue
        for pos, n in enumerate(names):
            where.setdefault(n, (src, pos))
            where.setdefault(f"{src.name}/{n}", (src, pos))

    def read(names) -> dict:
        out = {}
        for n in sorted(set(names), key=lambda n: (id(where[n][0]), where[n][1]) if n in where else (0, 0)):
            if n in where:
                src, pos = where[n]
                out[n] = next((f.image for f in src.iter_range(pos, pos + 1)), None)
            elif n and Path(n).is_file():  # paths on stdin
                out[n] = decode_image(Path(n))[0]
        return out

    return read


def _rows(path: Path) -> list[dict]:
    with open(path, newline="", encoding="utf-8", errors="surrogateescape") as fh:
        return list(csv.DictReader(fh))


def write_report(out, db_srcs=(), q_srcs=(), kind: str = "match", title: str | None = None) -> Path:
    """Write ``out/report.html`` (atomic) from ``out/metrics.json``, the methods' files and the sources' frames.

    ``kind``: ``"match"`` (database x query) or ``"loops"`` (one stream: the
    frame, the earlier frame it closes onto, a true earlier frame).
    """
    out = Path(out)
    metrics = json.loads((out / "metrics.json").read_text())
    params, methods = metrics.get("params", {}), metrics.get("methods", {})
    rows = [(m, table_cells(v, kind)) for m, v in methods.items()]
    figures = [("precision-recall", report.picture((out / "pr.png").read_bytes()))] if (out / "pr.png").is_file() \
        else []
    picked, counts = {}, {}
    for m in methods:
        folder = out / m
        if not (folder / "matches.csv").is_file():
            continue  # a verified variant shares its method's folder
        if (folder / "similarity.png").is_file():
            figures.append((f"{m}: similarity, the accepted matches on it",
                            report.picture((folder / "similarity.png").read_bytes())))
        decisions = _rows(folder / "matches.csv")
        has_gt = bool(decisions) and "right" in decisions[0]
        keys = [report.outcome(r["accepted"] == "1", int(r["right"]) if has_gt and r["right"] != "" else None,
                               (r["true_db"] != "-1") if has_gt else None) for r in decisions]
        score = [float(r["score"]) if r["score"] not in ("", "nan") else -math.inf for r in decisions]
        chosen, counts[m] = report.choose(keys, score, LIMIT)
        picked[m] = [(decisions[k], keys[k], score[k]) for k in chosen]
    q_read, db_read = _frames(q_srcs), _frames(db_srcs or q_srcs)
    q_img = q_read([r["query_name"] for rs in picked.values() for r, _, _ in rs])
    db_img = db_read([r[c] for rs in picked.values() for r, _, _ in rs for c in ("db_name", "true_name") if r.get(c)])
    thumbs = {("q", n): report.thumbnail(i) for n, i in q_img.items()}
    thumbs.update({("db", n): report.thumbnail(i) for n, i in db_img.items()})
    strips = [report.Strip(m, key, int(r["query"]), r["query_name"], r["db_name"], r.get("true_name", ""), s,
                           (thumbs.get(("q", r["query_name"])), thumbs.get(("db", r["db_name"])),
                            thumbs.get(("db", r.get("true_name", "")))))
              for m, rs in picked.items() for r, key, s in rs]
    what = f"{params.get('db', '')} vs {params.get('query', '')}" if kind == "match" else \
        ", ".join(map(str, params.get("seq", []) if isinstance(params.get("seq"), list) else [params.get("seq", "")]))
    gt = {k: v for k, v in (params.get("ground_truth") or {}).items() if v not in (None, [], "")}
    gt_text = ", ".join(f"{k} {' '.join(map(str, v)) if isinstance(v, list) else v}" for k, v in gt.items())
    notes = [f"vpr {params.get('command', '')}: {what}",
             f"ground truth: {gt_text or 'none'}; the table as metrics.json holds it",
             f"at most {LIMIT} decisions per method are shown, chosen by outcome, worst first"]
    sides = ("query", "best match", "true match") if kind == "match" else \
        ("frame", "closes onto", "a true earlier frame")
    page = report.page(title or f"vpr {params.get('command', '')}: {out.name}", TABLE[kind], rows,
                       figures, strips, counts, notes, sides)
    with io.atomic_open(out / "report.html", "w", encoding="utf-8", errors="surrogateescape") as fh:
        fh.write(page)
    return out / "report.html"


def write_table_report(out, title: str, header: list[tuple[str, str]], rows: list[tuple[str, list[str]]],
                       figures=(), notes=()) -> Path:
    """``out/report.html`` of a run without frames to show (a fleet's summary, ``vpr encoders test``): its table,
    as printed, and its plots (``figures``: (caption, PNG path))."""
    out = Path(out)
    pics = [(cap, report.picture(Path(p).read_bytes())) for cap, p in figures if Path(p).is_file()]
    page = report.page(title, header, rows, pics, [], {}, list(notes))
    with io.atomic_open(out / "report.html", "w", encoding="utf-8", errors="surrogateescape") as fh:
        fh.write(page)
    return out / "report.html"
