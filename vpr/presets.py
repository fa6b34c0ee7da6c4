"""Named settings of a run: encoder with its conf, methods with their confs."""
from __future__ import annotations

import copy

__all__ = ["PRESETS", "DEFAULT", "CONF_EXAMPLES", "PAPER_FIG3", "NORDLAND_METHODS", "DEMO", "ENCODER_TEST_METHODS",
           "available", "get", "resolve", "describe"]

#: ``--method-conf`` settings the command line's help shows as examples
CONF_EXAMPLES = ("seqslam.ds=20", "rshosm.p_extra=0.01")

#: The curves of the paper's Fig. 3 (``vpr paper-fig3``), per panel: name -> (method, its ``p_extra``, aliasing ``a``,
#: noise ``n``). Left: SHOSM against rSHOSM; right: pairwise comparison of the input SDRs against rSHOSM.
PAPER_FIG3 = {
    "left": {"SHOSM": ("rshosm", 0.0, 0, 0.0), "rSHOSM p=0.01": ("rshosm", 0.01, 0, 0.0),
             "rSHOSM p=0.05": ("rshosm", 0.05, 0, 0.0)},
    "right": {f"{m} a={a} n={n}": (method, p, a, n) for a, n in ((0, 0.5), (5, 0.0), (5, 0.5))
              for m, method, p in (("pairwise", "pairwise", 0.0), ("rSHOSM p=0.05", "rshosm", 0.05))},
}

#: The entries of ``vpr nordland``'s table: label -> (method, conf). Defaults everywhere except where stated.
NORDLAND_METHODS = {
    "pairwise (pixel, SAD)": ("pairwise", {"on": "descriptor", "metric": "sad"}),
    "pairwise (SDR overlap)": ("pairwise", {"on": "sdr", "metric": "overlap"}),
    "SeqSLAM (pixel)": ("seqslam", {}),
    "rSHOSM (paper)": ("rshosm", {}),
    "rSHOSM-seq": ("rshosm-seq", {}),
}

#: Every setting of ``vpr demo``. Verification is the expensive part (ORB matching per candidate pair): only the
#: headline method's 3 best candidates per query are verified, with 500 keypoints, so that the demo stays near a
#: minute on 2 cores (research/docs/benchmarks.md has the cost).
DEMO = {"scene": "two_seasons", "preset": "default", "radius": 3.0, "soft_radius": 10.0,
        "verify": 3, "verify_methods": ("rshosm-seq",), "verify_conf": {"n_features": 500}}

#: The methods ``vpr encoders test`` scores an encoder with: single frames and a sequence method.
ENCODER_TEST_METHODS = ("pairwise", "rshosm-seq")

#: the preset of a run without ``--preset``
DEFAULT = "default"

#: name -> encoder, encoder_conf, methods (first = the headline), method_conf (method -> conf),
#: loop_method, loop_encoder_conf (over encoder_conf in ``vpr loops``), and a one-line ``use`` shown by
#: ``--help`` and the README
PRESETS: dict[str, dict] = {
    "default": {
        "encoder": "pixel+cnn",
        "encoder_conf": {"standardise": "fit", "pixel.n_bits": 1536, "pixel.k": 150,
                         "cnn.n_bits": 512, "cnn.k": 50},
        "methods": ["rshosm-seq", "seqslam", "seqslam-desc", "pairwise"],
        "method_conf": {},
        "loop_method": "rshosm-seq",
        "loop_encoder_conf": {"standardise": "causal"},
        "use": "joined pixel + CNN SDRs: the best across every dataset measured",
    },
    "paper": {
        "encoder": "pixel",
        "encoder_conf": {"n_bits": 2048, "k": 40, "standardise": "none"},
        "methods": ["rshosm", "pairwise", "seqslam"],
        "method_conf": {"rshosm": {"p_extra": 0.05}},
        "loop_method": "rshosm",
        "loop_encoder_conf": {},
        "use": "the paper's setting (KI 2018), for reproducing it",
    },
    "descriptors": {
        "encoder": "descriptors",
        "encoder_conf": {"standardise": "fit"},
        "methods": ["rshosm-seq", "delta", "seqslam-desc", "pairwise"],
        "method_conf": {"pairwise": {"on": "descriptor"}},
        "loop_method": "rshosm-seq",
        "loop_encoder_conf": {"standardise": "causal"},
        "use": "descriptors computed elsewhere (.npy, hloc .h5): the default where the inputs are descriptor files",
    },
    "fast": {
        "encoder": "pixel",
        "encoder_conf": {"k": 200, "standardise": "fit"},
        "methods": ["rshosm-seq", "seqslam", "seqslam-desc", "pairwise"],
        "method_conf": {},
        "loop_method": "rshosm-seq",
        "loop_encoder_conf": {"standardise": "causal"},
        "use": "pixel SDRs only, no CNN: long videos on a laptop",
    },
}


