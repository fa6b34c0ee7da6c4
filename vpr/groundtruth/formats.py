"""Ground truth as the common benchmarks ship it: matrices in ``.npy``, images and Matlab files."""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from vpr.io import load_npy

__all__ = ["MATRIX_SUFFIXES", "is_matrix_file", "split_variable", "read_matrix", "db_query_matrix", "loop_matrix"]

#: File suffixes read as ground-truth matrices (everything else is a CSV).
MATRIX_SUFFIXES = (".npy", ".png", ".bmp", ".mat")


def split_variable(spec) -> tuple[Path, str | None]:
    """``"truth.mat:GT"`` -> (Path("truth.mat"), "GT"); other paths -> (path, None).

    Any matrix file is split so that ``gt.npy:GT`` is refused by name (only a ``.mat`` file has variables) rather than
    reported missing.
    """
    text = str(spec)
    head, sep, var = text.rpartition(":")
    if sep and Path(head).suffix.lower() in MATRIX_SUFFIXES and var.isidentifier():
        return Path(head), var
    return Path(text), None


def is_matrix_file(spec) -> bool:
    """Whether ``spec`` (a path, ``.mat`` possibly with ``:VARIABLE``) names a matrix file."""
    path, _ = split_variable(spec)
    return path.suffix.lower() in MATRIX_SUFFIXES


def _as_bool(a, path, binary: bool = True) -> np.ndarray:
    """A matrix file's content as bool; ``binary``: only 0/1 (or bool) values are taken, anything else refused.

    A matrix of 0.3 floats (a similarity, a distance, a probability) is not a ground truth: binarising it silently
    would give metrics of nothing. Images (``binary=False``) are read as nonzero = loop (RTAB-Map writes 0/255).
    """
    a = np.asarray(a)
    if a.dtype == object:
        raise ValueError(f"{path}: not a matrix of 0/1 values (an object array; VPR-Bench's per-query lists are "
                         "read for database x query ground truth only)")
    if a.ndim != 2:
        raise ValueError(f"{path}: expected a 2-D matrix, got shape {a.shape}")
    if a.dtype.kind not in "biuf":
        raise ValueError(f"{path}: expected numbers, got dtype {a.dtype}")
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        raise ValueError(f"{path}: contains NaN or infinite values")
    if binary and a.dtype.kind != "b":
        other = a[(a != 0) & (a != 1)]
        if other.size:
            raise ValueError(f"{path}: a ground-truth matrix holds 0/1 (or true/false) values, this one also "
                             f"{other.size} others (e.g. {other.flat[0]:g}); threshold it yourself if it is a "
                             "distance or a similarity")
    return a != 0


def _read_mat(path: Path, variable: str | None):
    import scipy.io

    try:
        data = scipy.io.loadmat(path)
    except (ValueError, NotImplementedError, TypeError, OSError) as e:
        raise ValueError(f"{path}: not a readable Matlab file ({e})") from None
    mats = {k: v for k, v in data.items() if not k.startswith("__")}
    if variable is not None:
        if variable not in mats:
            raise ValueError(f"{path}: no variable {variable!r}; variables: {', '.join(sorted(mats)) or 'none'}")
        v = mats[variable]
        return v.toarray() if sp.issparse(v) else v
    two_d = {k: v for k, v in mats.items() if (sp.issparse(v) or np.asarray(v).ndim == 2) and np.size(v) > 1}
    if len(two_d) != 1:
        raise ValueError(f"{path}: {len(two_d)} matrices ({', '.join(sorted(two_d)) or 'none'}); name one as "
                         f"{path}:NAME")
    v = next(iter(two_d.values()))
    return v.toarray() if sp.issparse(v) else v


def read_matrix(spec):
    """The raw content of a matrix file: a 2-D array (or, for a VPR-Bench ``.npy``, its object array)."""
    path, variable = split_variable(spec)
    if not path.is_file():
        raise FileNotFoundError(f"no such ground-truth file: {path}")
    suffix = path.suffix.lower()
    if variable is not None and suffix != ".mat":
        raise ValueError(f"{spec}: only a .mat file has named variables")
    if suffix == ".npy":
        # VPR-Bench's ground_truth_new.npy holds Python lists per query: read without running any code
        return load_npy(path, "ground-truth .npy file")
    if suffix in (".png", ".bmp"):
        import cv2

        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise ValueError(f"{path}: not a readable image")
        if img.ndim == 3:
            img = img.max(axis=2)
        return img
    if suffix == ".mat":
        return _read_mat(path, variable)
    raise ValueError(f"{path}: not a ground-truth matrix file (expected {', '.join(MATRIX_SUFFIXES)})")


