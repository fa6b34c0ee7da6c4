"""vpr: sequence-based visual place recognition.

The core of the library is :class:`vpr.SequenceMemory`, the rSHOSM sequence
memory of Neubert, Ahmad and Protzel (KI 2018), in :mod:`vpr.shosm` with
rSHOSM-seq, our graded evidence over it. The house, from the bottom floor up:

- shared types and helpers: :mod:`vpr.types` (encoded traverse, column, decision, match result),
  :mod:`vpr.sdr`, :mod:`vpr.similarity`, :mod:`vpr.config`, :mod:`vpr.checks`,
  :mod:`vpr.io`, :mod:`vpr.imageproc`;
- algorithms, one package each: :mod:`vpr.shosm`, :mod:`vpr.seqslam`,
  :mod:`vpr.frame_pairs`; geometry: :mod:`vpr.verify`;
- data in: :mod:`vpr.sources`, :mod:`vpr.render`, :mod:`vpr.simulate`;
- evaluation: :mod:`vpr.evaluate` (metrics), :mod:`vpr.groundtruth`;
- output: :mod:`vpr.plots`;
- on top: :mod:`vpr.methods` (every method behind one interface, by name) and
  :mod:`vpr.presets` (named settings).
"""
from importlib import import_module

__version__ = "0.1.0"

_LAZY = {"SequenceMemory": "vpr.shosm", "Localizer": "vpr.shosm", "LoopDetector": "vpr.shosm", "Map": "vpr.shosm"}


def __getattr__(name):
    # lazy so that `import vpr` stays cheap for the CLI's --help
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'vpr' has no attribute {name!r}")


__all__ = ["Localizer", "LoopDetector", "Map", "SequenceMemory", "__version__"]
