"""The one file format of saved states (a memory, a loop detector, a map): a header and named arrays."""
from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np

from vpr import io as _io

__all__ = ["MemoryFileError", "write_file", "read_file", "joint_state", "part_state"]


class MemoryFileError(ValueError):
    """A memory, detector or localizer file that cannot be used: missing, corrupt, foreign or of another version."""


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def joint_state(**objects) -> tuple[dict, dict]:
    """The states of several objects as one (header, arrays), each under its name (:func:`part_state` splits it)."""
    header, arrays = {}, {}
    for name, obj in objects.items():
        h, a = obj.state()
        header[name] = h
        arrays.update({f"{name}_{k}": v for k, v in a.items()})
    return header, arrays


def part_state(header: dict, arrays: dict, name: str) -> tuple[dict, dict]:
    """The (header, arrays) of object ``name`` in a :func:`joint_state`."""
    return header[name], {k[len(name) + 1:]: v for k, v in arrays.items() if k.startswith(name + "_")}


def write_file(path, fmt: str, version: int, header: dict, parts: Mapping[str, Mapping], names=None) -> Path:
    """Write ``header`` and the arrays of ``parts`` (part name -> arrays; ``""``: unprefixed) as one file.

    ``names``: frame names, stored as text.
    """
    arrays = {(f"{part}_{k}" if part else k): np.asarray(v) for part, d in parts.items() for k, v in d.items()}
    if names is not None:
        arrays["names"] = np.array([str(n) for n in names], dtype=str)
    return _io.save_versioned_npz(Path(path), {**header, "format": fmt, "version": version}, arrays,
                                  default=_json_default)


@contextlib.contextmanager
def read_file(path, fmt: str, version: int, what: str, hint: str = "",
               prefixes: tuple[str, ...] | None = None) -> Iterator[tuple[dict, dict, list | None]]:
    """Read a file of :func:`write_file`: yields ``(header, parts, names)``; errors in the block name the file.

    ``parts``: part name -> arrays, for the parts in ``prefixes`` (None: every ``PART_key`` prefix); other arrays
    under ``""``. An exception in the ``with`` block (inconsistent arrays, a bad conf) becomes a
    :class:`MemoryFileError` naming ``path`` and ``what`` it should have been.
    """
    header, data = _io.load_versioned_npz(path, fmt, version, what, MemoryFileError, hint=hint)
    names = [str(n) for n in data.pop("names").tolist()] if "names" in data else None
    parts: dict = {p: {} for p in prefixes or ()}
    for key, value in data.items():
        part, sep, rest = key.partition("_")
        if sep and (prefixes is None or part in prefixes):
            parts.setdefault(part, {})[rest] = value
        else:
            parts.setdefault("", {})[key] = value
    try:
        yield header, parts, names
    except MemoryFileError:
        raise
    except Exception as e:
        raise MemoryFileError(f"{path}: corrupt {what} file ({type(e).__name__}: {e})") from e
