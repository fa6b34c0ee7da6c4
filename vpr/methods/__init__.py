"""Place-recognition methods behind one interface, found by name like the encoders."""
from __future__ import annotations

import warnings
from importlib import import_module

from vpr.types import EncodedTraverse, ImageInput, MatchResult

from .base import Fitted, Method
from .speed import (
    PICKS,
    SpeedFollower,
    between_maps,
    disagree,
    fill_between,
    loops_at_speed,
    loops_in_run_at_speed,
    match_at_speed,
    path_lengths,
    pick_maps,
)

__all__ = ["online", "get", "build", "available", "get_class", "match", "loops", "image_inputs", "Method", "Fitted",
           "match_at_speed", "loops_at_speed", "loops_in_run_at_speed", "pick_maps", "disagree", "between_maps",
           "fill_between", "path_lengths", "SpeedFollower", "PICKS"]

# name -> (module, class); imported on first use, so that e.g. the SeqSLAM kernels load only for seqslam
_REGISTRY = {
    "rshosm": ("vpr.methods.rshosm", "Rshosm"),
    "rshosm-seq": ("vpr.methods.rshosm_seq", "RshosmSeq"),
    "seqslam": ("vpr.methods.seqslam", "SeqSlam"),
    "seqslam-desc": ("vpr.methods.seqslam", "SeqSlamDesc"),
    "pairwise": ("vpr.methods.pairwise", "Pairwise"),
}


def available() -> list[str]:
    """Names accepted by :func:`get`, in registration order."""
    return list(_REGISTRY)


def get_class(name: str) -> type[Method]:
    """The method class registered as ``name``.

    Raises
    ------
    ValueError
        Unknown name (the message lists the available ones).
    """
    if name not in _REGISTRY:
        raise ValueError(f"unknown method {name!r}; available: {', '.join(available())}")
    module, cls = _REGISTRY[name]
    return getattr(import_module(module), cls)


def online() -> str:
    """The method that runs online (:attr:`Method.runs_online`): the online commands' (``vpr loops -``,
    ``vpr learn`` / ``vpr localize``)."""
    return next(m for m in available() if get_class(m).runs_online)


def image_inputs() -> dict[str, ImageInput]:
    """Every input that a registered method computes from the images itself, by name (imports every method)."""
    out: dict[str, ImageInput] = {}
    for name in available():
        out.update(get_class(name).image_inputs)
    return out


def get(name: str, **conf) -> Method:
    """A new method ``name`` with ``conf`` merged over its ``default_conf``."""
    return get_class(name)(**conf)


def build(names, confs: dict | None = None) -> dict[str, Method]:
    """The methods ``names`` with their ``confs`` (method -> conf), built and checked before any work.

    A conf for a method not in ``names`` is still checked (a typo should not pass silently), then ignored with a
    warning; a name given twice runs once.
    """
    names = list(names)
    if not names:
        raise ValueError("--methods is empty")
    unique = list(dict.fromkeys(names))
    if len(unique) < len(names):
        twice = sorted({m for m in names if names.count(m) > 1})
        warnings.warn(f"--methods names {', '.join(twice)} more than once; each method runs once", stacklevel=2)
    for m in unique:
        get_class(m)  # unknown names fail here, with the list of methods
    built = {}
    for m, c in (confs or {}).items():
        try:
            built[m] = get(m, **c)
        except ValueError as exc:
            raise ValueError(f"--method-conf {m}: {exc}") from None
    unused = [m for m in built if m not in unique]
    if unused:
        warnings.warn(f"--method-conf for {', '.join(unused)}, which this run does not use ({', '.join(unique)}); "
                      "ignored", stacklevel=2)
    return {m: built.get(m) or get(m) for m in unique}


def match(method: str, db: EncodedTraverse, query: EncodedTraverse, conf: dict | None = None,
          progress: bool = False) -> MatchResult:
    """Match every query frame against the database traverse with ``method`` (see :meth:`Method.match`)."""
    return get(method, **(conf or {})).match(db, query, progress=progress)


def loops(method: str, seq: EncodedTraverse, exclude: int = 1, conf: dict | None = None,
          progress: bool = False) -> MatchResult:
    """Loop closures within one traverse with ``method`` (see :meth:`Method.loops`)."""
    return get(method, **(conf or {})).loops(seq, exclude=exclude, progress=progress)
