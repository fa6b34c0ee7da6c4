"""vpr: sequence-based visual place recognition."""
from importlib import import_module

__version__ = "0.1.0"

_LAZY = {"SequenceMemory": "vpr.shosm", "Localizer": "vpr.shosm", "LoopDetector": "vpr.shosm", "Map": "vpr.maps"}


def __getattr__(name):
    # lazy so that `import vpr` stays cheap for the CLI's --help
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'vpr' has no attribute {name!r}")


__all__ = ["Localizer", "LoopDetector", "Map", "SequenceMemory", "__version__"]
