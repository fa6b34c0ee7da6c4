"""vpr: sequence-based visual place recognition.

The core of the library is :class:`vpr.SequenceMemory`, the rSHOSM sequence
memory of Neubert, Ahmad and Protzel (KI 2018). Submodules:

- :mod:`vpr.sdr`: SDR batches (bool CSR matrices) and their helpers
- :mod:`vpr.memory`: the rSHOSM / SHOSM memory
- :mod:`vpr.localize`: online localisation against a learned database (:class:`vpr.Localizer`)
- :mod:`vpr.similarity`: overlap / cosine similarity matrices (db x query)
- :mod:`vpr.baselines`: pairwise comparison and SeqSLAM
- :mod:`vpr.evaluate`: precision-recall, AUC, recall@K, ground-truth builders
- :mod:`vpr.simulate`: the paper's simulated grid world
"""
from importlib import import_module

__version__ = "0.1.0"

_LAZY = {"SequenceMemory": "vpr.memory", "Localizer": "vpr.localize"}


def __getattr__(name):
    # lazy so that `import vpr` stays cheap for the CLI's --help
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'vpr' has no attribute {name!r}")


__all__ = ["Localizer", "SequenceMemory", "__version__"]
