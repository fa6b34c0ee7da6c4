"""A run's table and report page: the metrics as printed, the plots, and the frames side by side, worst first."""
from __future__ import annotations

import base64
import csv
import html
import json
import math
import struct
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import cv2
import numpy as np

from vpr import io

from .table import TABLE, metrics_table, recall_lines, recall_notes, table_cells

__all__ = ["recall_lines", "OUTCOMES", "TABLE", "Strip", "table_cells", "metrics_table", "outcome", "choose",
           "caption", "thumbnail", "picture", "png_text", "page", "settings", "pair_frames", "write", "write_table",
           "sampling_note"]

#: Strips per method: the page of a 50,000-frame run stays a few MB.
LIMIT = 120
#: Frames per side embedded for the pair under a click on a matrix (every k-th of a longer run: the nearest shown).
PAIR_LIMIT = 300

#: Outcomes of a decision, worst first: (key, label). Without ground truth only ``accepted`` and ``rejected``.
OUTCOMES = (("wrong", "accepted, wrong"), ("missed", "rejected, right"), ("lost", "rejected, wrong"),
            ("right", "accepted, right"), ("soft", "in the soft band (neither)"), ("none", "no true match"),
            ("accepted", "accepted"), ("rejected", "rejected"))
_LABEL = dict(OUTCOMES)
#: Of ``limit`` strips per method, the share each outcome may take before what it leaves goes to the next.
_SHARE = {"wrong": 0.35, "missed": 0.25, "lost": 0.15, "right": 0.1, "soft": 0.05, "none": 0.1, "accepted": 0.5,
          "rejected": 0.5}


def outcome(accepted: bool, right: int | None, has_truth: bool | None, soft: bool = False) -> str:
    """The outcome key of one decision: ``right`` 1, 0 or None (no ground truth, a soft-only pair, no match);
    ``soft``: the best match is a soft-only pair, neither right nor wrong, accepted or not."""
    if has_truth is None:
        return "accepted" if accepted else "rejected"
    if soft:
        return "soft"
    if accepted:
        return "right" if right == 1 else "wrong" if right == 0 else "soft" if has_truth else "none"
    if not has_truth:
        return "none"
    return "missed" if right == 1 else "lost"


def choose(keys, score, limit: int) -> tuple[np.ndarray, dict]:
    """The decisions to show, worst first, at most ``limit``: ``(positions, {outcome: (shown, of)})``.

    Within an outcome: accepted and wrong, rejected ones and those without a true match by score, highest first (the
    most confident mistakes, the nearest misses); accepted and right by score, lowest first (the closest calls). An
    outcome's share (:data:`_SHARE`) that it does not fill goes to the outcomes after it; what is still left, to the
    worst outcomes first.
    """
    keys = np.asarray(keys)
    score = np.nan_to_num(np.asarray(score, np.float64), nan=-np.inf)
    picks, counts, left, carry = {}, {}, int(limit), 0
    for k, _ in OUTCOMES:
        pos = np.flatnonzero(keys == k)
        if not pos.size:
            continue
        order = np.argsort(score[pos] if k == "right" else -score[pos], kind="stable")
        quota = int(round(limit * _SHARE[k])) + carry
        take = min(pos.size, quota, left)
        carry, left = quota - take, left - take
        picks[k] = pos[order]
        counts[k] = [int(take), int(pos.size)]
    for k in picks:  # what the shares left unused, to the worst outcomes first
        more = min(left, counts[k][1] - counts[k][0])
        counts[k][0] += more
        left -= more
    out = [picks[k][:counts[k][0]] for k in picks]
    counts = {k: tuple(c) for k, c in counts.items()}
    return (np.concatenate(out) if out else np.zeros(0, np.int64)), counts


def caption(name: str, index: int, t0: float | None = None) -> str:
    """A frame's short caption: ``frame 120 · 12.5 s`` where its name holds a time (a bag's ``topic@stamp``;
    ``t0``: the first frame's), else ``frame 120 · FILE`` (the file name, shortened)."""
    stamp = _stamp(name)
    if stamp is not None and t0 is not None:
        return f"frame {index} · {stamp - t0:.1f} s"
    base = str(name).replace("\\", "/").rsplit("/", 1)[-1]
    return f"frame {index} · {base if len(base) <= 28 else base[:12] + '…' + base[-12:]}"


