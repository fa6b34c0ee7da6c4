"""Argument checks shared across :mod:`vpr` (one definition each, so that messages and rules agree)."""
from __future__ import annotations

import numbers
import os

import numpy as np
import scipy.sparse as sp

__all__ = ["check_similarity", "check_int", "check_count", "check_float", "check_choice", "at",
           "physical_memory", "check_top_k", "check_exclude", "per_input"]

_SPARSE_FORMATS = ("coo", "csr", "csc")


def check_similarity(S, name: str = "S", allow_sparse: bool = True, sparse_format: str = "coo"):
    """Validate a similarity matrix (database x query) and return it as float64.

    Dense: no copy if already float64. Sparse (refused unless ``allow_sparse``): a copy in ``sparse_format``,
    duplicates summed, explicit zeros kept. Not 2-D, empty, not real, NaN or ``+inf`` raise ValueError starting with
    ``name``.
    """
    if sparse_format not in _SPARSE_FORMATS:
        raise ValueError(f"sparse_format must be one of {_SPARSE_FORMATS}, got {sparse_format!r}")
    sparse = sp.issparse(S)
    if sparse and not allow_sparse:
        raise ValueError(f"{name} must be a dense array here, got a sparse {S.format} matrix")
    if not sparse:
        S = np.asarray(S)
    if S.ndim != 2:
        raise ValueError(f"{name} must be 2-D (n_db x n_q), got shape {S.shape}")
    if S.dtype.kind not in "biuf":
        raise ValueError(f"{name} must be real-valued, got dtype {S.dtype}")
    if S.shape[0] == 0 or S.shape[1] == 0:
        raise ValueError(f"{name} must have at least one database entry and one query, got shape {S.shape}")
    if sparse:
        S = sp.coo_matrix(S, dtype=np.float64, copy=True)
        S.sum_duplicates()
        if sparse_format != "coo":
            S = S.asformat(sparse_format)
            S.sort_indices()
        values = S.data
    else:
        S = S.astype(np.float64, copy=False)
        values = S
    if np.isnan(values).any():
        raise ValueError(f"{name} contains NaN")
    if np.isposinf(values).any():
        raise ValueError(f"{name} contains +inf (use -inf for 'never matched')")
    return S


def check_int(value, name: str, minimum: int | None = None, maximum: int | None = None) -> int:
    """``value`` as a Python int, refusing bools, floats and values outside [minimum, maximum].

    Raises
    ------
    ValueError
        Naming ``name`` and the bound that failed.
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name}: must be an integer, got {value!r}")
    if minimum is not None and value < minimum:
        raise ValueError(f"{name}: must be an integer >= {minimum}, got {value!r}")
    if maximum is not None and value > maximum:
        raise ValueError(f"{name}: must be an integer <= {maximum}, got {value!r}")
    return int(value)


def check_count(value, name: str, minimum: int = 0) -> int:
    """A size or count: :func:`check_int` with a lower bound (default 0)."""
    return check_int(value, name, minimum=minimum)


def check_float(value, name: str, minimum: float | None = None, maximum: float | None = None,
                open_min: bool = False, open_max: bool = False) -> float:
    """``value`` as a finite float within [minimum, maximum] (``open_*``: the bound itself excluded).

    Raises
    ------
    ValueError
        Naming ``name``: not a number (bools are refused), not finite, or out of range.
    """
    if isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name}: expected a number, got {value!r}")
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number, got {value!r}") from None
    if not np.isfinite(f):
        raise ValueError(f"{name}: must be finite, got {value!r}")
    lo = minimum is not None and (f <= minimum if open_min else f < minimum)
    hi = maximum is not None and (f >= maximum if open_max else f > maximum)
    if lo or hi:
        if minimum is not None and maximum is not None:
            span = f"in {'(' if open_min else '['}{minimum}, {maximum}{')' if open_max else ']'}"
        elif minimum is not None:
            span = f"{'>' if open_min else '>='} {minimum}"
        else:
            span = f"{'<' if open_max else '<='} {maximum}"
        raise ValueError(f"{name}: must be {span}, got {value!r}")
    return f


def check_choice(value, name: str, choices) -> str:
    """``value`` if it is one of ``choices``, else a ValueError listing them."""
    if value not in tuple(choices):
        raise ValueError(f"{name} must be one of {', '.join(repr(c) for c in choices)}, got {value!r}")
    return value


def at(G, rows, cols) -> np.ndarray:
    """Values of a dense or sparse boolean matrix at coordinates ``(rows[i], cols[i])`` as a bool array.

    Sparse ``G`` is indexed without densifying; an entry counts as True when it is stored and nonzero.
    """
    rows = np.asarray(rows, dtype=np.intp)
    cols = np.asarray(cols, dtype=np.intp)
    if sp.issparse(G):
        if len(rows) == 0:
            return np.zeros(0, dtype=bool)
        if G.format not in ("csr", "csc"):
            G = G.tocsr()
        return np.asarray(G[rows, cols]).ravel() != 0
    return np.asarray(G)[rows, cols].astype(bool, copy=False)


def physical_memory() -> int | None:
    """This machine's physical memory in bytes (None where the system does not say).

    Sizes whose arrays could never fit are refused against it before any work, rather than failing with a
    ``MemoryError`` after reading every image.
    """
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError):  # pragma: no cover - not POSIX
        return None


def check_top_k(value, name: str = "top_k", nullable: bool = True) -> int | None:
    """Frames kept per query: an integer >= 1, or None (every frame) where ``nullable``. The one rule of every
    method, evidence and detector."""
    if value is None and nullable:
        return None
    return check_int(value, name, 1)


def check_exclude(value, name: str = "exclude") -> int:
    """Loop closure's ``exclude``: frames closer than this are not candidates, an integer >= 1 (one rule)."""
    return check_int(value, name, 1)


def per_input(value, n: int, option: str) -> list:
    """One value of an option per input: ``value`` None or one value for all ``n``, or a sequence of one per input
    (in order, as ``--gt FILE [FILE ...]``); ``option`` names it in the refusal."""
    if value is None or isinstance(value, (str, bytes, os.PathLike)):
        return [value] * n
    values = list(value)
    if len(values) == 1:
        return values * n
    if len(values) != n:
        raise ValueError(f"{option}: {len(values)} values for {n} inputs; give one for all, or one per input in "
                         "order")
    return values