def _vpr_bench(a, path, n_db: int, n_q: int) -> np.ndarray:
    """VPR-Bench rows ``[query, [db, ...]]`` -> bool (n_db, n_q).

    Entries naming frames beyond the traverses' (VPR-Bench's Gardens Point file lists database frames 200 and 201 of
    200-frame folders) are dropped and said (how many, which); a file most of whose entries lie beyond them is
    refused (the ground truth of other traverses). A negative frame is refused.
    """
    gt = np.zeros((n_db, n_q), bool)
    dropped, entries = [], 0
    for r, row in enumerate(a):
        try:
            q, dbs = int(row[0]), np.atleast_1d(np.asarray(row[1], dtype=np.int64))
        except (TypeError, ValueError, IndexError):
            raise ValueError(f"{path}: row {r} is not [query, [db, ...]] with integer frames") from None
        entries += max(dbs.size, 1)
        if q < 0 or (dbs < 0).any():
            raise ValueError(f"{path}: row {r}: a negative frame number")
        if q >= n_q:
            dropped.append(f"row {r} (query frame {q})")
            continue
        outside = dbs >= n_db
        dropped += [f"row {r} (database frame {int(b)})" for b in dbs[outside]]
        gt[dbs[~outside], q] = True
    if dropped and len(dropped) > entries / 2:
        raise ValueError(f"{path}: {len(dropped)} of its {entries} entries name frames beyond the database's "
                         f"0..{n_db - 1} or the query's 0..{n_q - 1} (ground truth of other traverses?)")
    if dropped:
        warnings.warn(f"{path}: {len(dropped)} entr{'y' if len(dropped) == 1 else 'ies'} name frames beyond the "
                      f"database's 0..{n_db - 1} or the query's 0..{n_q - 1} and are left out: "
                      f"{', '.join(dropped[:6])}{' ...' if len(dropped) > 6 else ''}", UserWarning, stacklevel=4)
    return gt


def db_query_matrix(spec, n_db: int, n_q: int, db_indices=None, q_indices=None, totals=None) -> np.ndarray:
    """Database x query ground truth of the frames read, from a matrix file (``GThard.npy`` or VPR-Bench's).

    The file is indexed by source frame number; ``db_indices`` / ``q_indices`` (the source numbers of the frames read;
    default 0, 1, ...) select its rows and columns. A ``GThard``-style matrix must be n_db x n_query of the source
    (its transpose is refused with a hint); ``totals`` (the number of frames in each source, where it is known
    exactly) refuses one of another size, which belongs to other traverses.
    """
    path, _ = split_variable(spec)
    raw = read_matrix(spec)
    db_i = np.arange(n_db) if db_indices is None else np.asarray(db_indices, np.int64)
    q_i = np.arange(n_q) if q_indices is None else np.asarray(q_indices, np.int64)
    need = (int(db_i.max()) + 1 if db_i.size else 0, int(q_i.max()) + 1 if q_i.size else 0)
    rows = isinstance(raw, np.ndarray) and raw.dtype == object and (raw.ndim == 1 or raw.shape[1:] == (2,))
    if rows:  # VPR-Bench: per-query lists, sized by the frames read
        full = _vpr_bench(raw, path, max(need[0], 1), max(need[1], 1))
        totals = None
    else:
        full = _as_bool(raw, path)
    if full.shape[0] < need[0] or full.shape[1] < need[1]:
        hint = " (transposed? rows are database frames, columns query frames)" if \
            full.shape[1] >= need[0] and full.shape[0] >= need[1] else ""
        raise ValueError(f"{path}: a {full.shape[0]} x {full.shape[1]} matrix does not cover database frames "
                         f"0..{need[0] - 1} x query frames 0..{need[1] - 1}{hint}")
    for axis, (total, role) in enumerate(zip(totals or (None, None), ("database", "query"), strict=True)):
        if total is not None and full.shape[axis] != total:
            raise ValueError(f"{path}: a {full.shape[0]} x {full.shape[1]} matrix, but the {role} has {total} frames: "
                             "rows are the database's frames, columns the query's (ground truth of other traverses?)")
    return full[np.ix_(db_i, q_i)]


def loop_matrix(spec, indices, total: int | None = None) -> np.ndarray:
    """Loop ground truth (T x T bool, rows earlier frame, columns frame) of the frames read, from a matrix file.

    ``indices``: the source frame numbers of the frames read. The file is a square matrix over the source's frames
    (row = frame, column = earlier frame, or the transpose: both triangles are read). ``total``: the number of frames
    in the stream, where it is known exactly; a matrix of another size is refused (it belongs to another stream).
    """
    path, _ = split_variable(spec)
    raw = read_matrix(spec)
    full = _as_bool(raw, path, binary=path.suffix.lower() not in (".png", ".bmp"))
    if full.shape[0] != full.shape[1]:
        raise ValueError(f"{path}: a loop ground truth is a square frame x frame matrix, got {full.shape[0]} x "
                         f"{full.shape[1]}")
    if total is not None and full.shape[0] != total:
        raise ValueError(f"{path}: a {full.shape[0]} x {full.shape[0]} loop matrix for a stream of {total} frames "
                         "(ground truth of another stream?)")
    idx = np.asarray(indices, np.int64)
    if idx.size and idx.max() >= full.shape[0]:
        raise ValueError(f"{path}: a {full.shape[0]} x {full.shape[0]} matrix does not cover frame {int(idx.max())} "
                         "of the stream")
    sub = full[np.ix_(idx, idx)]
    return sub | sub.T