def _stamp(name: str) -> float | None:
    if "@" not in str(name):
        return None
    try:
        return float(str(name).rsplit("@", 1)[1])
    except ValueError:
        return None


def _first_stamp(names) -> float | None:
    return next((t for t in (_stamp(n) for n in names) if t is not None), None)


def thumbnail(img: np.ndarray | None, width: int = 160, quality: int = 75) -> str | None:
    """A JPEG ``data:`` URI of ``img`` (uint8 BGR) scaled down to ``width`` pixels (None for None)."""
    if img is None:
        return None
    h, w = img.shape[:2]
    small = cv2.resize(img, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA) if w > width else img
    ok, buf = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    return "data:image/jpeg;base64," + base64.b64encode(buf.tobytes()).decode("ascii") if ok else None


def picture(data: bytes, width: int = 900) -> str | None:
    """A plot (PNG bytes) as a JPEG ``data:`` URI at most ``width`` pixels wide: a page of several stays small."""
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    return thumbnail(img, width, 88)


def png_text(data: bytes) -> dict:
    """The text chunks (``tEXt``) of a PNG file's bytes: {keyword: text}; {} for bytes that are not a PNG."""
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        return {}
    out, pos = {}, 8
    while pos + 8 <= len(data):
        n, kind = struct.unpack(">I4s", data[pos:pos + 8])
        if kind == b"tEXt":
            key, _, text = data[pos + 8:pos + 8 + n].partition(b"\0")
            out[key.decode("latin-1")] = text.decode("latin-1")
        elif kind == b"IEND":
            break
        pos += 12 + n
    return out


@dataclass
class Strip:
    """One decision as the page shows it: the query frame, its best match and a true match, with what was decided."""

    method: str
    outcome: str
    query: int
    query_name: str
    best: int  # the best match's index (-1: none)
    best_name: str
    true_name: str
    score: float
    images: tuple  # data URIs (or None) of the query, the best match and the true match
    captions: tuple = ()  # short captions of the three frames (:func:`caption`)





def _asset(name: str) -> str:
    """The page's stylesheet or script, shipped beside this module."""
    return resources.files(__package__).joinpath(name).read_text(encoding="utf-8")


def sampling_note(method: str, m: dict) -> str | None:
    """The line a report says of a method whose query was driven at another speed and followed (``m``: its
    ``metrics.json`` entry, ``sampling``); None where every frame was answered as it came."""
    s = m.get("sampling")
    if not s:
        return None

    def how(k: dict, whose: str) -> str:
        if k.get("db_step"):
            apart = f", {k['db_apart']} frames they place apart left undecided" if k.get("db_apart") else ""
            return f"matched again against {whose} {k['db_step']} maps of one frame in {k['db_step']}{apart}"
        filled = f", {k['query_filled']} placed between the accepted frames around them" if k.get("query_filled") \
            else ""
        return f"its frames matched as {k['query_step']} queries of one frame in {k['query_step']}{filled}"

    if "runs" in s:  # loops of one run: the stretches whose best earlier frames read another speed
        said = [f"frames {f['frames'][0]}-{f['frames'][1]} moved {f['speed']:.2f} earlier frames a frame, "
                + how(f, "the frames before them as") + f": {f['closures']} closures taken, confirmed by the frames "
                "after them" for f in s["runs"]]
        return f"{method}: {'; '.join(said)} (--query-speed follow)"
    if "sessions" in s:  # loops: every later session read, those off speed followed
        said = [f"session {f['session']} moved {f['speed']:.2f} of the earlier sessions' frames a frame, "
                + how(f, "the earlier sessions'") for f in s["sessions"] if f.get("db_step") or f.get("query_step")]
        return f"{method}: {'; '.join(said)} (--query-speed follow)" if said else None
    if "db_step_frames" in s or "query_step_frames" in s:  # localize: frames answered so while the speed lasted
        said = [f"{s[k + '_frames']} frames answered by the map's {s[k]} maps of one frame in {s[k]}"
                + (f" ({s['db_apart']} placed apart by them, left undecided)" if s.get("db_apart") else "")
                if k == "db_step" else f"{s[k + '_frames']} frames answered as {s[k]} queries of one frame in {s[k]}"
                + (f" ({s['query_filled']} by the frame before)" if s.get("query_filled") else "")
                for k in ("db_step", "query_step") if s.get(k + "_frames")]
        return f"{method}: the query was driven at another speed than the map: {'; '.join(said)} (--query-speed follow)"
    whose = "the database's"
    return (f"{method}: the query moved {s['speed']:.2f} database frames a frame along the run's accepted paths, "
            f"{how(s, whose)} (--query-speed follow)")


