"""Place-recognition methods behind one interface, found by name like the encoders."""
from __future__ import annotations

import warnings
from importlib import import_module

from vpr import io
from vpr.maps import Map
from vpr.shosm import LOOP_EXCLUDE
from vpr.statefile import MemoryFileError
from vpr.types import ENCODER_INPUTS, EncodedTraverse, ImageInput, MatchResult, StreamDetector

from .base import Fitted, Method
from .speed import loops_at_speed, loops_in_run_at_speed, match_at_speed

__all__ = ["online", "get_online", "load_map", "saved_loop_meta", "resume_loop_detector", "LOOP_EXCLUDE", "Map",
           "MemoryFileError", "register", "unregister", "get", "build", "reads_images", "available", "get_class",
           "match", "loops", "image_inputs", "Method", "Fitted", "match_at_speed", "loops_at_speed",
           "loops_in_run_at_speed"]

# name -> (module, class); imported on first use, so that e.g. the SeqSLAM kernels load only for seqslam
_REGISTRY = {
    "rshosm": ("vpr.methods.rshosm", "Rshosm"),
    "rshosm-seq": ("vpr.methods.rshosm_seq", "RshosmSeq"),
    "seqslam": ("vpr.methods.seqslam", "SeqSlam"),
    "seqslam-desc": ("vpr.methods.seqslam", "SeqSlamDesc"),
    "pairwise": ("vpr.methods.pairwise", "Pairwise"),
    "delta": ("vpr.methods.delta", "Delta"),
}


def register(name: str, module: str, cls: str) -> None:
    """Register the method class ``cls`` of ``module`` as ``name`` (imported on first use), after the others.

    Raises
    ------
    ValueError
        ``name`` is taken.
    """
    if name in _REGISTRY:
        raise ValueError(f"method {name!r} is registered already ({'.'.join(_REGISTRY[name])})")
    _REGISTRY[name] = (module, cls)


def unregister(name: str) -> None:
    """Remove the method ``name`` from the registry (KeyError: not registered)."""
    del _REGISTRY[name]


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
    """The first registered method that runs online (:attr:`Method.runs_online`): the online commands' default
    (``vpr loops -``, ``vpr learn`` / ``vpr localize``)."""
    return next(m for m in available() if get_class(m).runs_online)


def get_online(name: str, sdr_bits: int | None = None, encoder: str = "the encoder", **conf) -> Method:
    """A new method ``name`` that runs online (ValueError naming those that do, for one that does not); ``sdr_bits``:
    the width of the ``encoder``'s SDRs, which the method's reads follow (:meth:`Method.conf_for_sdrs`)."""
    method = get(name, **get_class(name).conf_for_sdrs(conf, sdr_bits, encoder))
    if not method.runs_online:
        able = [m for m in available() if get_class(m).runs_online]
        raise ValueError(f"{name} does not run online (one frame at a time as it comes); methods that do: "
                         f"{', '.join(able)}")
    return method


def load_map(path) -> Map:
    """A map file written by ``vpr learn`` (:meth:`vpr.maps.Map.save`), its localizer restored by the method that
    learned it (MemoryFileError: missing, corrupt, foreign, of another version, or of a method not registered)."""
    def restore(name, header, parts, names):
        return get_class(name).restore_localizer(header, parts, names)
    return Map.load(path, restore)


def saved_loop_meta(path) -> dict:
    """The meta of a loop detector's saved state (``vpr loops - --state-out``): ``method``, what its caller stored,
    and ``opinion`` (whether it decided with one). MemoryFileError: not such a state."""
    header = io.versioned_npz_header(path)
    name = (header or {}).get("meta", {}).get("method") if isinstance((header or {}).get("meta"), dict) else None
    if name not in _REGISTRY or not get_class(name).runs_online:
        raise MemoryFileError(f"{path}: not a loop detector's state (written by `vpr loops - --state-out`)")
    return get_class(name).saved_loop_meta(path)


def resume_loop_detector(path, encoder=None, opinion=None) -> StreamDetector:
    """The loop detector saved at ``path``, by the method that saved it, continuing where it was saved."""
    return get_class(saved_loop_meta(path)["method"]).resume_loop_detector(path, encoder, opinion)


def image_inputs() -> dict[str, ImageInput]:
    """Every input that a registered method computes from the images itself, by name (imports every method)."""
    out: dict[str, ImageInput] = {}
    for name in available():
        out.update(get_class(name).image_inputs)
    return out


def get(name: str, **conf) -> Method:
    """A new method ``name`` with ``conf`` merged over its ``default_conf``."""
    return get_class(name)(**conf)


def reads_images(method: Method) -> bool:
    """Whether ``method`` (with its conf) reads an input it computes from the images (not the encoder's)."""
    return bool(set(method.required_inputs) - set(ENCODER_INPUTS))


def build(names, confs: dict | None = None, images: bool = True, sdr_bits: int | None = None,
          encoder: str = "the encoder") -> dict[str, Method]:
    """The methods ``names`` with their ``confs`` (method -> conf), built and checked before any work.

    A conf for a method not in ``names`` is still checked (a typo should not pass silently), then ignored with a
    warning; a name given twice runs once. Without ``images`` (the inputs are descriptor files) a method that reads
    the images is refused, naming those that do not. ``sdr_bits``: the width of the ``encoder``'s SDRs, which the
    methods' reads follow (:meth:`Method.conf_for_sdrs`).
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
    for m, c in {**{m: {} for m in unique}, **(confs or {})}.items():
        c = get_class(m).conf_for_sdrs(c, sdr_bits, encoder)
        try:
            built[m] = get(m, **c)
        except ValueError as exc:
            raise ValueError(f"--method-conf {m}: {exc}" if m in (confs or {}) else str(exc)) from None
    unused = [m for m in confs or {} if m not in unique]
    if unused:
        warnings.warn(f"--method-conf for {', '.join(unused)}, which this run does not use ({', '.join(unique)}); "
                      "ignored", stacklevel=2)
    out = {m: built[m] for m in unique}
    blind = [m for m, r in out.items() if not images and reads_images(r)]
    if blind:
        able = [m for m in available() if not reads_images(get(m))]
        raise ValueError(f"{', '.join(blind)} read{'s' if len(blind) == 1 else ''} the images, and the inputs are "
                         f"descriptors (--preset descriptors); methods that read descriptors: {', '.join(able)}")
    return out


def match(method: str, db: EncodedTraverse, query: EncodedTraverse, conf: dict | None = None,
          progress: bool = False) -> MatchResult:
    """Match every query frame against the database traverse with ``method`` (see :meth:`Method.match`)."""
    return get(method, **(conf or {})).match(db, query, progress=progress)


def loops(method: str, seq: EncodedTraverse, exclude: int = 1, conf: dict | None = None,
          progress: bool = False) -> MatchResult:
    """Loop closures within one traverse with ``method`` (see :meth:`Method.loops`)."""
    return get(method, **(conf or {})).loops(seq, exclude=exclude, progress=progress)
