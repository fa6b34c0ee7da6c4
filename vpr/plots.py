"""Figures for evaluation results: PR curves, similarity matrices, bar charts."""
from __future__ import annotations

import json
import numbers
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from matplotlib import colormaps, rcParams
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from vpr.checks import check_int, check_similarity
from vpr.io import save_figure

__all__ = ["plot_pr", "plot_similarity", "plot_bars", "block_max", "block_any"]


def _new_figure(figsize):
    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def plot_pr(curves, path, title=None, dpi=150, ap=None) -> Path:
    """One precision-recall curve per method, its average precision in the legend; returns ``path``.

    Parameters
    ----------
    curves : dict[str, tuple]
        Method name -> ``(precision, recall[, thresholds])``, by non-decreasing recall.
    ap : dict[str, float], optional
        Method name -> AP to show; otherwise the AP of the drawn points.
    path : str or Path
        Output file (format from the suffix).
    title, dpi

    Raises ValueError naming the curve if ``curves`` is empty or a curve malformed, or an ``ap`` is not in [0, 1].
    """
    ap = {} if ap is None else ap
    if not isinstance(ap, Mapping):
        raise ValueError("ap must be a dict of name -> average precision")
    if set(ap) - set(curves):
        raise ValueError(f"ap has names without a curve: {sorted(map(str, set(ap) - set(curves)))}")
    if not isinstance(curves, Mapping) or len(curves) == 0:
        raise ValueError("curves must be a non-empty dict of name -> (precision, recall)")
    checked = []
    for name, curve in curves.items():
        if not isinstance(curve, (tuple, list)) or len(curve) not in (2, 3):
            raise ValueError(f"curves[{name!r}] must be (precision, recall) or "
                             f"(precision, recall, thresholds)")
        precision = np.asarray(curve[0], dtype=np.float64)
        recall = np.asarray(curve[1], dtype=np.float64)
        if precision.ndim != 1 or precision.shape != recall.shape or precision.size == 0:
            raise ValueError(f"curves[{name!r}]: precision and recall must be non-empty 1-D arrays of "
                             f"equal length, got shapes {precision.shape} and {recall.shape}")
        for label, a in (("precision", precision), ("recall", recall)):
            if not np.all((a >= 0) & (a <= 1)):  # also catches NaN
                raise ValueError(f"curves[{name!r}]: {label} must lie in [0, 1] (no NaN)")
        if np.any(np.diff(recall) < 0):
            raise ValueError(f"curves[{name!r}]: recall must be non-decreasing (order points by decreasing "
                             f"threshold)")
        if name in ap:
            value = ap[name]
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real) or not 0 <= value <= 1:
                raise ValueError(f"ap[{name!r}] must be a number in [0, 1], got {value!r}")
            score = float(value)
        else:
            score = float(np.sum(np.diff(recall) * precision[1:]))
        checked.append((str(name), precision, recall, score))

    # a method and its twins ("m+verify") share a colour; a twin is dashed and drawn over it, so that equal curves
    # stay visible as one dashed-over-solid line
    bases = list(dict.fromkeys(name.split("+")[0] for name, *_ in checked))
    colour = {b: f"C{i % 10}" for i, b in enumerate(bases)}
    fig = _new_figure((8.5, 5))
    ax = fig.subplots()
    for name, precision, recall, score in sorted(checked, key=lambda c: "+" in c[0]):
        twin = "+" in name
        ax.plot(recall, precision, label=f"{name} (AP = {score:.3f})", color=colour[name.split("+")[0]],
                linestyle="--" if twin else "-", linewidth=1.2 if twin else 2.0, zorder=3 if twin else 2)
    ax.set_xlabel("recall")
    ax.set_ylabel("precision")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.grid(True, alpha=0.3)
    # beside the axes, not over the low curves
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize="small", borderaxespad=0.0)
    if title:
        ax.set_title(title)
    return save_figure(fig, path, dpi=dpi, bbox_inches="tight")