def available() -> list[str]:
    """Preset names, ``default`` first."""
    return list(PRESETS)


def get(name: str) -> dict:
    """A copy of preset ``name`` (changing it leaves :data:`PRESETS` alone).

    Raises
    ------
    ValueError
        Unknown name (the message lists the available ones).
    """
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; available: {', '.join(available())}")
    return copy.deepcopy(PRESETS[name])


def describe() -> str:
    """One line per preset for ``--help``: name, encoder, methods and when to use it."""
    return "; ".join(f"{n} ({p['encoder']}: {', '.join(p['methods'])}): {p['use']}" for n, p in PRESETS.items())


def resolve(name: str | None = DEFAULT, encoder: str | None = None, encoder_conf: dict | None = None,
            methods: list[str] | None = None, method_conf: dict | None = None, loops: bool = False) -> dict:
    """The settings of a run: preset ``name`` (None: :data:`DEFAULT`) with the given settings over it.

    ``encoder`` replaces the preset's (its encoder conf then dropped); ``encoder_conf`` is merged key by key over the
    preset's when the encoder is the preset's, else taken whole; ``methods`` replaces the preset's (first = headline);
    ``method_conf`` (method -> conf) is merged key by key and always kept, so that a run can refuse a typo; ``loops``:
    the preset's ``loop_encoder_conf`` goes over its encoder conf.

    Returns plain data (copies): ``preset``, ``encoder``, ``encoder_conf``, ``methods``, ``method_conf``,
    ``loop_method``. An unknown preset, an empty or non-string method list or a conf not a dict raise ValueError.
    """
    name = DEFAULT if name is None else name
    preset = get(name)
    for arg, value in (("encoder_conf", encoder_conf), ("method_conf", method_conf)):
        if value is not None and not isinstance(value, dict):
            raise ValueError(f"{arg} must be a dict, got {type(value).__name__}")
    if encoder is None or encoder == preset["encoder"]:
        loop_conf = preset["loop_encoder_conf"] if loops else {}
        base = {**preset["encoder_conf"], **loop_conf}
        # a key given without a part prefix (k=100 on pixel+cnn) is meant for every part: it replaces the preset's
        # per-part values of that key, which would otherwise win over it inside the joined encoder
        given = {k for k in (encoder_conf or {}) if "." not in k}
        base = {k: v for k, v in base.items() if k.partition(".")[2] not in given or "." not in k}
        enc, enc_conf = preset["encoder"], {**base, **(encoder_conf or {})}
    else:
        enc, enc_conf = encoder, dict(encoder_conf or {})
    if methods is not None:
        methods = list(methods)
        if not methods or not all(isinstance(m, str) and m for m in methods):
            raise ValueError(f"methods must be a non-empty list of method names, got {methods!r}")
    used = methods if methods is not None else preset["methods"]
    confs = {m: dict(c) for m, c in preset["method_conf"].items() if m in used or m == preset["loop_method"]}
    for m, c in (method_conf or {}).items():
        if not isinstance(c, dict):
            raise ValueError(f"method_conf[{m!r}] must be a dict, got {type(c).__name__}")
        confs[m] = {**confs.get(m, {}), **c}
    return {"preset": name, "encoder": enc, "encoder_conf": enc_conf, "methods": list(used),
            "method_conf": confs, "loop_method": preset["loop_method"]}