def _esc(x) -> str:
    return html.escape(str(x), quote=True)


def _figure(uri: str | None, caption: str, pics: dict | None = None, matrix: dict | None = None,
            title: str = "") -> str:
    """A picture with its caption; with ``pics`` (data URI -> id) the picture is named and filled in by the page's
    script, so that a frame shown in many strips is in the file once. ``matrix``: a similarity matrix's
    ``method``, ``box``, ``shape`` and ``labels`` (rows, columns): a click on it shows the nearest strip."""
    if not uri:
        pic = '<div class="missing">not read</div>'
    elif matrix is not None:
        attrs = " ".join(f'data-{k}="{_esc(json.dumps(v) if k != "method" else v)}"' for k, v in matrix.items())
        return (f'<figure><img class="matrix" src="{uri}" alt="{_esc(caption)}" {attrs}><figcaption>{_esc(caption)}'
                ' (click a pair to see its frames) <button class="full-size">full size</button> '
                '<span class="at"></span></figcaption><div class="pair"></div></figure>')
    elif pics is None:
        pic = f'<a href="{uri}" target="_blank"><img src="{uri}" alt="{_esc(caption)}"></a>'
    else:
        pic = f'<img data-pic="{pics.setdefault(uri, f"p{len(pics)}")}" alt="{_esc(caption)}">'
    tip = f' title="{_esc(title)}"' if title else ""
    return f"<figure{tip}>{pic}<figcaption>{_esc(caption)}</figcaption></figure>"


#: ``params`` of ``metrics.json`` that are measurements or bookkeeping, not settings of the run
_NOT_SETTINGS = frozenset({"inputs", "skipped", "ignored_files", "encode_seconds", "cached", "seconds", "map_seconds",
                           "shipped", "learn_seconds"})


def settings(params: dict) -> list[tuple[str, str]]:
    """The settings of a run as the page shows them: ``(key, value)`` of ``metrics.json``'s ``params`` (a value
    that is not a string or number as compact JSON), measurements and bookkeeping left out."""
    def text(v) -> str:
        return v if isinstance(v, str) else json.dumps(v, sort_keys=True, separators=(", ", ": "))
    return [(k, text(v)) for k, v in params.items() if k not in _NOT_SETTINGS]


