"""Figures for evaluation results: PR curves, similarity matrices, bar charts.

Every function builds its own :class:`matplotlib.figure.Figure` on an Agg
canvas (never pyplot's global figure manager, so they are safe in threads and
batch jobs) and writes it atomically with :func:`vpr.io.save_figure`; the file
format follows the suffix of ``path``.
"""
from __future__ import annotations

import numbers
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from vpr.evaluate import auc_from_pr
from vpr.io import save_figure

__all__ = ["plot_pr", "plot_similarity", "plot_bars"]


def _new_figure(figsize):
    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


# --------------------------------------------------------------------------- #
# precision-recall curves
# --------------------------------------------------------------------------- #
def plot_pr(curves, path, title=None, dpi=150) -> Path:
    """Plot one precision-recall curve per method, with its AUC in the legend.

    Parameters
    ----------
    curves : dict[str, tuple]
        Method name -> ``(precision, recall)``; a third element (the
        thresholds returned by :func:`vpr.evaluate.pr_curve`) is accepted and
        ignored. Points must be ordered by non-decreasing recall.
    path : str or Path
        Output file (format from the suffix, e.g. ``.png``).
    title : str, optional
    dpi : int

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        If ``curves`` is empty or a curve is malformed (lengths differ, NaN,
        values outside [0, 1], recall decreasing); the message names the curve.
    """
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
        try:
            auc = auc_from_pr(precision, recall)
        except ValueError as e:
            raise ValueError(f"curves[{name!r}]: {e}") from None
        checked.append((str(name), precision, recall, auc))

    fig = _new_figure((6, 5))
    ax = fig.subplots()
    for name, precision, recall, auc in checked:
        ax.plot(recall, precision, label=f"{name} (AUC = {auc:.3f})", linewidth=1.5)
    ax.set_xlabel("recall")
    ax.set_ylabel("precision")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="lower left", fontsize="small")
    if title:
        ax.set_title(title)
    return save_figure(fig, path, dpi=dpi)