def block_max(S, fr, fc):
    """Max-pool ``S`` in ``fr x fc`` blocks; never-matched entries become NaN.

    Max pooling keeps a strong match visible however far the matrix is shrunk, which mean pooling would wash out.
    """
    n_db, n_q = S.shape
    out_shape = (-(-n_db // fr), -(-n_q // fc))
    if sp.issparse(S):
        coo = sp.coo_matrix(S)
        grid = np.full(out_shape, np.nan)
        vals = coo.data.astype(np.float64)
        vals[vals == -np.inf] = np.nan
        np.fmax.at(grid, (coo.row // fr, coo.col // fc), vals)
        return grid
    a = np.where(S == -np.inf, np.nan, S.astype(np.float64, copy=False))
    if fr == 1 and fc == 1:
        return a
    padded = np.full((out_shape[0] * fr, out_shape[1] * fc), np.nan)
    padded[:n_db, :n_q] = a
    return np.fmax.reduce(padded.reshape(out_shape[0], fr, out_shape[1], fc), axis=(1, 3))


def block_any(G, fr, fc):
    n_db, n_q = G.shape
    out_shape = (-(-n_db // fr), -(-n_q // fc))
    if sp.issparse(G):
        coo = sp.coo_matrix(G)
        grid = np.zeros(out_shape, dtype=bool)
        nz = coo.data.astype(bool)
        grid[coo.row[nz] // fr, coo.col[nz] // fc] = True
        return grid
    padded = np.zeros((out_shape[0] * fr, out_shape[1] * fc), dtype=bool)
    padded[:n_db, :n_q] = G
    return padded.reshape(out_shape[0], fr, out_shape[1], fc).any(axis=(1, 3))


def _has_candidate(S, best_db):
    """Which queries' ``best_db`` entry is a real candidate worth a marker (bool, shape (n_q,)).

    Not a candidate: a negative ``best_db``, a never-matched entry (``-inf`` or not stored), or a column of ties,
    where the entry is no more similar than the least similar one of its column (unstored entries count as least
    similar). An all-zero column is such a tie: its argmax, row 0, would read as a match to database frame 0. With one
    database entry there is nothing to tie with.
    """
    n_db, n_q = S.shape
    has = best_db >= 0
    q = np.flatnonzero(has)
    rows = best_db[q]
    if sp.issparse(S):  # canonical CSC with sorted indices (check_similarity)
        # global position of (row, col) in the column-major order of the stored entries
        keys = S.indices.astype(np.int64) + np.repeat(np.arange(n_q, dtype=np.int64), np.diff(S.indptr)) * n_db
        want = rows.astype(np.int64) + q.astype(np.int64) * n_db
        pos = np.searchsorted(keys, want)
        stored = pos < len(keys)
        stored[stored] = keys[pos[stored]] == want[stored]
        val = np.full(len(q), -np.inf)
        val[stored] = S.data[pos[stored]]
        col_min = np.full(n_q, -np.inf)
        full = np.flatnonzero(np.diff(S.indptr) == n_db)  # only full columns lack an unstored entry
        if len(full):
            col_min[full] = np.minimum.reduceat(S.data, S.indptr[full])
    else:
        val = S[rows, q]
        col_min = S.min(axis=0)
    ok = val > -np.inf
    if n_db > 1:
        ok &= val > col_min[q]
    has[q] = ok
    return has


#: how :func:`plot_similarity` draws by default (its ``**style``)
SIMILARITY_STYLE = {"title": None, "max_pixels": 1000, "dpi": 150, "value_label": "similarity",
                    "axis_labels": ("database", "query")}


def plot_similarity(S, path, best_db=None, accepted=None, gt_hard=None, gt_soft=None, mask=None, **style) -> Path:
    """Heatmap of a similarity matrix with best matches and ground truth; returns ``path``.

    Database entries down the y axis, queries along x, max-pooled to at most ``max_pixels`` per axis (markers exact);
    unstored and ``-inf`` entries are blank. NaN / +inf, shape mismatches, non-bool masks, ``best_db`` out of range or
    ``accepted`` without ``best_db`` raise ValueError.

    Parameters
    ----------
    S : array_like or scipy.sparse matrix, shape (n_db, n_q)
    path : str or Path
        Output file (format from the suffix).
    best_db : array_like of int, shape (n_q,), optional
        Each query's best database index; no marker where there is no candidate (negative, never matched, or a column
        of ties).
    accepted : array_like of bool, shape (n_q,), optional
        Accepted (circle) or rejected (cross); with ``gt_hard`` green when right, red when wrong, orange on
        ``gt_soft`` only.
    gt_hard, gt_soft : bool array or sparse bool matrix, shape (n_db, n_q), optional
        Drawn as a faint red overlay (hard).
    mask : bool array or sparse bool matrix, shape (n_db, n_q), optional
        The pairs evaluated; the ground truth is drawn only there.
    style : ``title``, ``max_pixels``, ``dpi``, ``value_label``, ``axis_labels`` over :data:`SIMILARITY_STYLE`
        (another key: ValueError).
    """
    unknown = sorted(set(style) - set(SIMILARITY_STYLE))
    if unknown:
        raise ValueError(f"plot_similarity: unknown style {', '.join(unknown)}; known: {', '.join(SIMILARITY_STYLE)}")
    style = {**SIMILARITY_STYLE, **style}
    title, max_pixels, dpi, value_label, axis_labels = (style[k] for k in SIMILARITY_STYLE)
    S = check_similarity(S, sparse_format="csc")
    n_db, n_q = S.shape
    max_pixels = check_int(max_pixels, "max_pixels", minimum=1)

    if best_db is not None:
        best_db = np.asarray(best_db)
        if best_db.shape != (n_q,):
            raise ValueError(f"best_db must have shape ({n_q},), got {best_db.shape}")
        if best_db.dtype.kind not in "iu":
            raise ValueError(f"best_db must hold integers, got dtype {best_db.dtype}")
        if np.any(best_db >= n_db):
            raise ValueError(f"best_db has indices >= n_db = {n_db}")
    if accepted is not None:
        if best_db is None:
            raise ValueError("accepted requires best_db")
        accepted = np.asarray(accepted)
        if accepted.shape != (n_q,) or accepted.dtype != bool:
            raise ValueError(f"accepted must be a bool array of shape ({n_q},), "
                             f"got {accepted.dtype} {accepted.shape}")
    if gt_hard is not None:
        if sp.issparse(gt_hard):
            gt_dtype, gt_shape = gt_hard.dtype, gt_hard.shape
        else:
            gt_hard = np.asarray(gt_hard)
            gt_dtype, gt_shape = gt_hard.dtype, gt_hard.shape
        if gt_dtype != np.bool_:
            raise ValueError(f"gt_hard must be boolean, got dtype {gt_dtype}")
        if gt_shape != (n_db, n_q):
            raise ValueError(f"gt_hard has shape {gt_shape}, but S has shape {(n_db, n_q)}")

    fr = -(-n_db // max_pixels)
    fc = -(-n_q // max_pixels)
    shown = block_max(S, fr, fc)
    # pixel edges in original index units, so markers need no rescaling
    extent = (-0.5, n_q - 0.5, n_db - 0.5, -0.5)

    aspect = n_db / n_q
    fig = _new_figure((7.5, float(np.clip(6.5 * aspect, 3.5, 9.0))))
    ax = fig.subplots()
    cmap = colormaps["viridis"].with_extremes(bad="0.92")
    finite = shown[np.isfinite(shown)]
    vmin, vmax = (finite.min(), finite.max()) if finite.size else (0.0, 1.0)
    im = ax.imshow(np.ma.masked_invalid(shown), cmap=cmap, aspect="auto", interpolation="nearest",
                   extent=extent, vmin=vmin, vmax=vmax if vmax > vmin else vmin + 1)
    fig.colorbar(im, ax=ax, label=value_label, shrink=0.9)

    handles = []
    if not np.isfinite(shown).all():  # never scored: excluded pairs, SeqSLAM's edge queries, unstored entries
        handles.append(Patch(facecolor="0.92", edgecolor="0.7", label="no score"))
    if gt_hard is not None:
        if mask is not None:
            gt_hard = gt_hard.multiply(mask).tocsr() if sp.issparse(gt_hard) else gt_hard & np.asarray(mask, bool)
        gt_shown = block_any(gt_hard, fr, fc)
        ax.imshow(np.ma.masked_where(~gt_shown, np.ones(gt_shown.shape)), cmap=ListedColormap(["red"]),
                  vmin=0, vmax=1, alpha=0.35, aspect="auto", interpolation="nearest", extent=extent)
        handles.append(Patch(facecolor="red", alpha=0.35, label="ground truth"))

    if best_db is not None:
        q = np.flatnonzero(_has_candidate(S, best_db))
        # thousands of markers would hide the matrix; thin them like the pixels
        q = q[::max(1, -(-len(q) // (2 * max_pixels)))] if len(q) > 2 * max_pixels else q
        size = float(np.clip(2000.0 / max(len(q), 1), 2.0, 30.0))
        if accepted is None:
            ax.scatter(q, best_db[q], s=size, marker="+", c="white", linewidths=0.8)
            handles.append(Line2D([], [], marker="+", color="white", markeredgecolor="black",
                                  linestyle="", label="best match"))
        else:
            acc = accepted[q]
            groups = [("accepted", acc, "orange")]
            if gt_hard is not None:  # right and wrong accepted matches look different
                right = _pairs_in(gt_hard, best_db[q], q)
                soft = _pairs_in(gt_soft, best_db[q], q) & ~right if gt_soft is not None else np.zeros_like(right)
                groups = [("accepted, right", acc & right, "lime"), ("accepted, wrong", acc & ~right & ~soft, "red"),
                          ("accepted, ignored (soft)", acc & soft, "orange")]
            for label, sel, col in groups:
                if sel.any():
                    ax.scatter(q[sel], best_db[q[sel]], s=size, marker="o", facecolors="none", edgecolors=col,
                               linewidths=0.9)
                    handles.append(Line2D([], [], marker="o", markerfacecolor="none", markeredgecolor=col,
                                          linestyle="", label=label))
            if (~acc).any():
                ax.scatter(q[~acc], best_db[q[~acc]], s=size, marker="x", c="magenta", linewidths=0.8)
                handles.append(Line2D([], [], marker="x", color="magenta", linestyle="", label="rejected"))
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_xlabel(axis_labels[1])
    ax.set_ylabel(axis_labels[0])
    if handles:  # below the matrix, not over its corner
        ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncols=min(len(handles), 3),
                  fontsize="small", framealpha=0.8)
    if title:
        ax.set_title(title)
    if fr > 1 or fc > 1:
        ax.text(1.0, 1.01, f"display max-pooled {fr}x{fc}", transform=ax.transAxes, ha="right",
                fontsize="x-small", va="bottom")
    # laid out once: the crop saved and where the matrix lies in it (so that a page showing the picture can tell
    # which pair a click is on) come from the same layout
    tight, box = _layout(fig, ax)
    meta = {"vpr-matrix": json.dumps({"box": box, "shape": [int(n_db), int(n_q)]})} \
        if Path(path).suffix.lower() == ".png" else None
    return save_figure(fig, path, dpi=dpi, bbox_inches=tight, metadata=meta)


def _layout(fig, ax) -> tuple:
    """Lay ``fig`` out once and fix it there: (the picture's crop, as ``bbox_inches="tight"`` would take it; the box
    of ``ax`` in that crop, as fractions of its width and height from the top left: x0, y0, x1, y1)."""
    fig.canvas.draw()  # lays the figure out (constrained)
    tight = fig.get_tightbbox(fig.canvas.get_renderer()).padded(rcParams["savefig.pad_inches"])  # inches
    fig.set_layout_engine("none")  # saving keeps this layout instead of laying the figure out again
    w, h = fig.get_size_inches()
    pos = ax.get_position()  # figure fractions
    x0, x1 = ((pos.x0 * w - tight.x0) / tight.width, (pos.x1 * w - tight.x0) / tight.width)
    y0, y1 = ((tight.y1 - pos.y1 * h) / tight.height, (tight.y1 - pos.y0 * h) / tight.height)
    return tight, [round(v, 5) for v in (x0, y0, x1, y1)]


def _pairs_in(G, rows, cols) -> np.ndarray:
    """``G[rows[i], cols[i]]`` as bools (dense or sparse ``G``; rows < 0 are False)."""
    rows, cols = np.asarray(rows), np.asarray(cols)
    ok = rows >= 0
    out = np.zeros(rows.shape, bool)
    if sp.issparse(G):
        out[ok] = np.asarray(sp.csr_matrix(G)[rows[ok], cols[ok]]).ravel().astype(bool)
    else:
        out[ok] = np.asarray(G)[rows[ok], cols[ok]].astype(bool)
    return out


def plot_bars(table, path, ylabel, title=None, dpi=150) -> Path:
    """Grouped bar chart (e.g. a group per dataset, a bar per encoder); returns ``path``.

    ``table``: group -> (name -> value); a missing name draws no bar; colours follow the order names first appear.
    Raises ValueError if ``table`` or all its groups are empty, or a value is not finite (naming group and name).
    """
    if not isinstance(table, Mapping) or len(table) == 0:
        raise ValueError("table must be a non-empty dict of group -> dict of name -> value")
    names = []
    for group, row in table.items():
        if not isinstance(row, Mapping):
            raise ValueError(f"table[{group!r}] must be a dict of name -> value")
        for name, value in row.items():
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real) \
                    or not np.isfinite(value):
                raise ValueError(f"table[{group!r}][{name!r}] must be a finite number, got {value!r}")
            if name not in names:
                names.append(name)
    if not names:
        raise ValueError("table has no values")

    groups = list(table)
    width = 0.8 / len(names)
    x = np.arange(len(groups))
    fig = _new_figure((max(5.0, 1.2 + 0.35 * len(groups) * len(names)), 4.5))
    ax = fig.subplots()
    label_bars = len(groups) * len(names) <= 40
    for k, name in enumerate(names):
        idx = [g for g, group in enumerate(groups) if name in table[group]]
        vals = [float(table[groups[g]][name]) for g in idx]
        bars = ax.bar(x[idx] + (k - (len(names) - 1) / 2) * width, vals, width, label=str(name))
        if label_bars:
            ax.bar_label(bars, fmt="%.2f", fontsize="x-small", padding=1)
    ax.set_xticks(x, [str(g) for g in groups])
    ax.set_ylabel(ylabel)
    ax.axhline(0, color="black", linewidth=0.6)
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize="small", ncols=min(len(names), 4))
    if title:
        ax.set_title(title)
    return save_figure(fig, path, dpi=dpi)