def page(title: str, header: list[tuple[str, str]], rows: list[tuple[str, list[str]]], figures: list[tuple],
         strips: list[Strip], counts: dict, notes: list[str], sides=("query", "best match", "true match"),
         run: dict | None = None) -> str:
    """The report's HTML.

    ``header``/``rows``: the metrics table's (key, label) columns and each method's printed cells; ``figures``:
    (caption, data URI[, matrix]) (:func:`_figure`); ``strips``: the decisions shown; ``counts``: per method {outcome:
    (shown, of)}; ``notes``: lines under the title; ``sides``: what a strip's three frames are; ``run``: what the run
    adds, each optional: ``sessions`` (per method :func:`vpr.evaluate.session_pairs`' rows), ``params``
    (``metrics.json``'s params: :func:`settings`) and ``pairs`` (the frames a click on a matrix shows:
    :func:`pair_frames`).
    """
    sessions, params, pairs = ((run or {}).get(k) for k in ("sessions", "params", "pairs"))
    out = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
           f"<title>{_esc(title)}</title><style>{_asset('page.css')}</style></head><body>", f"<h1>{_esc(title)}</h1>"]
    out += [f'<p class="note">{_esc(n)}</p>' for n in notes]
    labels = ["method", *(lab for _, lab in header)]
    out.append('<table id="metrics"><tr>' + "".join(f"<th>{_esc(h)}</th>" for h in labels) + "</tr>")
    for name, cells in rows:
        link = f'<a href="#strips" data-method="{_esc(name)}">{_esc(name)}</a>' if name in counts else _esc(name)
        out.append(f'<tr data-method="{_esc(name)}"><td>{link}</td>'
                   + "".join(f'<td data-key="{_esc(k)}">{_esc(c)}</td>'
                             for (k, _), c in zip(header, cells, strict=True))
                   + "</tr>")
    out.append("</table>")
    for m, pairs in (sessions or {}).items():
        out.append(f'<table class="sessions" data-method="{_esc(m)}"><caption>{_esc(m)}: closures per pair of '
                   "sessions</caption><tr><th>session</th><th>onto</th><th>frames with a loop</th><th>accepted</th>"
                   "<th>precision</th><th>recall</th></tr>")
        for p in pairs:
            cells = [p["session"], p["onto"], "-" if p["frames"] is None else p["frames"], p["accepted"],
                     *("-" if p[k] is None else f"{p[k]:.3f}" for k in ("precision", "recall"))]
            out.append("<tr>" + "".join(f"<td>{_esc(c)}</td>" for c in cells) + "</tr>")
        out.append("</table>")
    if params:
        out.append('<details id="settings"><summary>Settings of this run (metrics.json params)</summary><table>'
                   + "".join(f'<tr><th>{_esc(k)}</th><td data-key="{_esc(k)}">{_esc(v)}</td></tr>'
                             for k, v in settings(params)) + "</table></details>")
    out.append('<div class="figs">' + "".join(_figure(f[1], f[0], None, *f[2:]) for f in figures) + "</div>")
    out.append('<h2 id="strips">The decisions, worst first</h2>' if len(sides) > 2 else
               '<h2 id="strips">The decisions, by score (no ground truth: none is known right or wrong)</h2>')
    for m, c in counts.items():
        said = "; ".join(f"{_LABEL[k]} {s} of {n}" for k, (s, n) in c.items())
        out.append(f'<p class="note">{_esc(m)}: {_esc(said)}</p>')
    out.append('<div id="filters">method: <button data-filter="method" data-value="all">all</button>'
               + "".join(f'<button data-filter="method" data-value="{_esc(m)}">{_esc(m)}</button>' for m in counts)
               + '<br>outcome: <button data-filter="outcome" data-value="all">all</button>'
               + "".join(f'<button data-filter="outcome" data-value="{k}">{_esc(lab)}</button>'
                         for k, lab in OUTCOMES if any(k in c for c in counts.values()))
               + ' <span id="shown"></span></div>')
    pics: dict[str, str] = {}
    out.append('<div id="strip-list">')
    for s in strips:
        short = s.captions or (s.query_name, s.best_name, s.true_name)
        caps = (f"{sides[0]}: {short[0]}", f"{sides[1]}: {short[1] if s.best_name else '(none)'}",
                *([f"{sides[2]}: {short[2] if s.true_name else '(none)'}"] if len(sides) > 2 else []))
        full = (s.query_name, s.best_name, s.true_name)
        score = f"{s.score:.3f}" if np.isfinite(s.score) else "-"
        out.append(f'<div class="strip {s.outcome}" data-method="{_esc(s.method)}" data-outcome="{s.outcome}" '
                   f'data-query="{s.query}" data-best="{s.best}" id="s-{_esc(s.method)}-{s.query}">'
                   f'<b>{_esc(s.method)}</b> · {_esc(_LABEL[s.outcome])} · score '
                   f"{score}<br>" + "".join(_figure(u, c, pics, title=t)
                                            for u, c, t in zip(s.images, caps, full, strict=False))
                   + "</div>")
    out.append("</div>")
    # the pictures once, before the script that puts them in place
    out.append('<script type="application/json" id="pics">'
               + json.dumps({k: uri for uri, k in pics.items()}).replace("</", "<\\/") + "</script>")
    if pairs:
        out.append('<script type="application/json" id="pairs">' + json.dumps(pairs).replace("</", "<\\/")
                   + "</script>")
    out.append(f"<script>{_asset('page.js')}</script>")
    out.append('<script type="application/json" id="counts">' + json.dumps(counts).replace("</", "<\\/")
               + "</script></body></html>")
    return "\n".join(out)