# --------------------------------------------------------------------------- #
# similarity matrix
# --------------------------------------------------------------------------- #
def _block_max(S, fr, fc):
    """Max-pool ``S`` in ``fr x fc`` blocks; never-matched entries become NaN.

    Max pooling keeps a strong match visible however far the matrix is shrunk,
    which mean pooling would wash out.
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


def _block_any(G, fr, fc):
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


def _check_similarity(S):
    if sp.issparse(S):
        data = S.data
    else:
        S = np.asarray(S)
        data = S
    if S.ndim != 2 or S.shape[0] == 0 or S.shape[1] == 0:
        raise ValueError(f"S must be a non-empty 2-D (n_db x n_q) matrix, got shape {S.shape}")
    if S.dtype.kind not in "biuf":
        raise ValueError(f"S must be real-valued, got dtype {S.dtype}")
    if np.isnan(data).any():
        raise ValueError("S contains NaN")
    if np.isposinf(data).any():
        raise ValueError("S contains +inf (use -inf for 'never matched')")
    return S


def plot_similarity(S, path, best_db=None, accepted=None, gt_hard=None, title=None,
                    max_pixels=1000, dpi=150) -> Path:
    """Heatmap of a similarity matrix with best matches and ground truth.

    Database entries run down the y axis, queries along the x axis. Larger
    matrices are max-pooled to at most ``max_pixels`` cells per axis for
    display (markers keep their exact positions). Sparse ``S`` is pooled from
    its stored entries without densifying; unstored and ``-inf`` entries are
    drawn blank.

    Parameters
    ----------
    S : array_like or scipy.sparse matrix, shape (n_db, n_q)
    path : str or Path
        Output file (format from the suffix).
    best_db : array_like of int, shape (n_q,), optional
        Each query's best database index; a negative value means "no match"
        and draws nothing.
    accepted : array_like of bool, shape (n_q,), optional
        Whether each best match was accepted (circle) or rejected (cross).
        Requires ``best_db``.
    gt_hard : bool array or sparse bool matrix, shape (n_db, n_q), optional
        Drawn as a faint red overlay.
    title : str, optional
    max_pixels : int
        Display resolution limit per axis.
    dpi : int

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        On NaN / +inf in ``S``, shape mismatches, non-bool ``gt_hard`` or
        ``accepted``, out-of-range ``best_db``, or ``accepted`` without
        ``best_db``.
    """
    S = _check_similarity(S)
    n_db, n_q = S.shape
    if isinstance(max_pixels, (bool, np.bool_)) or not isinstance(max_pixels, numbers.Integral) \
            or max_pixels < 1:
        raise ValueError(f"max_pixels must be a positive integer, got {max_pixels!r}")

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
        if gt_dtype != bool:
            raise ValueError(f"gt_hard must be boolean, got dtype {gt_dtype}")
        if gt_shape != (n_db, n_q):
            raise ValueError(f"gt_hard has shape {gt_shape}, but S has shape {(n_db, n_q)}")

    fr = -(-n_db // max_pixels)
    fc = -(-n_q // max_pixels)
    shown = _block_max(S, fr, fc)
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
    fig.colorbar(im, ax=ax, label="similarity", shrink=0.9)

    handles = []
    if gt_hard is not None:
        gt_shown = _block_any(gt_hard, fr, fc)
        ax.imshow(np.ma.masked_where(~gt_shown, np.ones(gt_shown.shape)), cmap=ListedColormap(["red"]),
                  vmin=0, vmax=1, alpha=0.35, aspect="auto", interpolation="nearest", extent=extent)
        handles.append(Patch(facecolor="red", alpha=0.35, label="ground truth"))

    if best_db is not None:
        q = np.flatnonzero(best_db >= 0)
        # thousands of markers would hide the matrix; thin them like the pixels
        q = q[::max(1, -(-len(q) // (2 * max_pixels)))] if len(q) > 2 * max_pixels else q
        size = float(np.clip(2000.0 / max(len(q), 1), 2.0, 30.0))
        if accepted is None:
            ax.scatter(q, best_db[q], s=size, marker="+", c="white", linewidths=0.8)
            handles.append(Line2D([], [], marker="+", color="white", markeredgecolor="black",
                                  linestyle="", label="best match"))
        else:
            acc = accepted[q]
            ax.scatter(q[acc], best_db[q[acc]], s=size, marker="o", facecolors="none",
                       edgecolors="orange", linewidths=0.8)
            ax.scatter(q[~acc], best_db[q[~acc]], s=size, marker="x", c="magenta", linewidths=0.8)
            handles.append(Line2D([], [], marker="o", markerfacecolor="none", markeredgecolor="orange",
                                  linestyle="", label="accepted"))
            handles.append(Line2D([], [], marker="x", color="magenta", linestyle="", label="rejected"))
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_xlabel("query")
    ax.set_ylabel("database")
    if handles:
        ax.legend(handles=handles, loc="upper right", fontsize="small", framealpha=0.8)
    if title:
        ax.set_title(title)
    if fr > 1 or fc > 1:
        ax.text(0.0, -0.08, f"display max-pooled {fr}x{fc}", transform=ax.transAxes,
                fontsize="x-small", va="top")
    return save_figure(fig, path, dpi=dpi)


# --------------------------------------------------------------------------- #
# grouped bars
# --------------------------------------------------------------------------- #
def plot_bars(table, path, ylabel, title=None, dpi=150) -> Path:
    """Grouped bar chart, e.g. one group per dataset and one bar per encoder.

    Parameters
    ----------
    table : dict[str, dict[str, float]]
        Group -> (name -> value). A name missing from a group draws no bar
        there; bar colours follow the order in which names first appear.
    path : str or Path
        Output file (format from the suffix).
    ylabel : str
    title : str, optional
    dpi : int

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        If ``table`` or all of its groups are empty, or a value is not a finite
        real number (the message names group and name).
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
