"""Image encoders: batches of images -> SDR batches (bool CSR, frames x n_bits).

Look an encoder up by name, as in hloc::

    import encoders
    enc = encoders.get("pixel", k=40, standardise="fit")
    sdrs = enc.fit(db_images).encode(db_images)

Registered encoders (see each module for its conf keys):

- ``pixel``: SeqSLAM patch-normalised 64x32 thumbnail -> random projection top-k
- ``projection``: random projection top-k of a named descriptor (pixel, hog, cnn)
- ``orb``: ORB / grid-BRIEF binary descriptors -> LSH votes -> top-k
- ``cnn``: pooled ONNX CNN features (EfficientNet-Lite0 by default) -> projection top-k

Conf values may be strings (from ``--encoder-conf key=value``); they are
coerced to the type of the default (:func:`vpr.config.merge_conf`).
"""
from __future__ import annotations

import argparse
from importlib import import_module

from vpr.config import parse_key_values

from .base import BaseEncoder

__all__ = ["get", "available", "get_class", "parse_conf", "add_arguments", "from_args", "BaseEncoder"]

# name -> (module, class); imported lazily so that e.g. onnxruntime is only
# loaded when the cnn encoder is used
_REGISTRY = {
    "pixel": ("encoders.pixel", "PixelEncoder"),
    "projection": ("encoders.projection", "ProjectionEncoder"),
    "orb": ("encoders.orb", "OrbEncoder"),
    "cnn": ("encoders.cnn", "CnnEncoder"),
    "descriptors": ("encoders.descriptors", "DescriptorsEncoder"),
}


def available() -> list[str]:
    """Registered names, sorted; :func:`get` also takes any ``a+b`` of them (a joined encoder, e.g. ``pixel+cnn``)."""
    return sorted(_REGISTRY)


def get_class(name: str) -> type[BaseEncoder]:
    """The encoder class registered as ``name``.

    Raises
    ------
    ValueError
        Unknown name (the message lists the available ones).
    """
    if "+" in name:  # a joined encoder, e.g. pixel+cnn (encoders/joined.py)
        return import_module("encoders.joined").joined_class(name)
    if name not in _REGISTRY:
        raise ValueError(f"unknown encoder {name!r}; available: {', '.join(available())}")
    module, cls = _REGISTRY[name]
    return getattr(import_module(module), cls)


def get(name: str, **conf) -> BaseEncoder:
    """A new encoder ``name`` with ``conf`` merged over its ``default_conf``."""
    return get_class(name)(**conf)


def parse_conf(pairs) -> dict:
    """``["k=40", "standardise=fit"]`` (the CLI's ``--encoder-conf``) -> dict of strings.

    The strings are coerced to the defaults' types by :func:`get`.

    Raises
    ------
    ValueError
        An item without ``=`` or with an empty key.
    """
    return parse_key_values(pairs, "--encoder-conf")


def add_arguments(parser, default: str | None = "pixel") -> None:
    """Add ``--encoder NAME`` and repeatable ``--encoder-conf key=value`` to an argparse parser.

    ``default=None``: not given stays None (the caller's preset decides, see ``vpr.presets``).
    """
    def name(text: str) -> str:  # registered or joined (a+b); argparse choices cannot list the joined ones
        try:
            get_class(text)
        except ValueError as e:
            raise argparse.ArgumentTypeError(str(e)) from None
        return text

    parser.add_argument("--encoder", default=default, type=name, metavar="NAME",
                        help=f"image encoder: {', '.join(available())} or parts joined by '+', "
                             f"e.g. pixel+cnn (default: {default or 'the preset'})")
    parser.add_argument("--encoder-conf", action="append", default=[], metavar="KEY=VALUE",
                        help="encoder conf override, repeatable; values are read as the default's type")


def from_args(args) -> BaseEncoder:
    """The encoder selected by the arguments of :func:`add_arguments`."""
    return get(args.encoder, **parse_conf(args.encoder_conf))