def pair_frames(frames: dict, read_query, read_db, same: bool) -> dict:
    """What a click on a matrix shows: per side (``rows``: the database or earlier frames; ``columns``: the
    queries, left out when ``same``, one stream) at most :data:`PAIR_LIMIT` frames, every ``step``-th, with their
    index, name, short caption (:func:`caption`) and thumbnail. ``frames``: a method's ``frames.json``."""
    def side(names, read) -> dict:
        step = max(1, math.ceil(len(names) / PAIR_LIMIT))
        index = list(range(0, len(names), step))
        imgs = read([names[i] for i in index])
        t0 = _first_stamp(names)
        return {"step": step, "index": index, "names": [names[i] for i in index],
                "captions": [caption(names[i], i, t0) for i in index],
                "pics": [thumbnail(imgs.get(names[i]), 96, 60) for i in index]}

    out = {"rows": side(frames["rows"], read_db)}
    if not same:
        out["columns"] = side(frames["columns"], read_query)
    return out


def _rows(path: Path) -> list[dict]:
    with open(path, newline="", encoding="utf-8", errors="surrogateescape") as fh:
        return list(csv.DictReader(fh))


def _save(out: Path, text: str) -> Path:
    with io.atomic_open(out / "report.html", "w", encoding="utf-8", errors="surrogateescape") as fh:
        fh.write(text)
    return out / "report.html"


