"""One configuration helper for encoders, methods, descriptors and the verifier."""
from __future__ import annotations

import copy
import json
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

__all__ = ["merge_conf", "coerce_value", "parse_key_values", "parse_method_confs"]

_TRUE = {"1", "true", "yes", "on", "y", "t"}
_FALSE = {"0", "false", "no", "off", "n", "f"}
_NONE = ("none", "null", "")


def _parse_scalar(text: str):
    t = text.strip()
    if t.lower() in _NONE:
        return None
    for cast in (int, float):
        try:
            return cast(t)
        except ValueError:
            pass
    return t


def coerce_value(key: str, value: Any, default: Any) -> Any:
    """Coerce ``value`` to the type of ``default``.

    Strings are parsed (``"true"``/``"0"``, ``"224,224"`` or ``"[224, 224]"`` for tuples, JSON for dicts, ``"none"``),
    other values checked loosely and converted; ValueError naming ``key`` otherwise.
    """
    if default is None:
        return _parse_scalar(value) if isinstance(value, str) else value
    try:
        if isinstance(default, bool):
            if isinstance(value, str):
                v = value.strip().lower()
                if v in _TRUE:
                    return True
                if v in _FALSE:
                    return False
                raise ValueError(value)
            if isinstance(value, (bool, np.bool_)) or value in (0, 1):
                return bool(value)
            raise ValueError(value)
        if isinstance(default, int):
            if isinstance(value, str):
                f = float(value.strip())
            elif isinstance(value, (bool, np.bool_)):
                raise ValueError(value)
            else:
                f = float(value)
            if f != int(f):
                raise ValueError(value)
            return int(f)
        if isinstance(default, float):
            if isinstance(value, (bool, np.bool_)):
                raise ValueError(value)
            return float(value.strip() if isinstance(value, str) else value)
        if isinstance(default, (tuple, list)):
            if isinstance(value, str):
                s = value.strip()
                if s.startswith(("[", "(")):
                    s = s[1:-1]
                items = [x for x in (p.strip() for p in s.split(",")) if x != ""]
            else:
                items = list(value)
            if default:
                proto = default[0]
                items = [coerce_value(f"{key}[{i}]", x, proto) for i, x in enumerate(items)]
            else:
                items = [_parse_scalar(x) if isinstance(x, str) else x for x in items]
            return type(default)(items)
        if isinstance(default, dict):
            if isinstance(value, str):
                value = json.loads(value) if value.strip() else {}
            if not isinstance(value, Mapping):
                raise ValueError(value)
            return dict(value)
        if isinstance(default, str):
            if not isinstance(value, str):
                raise ValueError(value)
            return value
    except (ValueError, TypeError, json.JSONDecodeError) as e:
        raise ValueError(f"conf {key!r}: cannot read {value!r} as {type(default).__name__}") from e
    return value


def merge_conf(default_conf: Mapping, conf: Mapping | None, what: str, nullable: Iterable[str] = ()) -> dict:
    """``default_conf`` (deep-copied) updated with ``conf``, each value coerced to its default's type.

    Strings are parsed as the default's type (:func:`coerce_value`); ``nullable`` keys also take None or ``"none"``;
    ``what`` names the configured thing in errors. Unknown keys (the valid ones listed) or unreadable values raise
    ValueError.
    """
    conf = dict(conf or {})
    unknown = sorted(set(conf) - set(default_conf))
    if unknown:
        raise ValueError(f"unknown {what} option(s) {unknown}; valid: {sorted(default_conf)}")
    nullable = set(nullable)
    out = {}
    for key, default in default_conf.items():
        if key not in conf:
            out[key] = copy.deepcopy(default)
            continue
        value = conf[key]
        if key in nullable and (value is None or (isinstance(value, str) and value.strip().lower() in _NONE)):
            out[key] = None
            continue
        try:
            out[key] = coerce_value(key, value, default)
        except ValueError as e:
            raise ValueError(f"{what}: {e}") from None
    return out


def parse_method_confs(items: Iterable[str] | None, known) -> dict:
    """``["seqslam.ds=20", ...]`` (``--method-conf METHOD.key=value``, repeatable) -> {method: {key: string}}.

    ``known``: the method names; another is refused, naming them.
    """
    confs: dict = {}
    for head, value in parse_key_values(items, "--method-conf").items():
        method, dot, key = head.partition(".")
        if not dot or not key:
            raise ValueError(f"--method-conf: expected METHOD.key=value, got {head}={value!r}")
        if method not in known:
            raise ValueError(f"--method-conf: unknown method {method!r}; available: {', '.join(known)}")
        confs.setdefault(method, {})[key] = value
    return confs


def parse_key_values(items: Iterable[str] | None, flag: str) -> dict:
    """``["k=40", "standardise=fit"]`` (a repeatable ``--x-conf key=value``) -> dict of strings.

    An item without ``=`` or with an empty key raises ValueError naming ``flag``.
    """
    out = {}
    for item in items or ():
        key, sep, value = str(item).partition("=")
        if not sep or not key.strip():
            raise ValueError(f"{flag}: expected key=value, got {item!r}")
        out[key.strip()] = value
    return out
