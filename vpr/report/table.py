"""The printed metrics table of every command, and its Recall@N beside it (on the terminal and the report page)."""
from __future__ import annotations

__all__ = ["TABLE", "table_cells", "metrics_table", "recall_lines", "recall_notes"]


#: Columns of the printed table: (metrics key, header).
TABLE = {"match": [("ap", "AP"), ("recall_at_100p", "R@100P"), ("recall_at_1", "R@1"), ("n_accepted", "accepted"),
                   ("precision_accepted", "P(acc)"), ("recall_accepted", "R(acc)"), ("seconds", "seconds")],
         "loops": [("ap", "AP"), ("frame_recall_at_100p", "R@100P"), ("recall_at_1", "R@1"), ("n_accepted", "accepted"),
                   ("precision_accepted", "P(acc)"), ("recall_accepted", "R(acc)"), ("false_per_1000", "false/1k"),
                   ("seconds", "seconds")]}


def table_cells(m: dict, kind: str = "match") -> list[str]:
    """One method's cells of the printed table (:data:`TABLE`): integers as they are, numbers to 3 decimals, ``-``
    for a metric that is not there or undefined."""
    return [(str(m[k]) if isinstance(m[k], int) else f"{m[k]:.3f}") if isinstance(m.get(k), (int, float)) else "-"
            for k, _ in TABLE[kind]]


def metrics_table(table: dict, kind: str = "match", ground_truth: dict | None = None) -> str:
    """The printed table: one row per method of ``{method: metrics}`` (``kind``: ``"match"`` or ``"loops"``).

    A metric that is not there (no ground truth) or undefined (the precision of no accepted match) prints as ``-``.
    With a soft band (``--gt-soft``) a legend says that R@1 and P(acc) ignore best matches there, and how many.
    ``ground_truth``: ``params.ground_truth`` of ``metrics.json``; a tolerance is said in both its units (frames kept,
    input frames).
    """
    keys = TABLE[kind]
    lines = [f"{'method':<22}" + "".join(f"{h:>10}" for _, h in keys)]
    for name, m in table.items():
        lines.append(f"{name:<22}" + "".join(f"{c:>10}" for c in table_cells(m, kind)))
    soft = {name: m["best_in_soft"] for name, m in table.items() if "best_in_soft" in m}
    if soft:
        lines.append("R@1, AP, R@100P and P(acc) ignore best matches in the soft band (--gt-soft): neither right nor "
                     "wrong. Best matches there: " + ", ".join(f"{n} {c}" for n, c in soft.items()))
    lines += recall_lines(table, kind)
    units = [t for t in ((ground_truth or {}).get(k) for k in ("tolerance_text", "gt_soft_text")) if t]
    if units:
        lines.append("ground truth in frames kept (after --step / --fps / --every): " + "; ".join(units))
    return "\n".join(lines)


def _recall_words(kind: str, r: dict) -> tuple[str, str]:
    """(every query, queries with a true match) in a ``kind``'s words."""
    if kind == "loops":
        return f"every frame ({r['queries']})", f"the {r['queries_with_true_match']} frames with an earlier true match"
    return f"every query (the field's: {r['queries']} queries)", f"the {r['queries_with_true_match']} with a true match"


def recall_lines(table: dict, kind: str = "match") -> list[str]:
    """Recall@N of the methods that have it (metrics.json's ``recall_at_n``), over every query (the field's
    denominator; loops: every frame) and over the queries with a true match (the table's R@1), as lines of a small
    table."""
    rn = {name: m["recall_at_n"] for name, m in table.items() if m.get("recall_at_n")}
    if not rn:
        return []
    first = next(iter(rn.values()))
    ns = list(first["every_query"])
    cell = lambda v: f"{v:>7.3f}" if v is not None else f"{'-':>7}"  # noqa: E731
    head = "".join(f"{'R@' + n:>7}" for n in ns)
    every, with_match = _recall_words(kind, first)
    out = [f"Recall@N over {every} | over {with_match} (R@1 above)", f"{'method':<22}{head}   |{head}"]
    for name, r in rn.items():
        out.append(f"{name:<22}" + "".join(cell(r["every_query"][n]) for n in ns) + "   |"
                   + "".join(cell(r["with_true_match"][n]) for n in ns))
    return out


def recall_notes(methods: dict, kind: str = "match") -> list[str]:
    """The report's lines of Recall@N: per method, over every query (the field's; loops: every frame) and over those
    with a true match."""
    out = []
    for name, m in methods.items():
        r = m.get("recall_at_n")
        if r:
            fmt = lambda d: ", ".join(f"R@{n} " + ("-" if v is None else f"{v:.3f}") for n, v in d.items())  # noqa: E731
            every, with_match = _recall_words(kind, r)
            out.append(f"{name}: Recall@N over {every}: {fmt(r['every_query'])}; over {with_match}: "
                       f"{fmt(r['with_true_match'])}")
    return out