def write(out, read_query, read_db, kind: str = "match", title: str | None = None) -> Path:
    """Write ``out/report.html`` (atomic) from ``out/metrics.json``, the methods' files and their frames.

    ``read_query(names)`` / ``read_db(names)``: ``{name: uint8 BGR image}`` of the frames named in ``matches.csv`` (a
    frame left out is shown as not read). ``kind``: ``"match"`` (database x query) or ``"loops"`` (one stream: the
    frame, the earlier frame it closes onto, a true earlier frame).
    """
    out = Path(out)
    metrics = json.loads((out / "metrics.json").read_text())
    params, methods = metrics.get("params", {}), metrics.get("methods", {})
    rows = [(m, table_cells(v, kind)) for m, v in methods.items()]
    figures = [("precision-recall", picture((out / "pr.png").read_bytes()))] if (out / "pr.png").is_file() else []
    picked, counts, truth_known = {}, {}, False
    labels = ["database", "query"] if kind == "match" else ["earlier frame", "frame"]
    for m in methods:
        base, _, variant = m.partition("+")
        folder = out / base
        if not (folder / "matches.csv").is_file():
            continue
        decisions = _rows(folder / "matches.csv")
        if variant == "verify":  # a verified variant: its method's rows with the verified match and decision
            if not decisions or "verified_db" not in decisions[0]:
                continue
            decisions = [{**{k: v for k, v in r.items() if k != "right"}, "best_db": r["verified_db"],
                          "db_name": r["verified_name"], "accepted": r["verified"], "score": r["inliers"],
                          **({"right": r["verified_right"]} if "verified_right" in r else {})} for r in decisions]
        elif variant:
            continue
        if not variant and (folder / "similarity.png").is_file():
            png = (folder / "similarity.png").read_bytes()
            where = png_text(png).get("vpr-matrix")
            figures.append((f"{m}: similarity, the accepted matches on it", picture(png),
                            *([{"method": m, **json.loads(where), "labels": labels}] if where else [])))
        has_gt = bool(decisions) and "right" in decisions[0]
        keys = [outcome(r["accepted"] == "1", int(r["right"]) if has_gt and r["right"] != "" else None,
                        (r["true_db"] != "-1") if has_gt else None,
                        has_gt and r["right"] == "" and int(r["best_db"] or -1) >= 0) for r in decisions]
        truth_known = truth_known or has_gt
        score = [float(r["score"]) if r["score"] not in ("", "nan") else -math.inf for r in decisions]
        chosen, counts[m] = choose(keys, score, LIMIT)
        picked[m] = [(decisions[k], keys[k], score[k]) for k in chosen]
    q_img = read_query([r["query_name"] for rs in picked.values() for r, _, _ in rs])
    db_img = read_db([r[c] for rs in picked.values() for r, _, _ in rs for c in ("db_name", "true_name") if r.get(c)])
    thumbs = {("q", n): thumbnail(i) for n, i in q_img.items()}
    thumbs.update({("db", n): thumbnail(i) for n, i in db_img.items()})
    frames = next((json.loads((out / m.partition("+")[0] / "frames.json").read_text()) for m in methods
                   if (out / m.partition("+")[0] / "frames.json").is_file()), None)
    t_q = _first_stamp(frames["columns"] if frames else [r["query_name"] for rs in picked.values() for r, _, _ in rs])
    t_db = t_q if kind == "loops" else _first_stamp(frames["rows"]) if frames else None

    def short(r) -> tuple:
        return (caption(r["query_name"], int(r["query"]), t_q),
                caption(r["db_name"], int(r["best_db"] or -1), t_db) if r["db_name"] else "",
                caption(r.get("true_name", ""), int(r.get("true_db") or -1), t_db) if r.get("true_name") else "")

    strips = [Strip(m, key, int(r["query"]), r["query_name"], int(r["best_db"] or -1), r["db_name"],
                    r.get("true_name", ""), s,
                    (thumbs.get(("q", r["query_name"])), thumbs.get(("db", r["db_name"])),
                     thumbs.get(("db", r.get("true_name", "")))), short(r))
              for m, rs in picked.items() for r, key, s in rs]
    pairs = pair_frames(frames, read_query, read_db, kind == "loops" and frames["rows"] == frames["columns"]) \
        if frames else None
    def source(v) -> str:
        return "image paths on stdin" if v == "-" else str(v)

    seq = params.get("seq", "")
    what = f"{source(params.get('db') or params.get('map_or_db', ''))} vs {source(params.get('query', ''))}" \
        if kind == "match" else ", ".join(map(source, seq if isinstance(seq, list) else [seq]))
    truth = params.get("ground_truth") or {}
    gt = {k: v for k, v in truth.items() if v not in (None, [], "") and k in ("tolerance", "gt", "radius", "gt_soft",
                                                                               "gt_topic")}
    gt_text = ", ".join(f"{k} {' '.join(map(str, v)) if isinstance(v, list) else v}" for k, v in gt.items())
    units = [t for t in (truth.get("tolerance_text"), truth.get("gt_soft_text")) if t]
    if units:
        gt_text += f" (in frames kept: {'; '.join(units)})"
    notes = [f"vpr {params.get('command', '')}: {what}",
             f"ground truth: {gt_text or 'none'}; the table as metrics.json holds it",
             f"at most {LIMIT} decisions per method are shown, chosen by outcome, worst first" if truth_known else
             f"no ground truth: at most {LIMIT} decisions per method are shown, the accepted and the rejected by "
             "score, highest first"]
    notes += [n for n in (sampling_note(m, v) for m, v in methods.items()) if n]
    notes += recall_notes(methods, kind)
    top_k = [m for m, v in methods.items() if str(v.get("similarity_file", "")).endswith("_topk.npz")]
    if top_k:
        budget = params.get("memory_budget")
        why = f"beyond the memory budget, {budget['text']}" if budget else "as an online run keeps it"
        notes.append(f"similarity kept as each query's best frames (top-K, {why}): {', '.join(top_k)}"
                     + ("; the others dense" if len(top_k) < len(methods) else ""))
    sides = ("query", "best match", "true match") if kind == "match" else \
        ("frame", "closes onto", "a true earlier frame")
    sides = sides if truth_known else sides[:2]
    sessions = {m: v["sessions"] for m, v in methods.items() if v.get("sessions")}
    return _save(out, page(title or f"vpr {params.get('command', '')}: {out.name}", TABLE[kind], rows, figures,
                           strips, counts, notes, sides, {"sessions": sessions, "params": params, "pairs": pairs}))


def write_table(out, title: str, header: list[tuple[str, str]], rows: list[tuple[str, list[str]]], figures=(),
                notes=()) -> Path:
    """``out/report.html`` of a run without frames to show (a fleet's summary, an encoder's test): its table,
    as printed, and its plots (``figures``: (caption, PNG path))."""
    pics = [(cap, picture(Path(p).read_bytes())) for cap, p in figures if Path(p).is_file()]
    return _save(Path(out), page(title, header, rows, pics, [], {}, list(notes)))
