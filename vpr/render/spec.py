"""Scene specifications for the procedural renderer: loading, validation, defaults."""
from __future__ import annotations

import copy
import json
import math
import re
import zlib
from importlib import resources
from pathlib import Path

__all__ = ["load_spec", "builtin_spec_path", "builtin_specs", "CONDITION_PRESETS", "SpecContext", "check_spec_size"]

TIMES = ("day", "dusk", "night")
SEASONS = ("spring", "summer", "autumn", "winter")
WEATHERS = ("clear", "overcast", "fog", "rain")
KINDS = ("street", "corridor")

# Condition defaults that depend on the time of day / weather; any of them can be overridden explicitly in a
# traverse's "conditions".
CONDITION_PRESETS = {
    "time": {
        "day": {"gain": 1.0, "gamma": 1.0, "noise": 2.0, "lit_windows": 0.0},
        "dusk": {"gain": 1.3, "gamma": 1.1, "noise": 4.0, "lit_windows": 0.2},
        "night": {"gain": 2.2, "gamma": 1.25, "noise": 7.0, "lit_windows": 0.3},
    },
    "weather": {
        "clear": {"fog": None, "rain": 0.0},
        "overcast": {"fog": 400.0, "rain": 0.0},
        "fog": {"fog": 45.0, "rain": 0.0},
        "rain": {"fog": 160.0, "rain": 0.6},
    },
}

_CONDITION_DEFAULTS = {
    "time": "day", "season": "summer", "weather": "clear",
    "blur": 0.0, "lateral_offset": 0.15, "lane": 0.0, "yaw_jitter": 0.3,
    "exposure_jitter": 0.03, "vignette": 0.25,
}

_KIND_DEFAULTS = {
    "street": {"half_width": 8.0, "height": 1.5, "hfov": 75.0, "max_depth": 150.0},
    "corridor": {"half_width": 1.3, "height": 1.2, "hfov": 80.0, "max_depth": 60.0},
}


class SpecContext:
    """Where a value came from, for error messages: the file (or source) and the key path."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, key: str, msg: str):
        raise ValueError(f"{self.source}: key '{key}': {msg}")


def _num(ctx, key, v, *, integer=False, minimum=None, exclusive=False, maximum=None, allow_none=False):
    if v is None and allow_none:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (integer and not float(v).is_integer()):
        ctx.fail(key, f"expected {'an integer' if integer else 'a number'}, got {type(v).__name__} {v!r}")
    if not math.isfinite(v):
        ctx.fail(key, f"must be finite, got {v!r}")
    if minimum is not None and (v < minimum or (exclusive and v == minimum)):
        ctx.fail(key, f"must be {'>' if exclusive else '>='} {minimum}, got {v!r}")
    if maximum is not None and v > maximum:
        ctx.fail(key, f"must be <= {maximum}, got {v!r}")
    return int(v) if integer else float(v)


def _str(ctx, key, v, choices=None):
    if not isinstance(v, str):
        ctx.fail(key, f"expected a string, got {type(v).__name__} {v!r}")
    if choices is not None and v not in choices:
        ctx.fail(key, f"must be one of {', '.join(choices)}; got {v!r}")
    return v


def _bool(ctx, key, v):
    if not isinstance(v, bool):
        ctx.fail(key, f"expected true/false, got {type(v).__name__} {v!r}")
    return v


def _obj(ctx, key, v, allowed):
    if not isinstance(v, dict):
        ctx.fail(key, f"expected an object, got {type(v).__name__}")
    for k in v:
        if k not in allowed:
            name = f"{key}.{k}" if key else k
            ctx.fail(name, f"unknown key (allowed: {', '.join(sorted(allowed))})")
    return v


def _list(ctx, key, v):
    if not isinstance(v, list):
        ctx.fail(key, f"expected a list, got {type(v).__name__}")
    return v


def _pairs(ctx, key, v, second_min, second_exclusive, what):
    out = []
    for i, p in enumerate(_list(ctx, key, v)):
        if not isinstance(p, (list, tuple)) or len(p) != 2:
            ctx.fail(f"{key}[{i}]", f"expected a [position, {what}] pair, got {p!r}")
        pos = _num(ctx, f"{key}[{i}][0]", p[0])
        val = _num(ctx, f"{key}[{i}][1]", p[1], minimum=second_min, exclusive=second_exclusive)
        out.append([pos, val])
    return sorted(out)


def _resolve_world(ctx, w):
    _obj(ctx, "world", w, {"kind", "seed", "length", "loop", "half_width", "density", "aliasing", "ceiling"})
    kind = _str(ctx, "world.kind", w.get("kind", "street"), KINDS)
    out = {
        "kind": kind,
        "seed": _num(ctx, "world.seed", w.get("seed", 0), integer=True, minimum=0),
        "length": _num(ctx, "world.length", w.get("length", 400.0), minimum=20.0, maximum=20000.0),
        "loop": _bool(ctx, "world.loop", w.get("loop", False)),
        # a street needs room for two lanes, kerbs and pavements
        "half_width": _num(ctx, "world.half_width", w.get("half_width", _KIND_DEFAULTS[kind]["half_width"]),
                           minimum=5.0 if kind == "street" else 0.8, maximum=30.0),
        "density": _num(ctx, "world.density", w.get("density", 1.0), minimum=0.0, maximum=5.0),
        "ceiling": _num(ctx, "world.ceiling", w.get("ceiling", 2.7 if kind == "corridor" else None),
                        minimum=1.5, maximum=10.0, allow_none=True),
    }
    if kind == "street" and out["ceiling"] is not None:
        ctx.fail("world.ceiling", "only corridors have a ceiling")
    al = []
    for i, a in enumerate(_list(ctx, "world.aliasing", w.get("aliasing", []))):
        k = f"world.aliasing[{i}]"
        _obj(ctx, k, a, {"source", "target", "length"})
        for req in ("source", "target", "length"):
            if req not in a:
                ctx.fail(f"{k}.{req}", "missing")
        src = _num(ctx, f"{k}.source", a["source"], minimum=0.0)
        dst = _num(ctx, f"{k}.target", a["target"], minimum=0.0)
        ln = _num(ctx, f"{k}.length", a["length"], minimum=0.0, exclusive=True)
        if max(src, dst) + ln > out["length"]:
            ctx.fail(k, f"stretch ends beyond the route length {out['length']} m")
        if abs(src - dst) < ln:
            ctx.fail(k, "source and target stretches overlap")
        al.append({"source": src, "target": dst, "length": ln})
    out["aliasing"] = al
    return out


def _resolve_camera(ctx, c, kind):
    _obj(ctx, "camera", c, {"size", "hfov", "height", "fps", "max_depth"})
    size = c.get("size", [320, 240])
    if not isinstance(size, (list, tuple)) or len(size) != 2:
        ctx.fail("camera.size", f"expected [width, height], got {size!r}")
    w = _num(ctx, "camera.size[0]", size[0], integer=True)
    h = _num(ctx, "camera.size[1]", size[1], integer=True)
    check_spec_size(ctx, "camera.size", (w, h))
    d = _KIND_DEFAULTS[kind]
    return {
        "size": [w, h],
        "hfov": _num(ctx, "camera.hfov", c.get("hfov", d["hfov"]), minimum=10.0, maximum=150.0),
        "height": _num(ctx, "camera.height", c.get("height", d["height"]), minimum=0.1, exclusive=True),
        "fps": _num(ctx, "camera.fps", c.get("fps", 10.0), minimum=0.0, exclusive=True),
        "max_depth": _num(ctx, "camera.max_depth", c.get("max_depth", d["max_depth"]), minimum=5.0),
    }


def check_spec_size(ctx, key, size):
    w, h = size
    if w < 16 or h < 16:
        ctx.fail(key, f"image size must be at least 16 x 16 pixels, got {w} x {h}")
    if w > 8192 or h > 8192:
        ctx.fail(key, f"image size must be at most 8192 x 8192 pixels, got {w} x {h}")


def _resolve_speed(ctx, key, s):
    _obj(ctx, key, s, {"mean", "variation", "profile", "stops"})
    return {
        "mean": _num(ctx, f"{key}.mean", s.get("mean", 8.0), minimum=0.0, exclusive=True),
        "variation": _num(ctx, f"{key}.variation", s.get("variation", 0.15), minimum=0.0, maximum=0.9),
        "profile": _pairs(ctx, f"{key}.profile", s.get("profile", []), 0.0, True, "speed factor > 0"),
        "stops": _pairs(ctx, f"{key}.stops", s.get("stops", []), 0.0, False, "seconds >= 0"),
    }


def _resolve_conditions(ctx, key, c):
    allowed = set(_CONDITION_DEFAULTS) | {"gain", "gamma", "noise", "lit_windows", "fog", "rain"}
    _obj(ctx, key, c, allowed)
    time = _str(ctx, f"{key}.time", c.get("time", "day"), TIMES)
    weather = _str(ctx, f"{key}.weather", c.get("weather", "clear"), WEATHERS)
    merged = {**_CONDITION_DEFAULTS, **CONDITION_PRESETS["time"][time],
              **CONDITION_PRESETS["weather"][weather], **c}
    return {
        "time": time,
        "season": _str(ctx, f"{key}.season", merged["season"], SEASONS),
        "weather": weather,
        "gain": _num(ctx, f"{key}.gain", merged["gain"], minimum=0.0, exclusive=True, maximum=20.0),
        "gamma": _num(ctx, f"{key}.gamma", merged["gamma"], minimum=0.2, maximum=5.0),
        "noise": _num(ctx, f"{key}.noise", merged["noise"], minimum=0.0, maximum=100.0),
        "blur": _num(ctx, f"{key}.blur", merged["blur"], minimum=0.0, maximum=20.0),
        "fog": _num(ctx, f"{key}.fog", merged["fog"], minimum=1.0, allow_none=True),
        "rain": _num(ctx, f"{key}.rain", merged["rain"], minimum=0.0, maximum=1.0),
        "lit_windows": _num(ctx, f"{key}.lit_windows", merged["lit_windows"], minimum=0.0, maximum=1.0),
        "lateral_offset": _num(ctx, f"{key}.lateral_offset", merged["lateral_offset"], minimum=0.0, maximum=5.0),
        "lane": _num(ctx, f"{key}.lane", merged["lane"], minimum=-10.0, maximum=10.0),
        "yaw_jitter": _num(ctx, f"{key}.yaw_jitter", merged["yaw_jitter"], minimum=0.0, maximum=20.0),
        "exposure_jitter": _num(ctx, f"{key}.exposure_jitter", merged["exposure_jitter"], minimum=0.0, maximum=0.5),
        "vignette": _num(ctx, f"{key}.vignette", merged["vignette"], minimum=0.0, maximum=1.0),
    }


_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


def _resolve_traverse(ctx, i, t, world):
    key = f"traverses[{i}]"
    _obj(ctx, key, t, {"name", "seed", "laps", "start", "end", "speed", "conditions"})
    name = _str(ctx, f"{key}.name", t.get("name", f"traverse{i}"))
    if not _NAME_RE.match(name):
        ctx.fail(f"{key}.name", f"must be a folder-safe name (letters, digits, _ . -), got {name!r}")
    laps = _num(ctx, f"{key}.laps", t.get("laps", 1), integer=True, minimum=1, maximum=1000)
    if laps > 1 and not world["loop"]:
        ctx.fail(f"{key}.laps", "several laps need a closed loop (world.loop = true)")
    L = world["length"]
    start = _num(ctx, f"{key}.start", t.get("start", 0.0), minimum=0.0, maximum=L)
    end = _num(ctx, f"{key}.end", t.get("end", L), minimum=0.0, maximum=L)
    if not world["loop"] and end - start < 1.0:
        ctx.fail(f"{key}.end", f"must be at least 1 m after start ({start}), got {end}")
    return {
        "name": name,
        # a stable default seed: the same spec always renders the same frames
        "seed": _num(ctx, f"{key}.seed", t.get("seed", zlib.crc32(name.encode()) % 100000), integer=True, minimum=0),
        "laps": laps,
        "start": start,
        "end": end,
        "speed": _resolve_speed(ctx, f"{key}.speed", t.get("speed", {})),
        "conditions": _resolve_conditions(ctx, f"{key}.conditions", t.get("conditions", {})),
    }


def resolve(spec: dict, source: str = "<spec>") -> dict:
    """Validate a spec dictionary and return a resolved deep copy (defaults filled)."""
    ctx = SpecContext(source)
    _obj(ctx, "", spec, {"name", "description", "world", "camera", "traverses"})
    world = _resolve_world(ctx, spec.get("world", {}))
    out = {
        "name": _str(ctx, "name", spec.get("name", Path(source).stem if source != "<spec>" else "scene")),
        "description": _str(ctx, "description", spec.get("description", "")),
        "world": world,
        "camera": _resolve_camera(ctx, spec.get("camera", {}), world["kind"]),
    }
    trs = _list(ctx, "traverses", spec.get("traverses", []))
    if not trs:
        ctx.fail("traverses", "at least one traverse is needed")
    out["traverses"] = [_resolve_traverse(ctx, i, t, world) for i, t in enumerate(trs)]
    if world["kind"] == "corridor" and out["camera"]["height"] >= world["ceiling"] - 0.1:
        ctx.fail("camera.height", f"must be below the corridor ceiling ({world['ceiling']} m)")
    centre = 1.75 if world["kind"] == "street" else 0.0  # the lane the camera drives in
    for i, t in enumerate(out["traverses"]):
        c = t["conditions"]
        if abs(centre + c["lane"]) + 2 * c["lateral_offset"] > world["half_width"] - 0.3:
            ctx.fail(f"traverses[{i}].conditions.lane",
                     f"lane {c['lane']} m with lateral_offset {c['lateral_offset']} m drives into the walls "
                     f"(half width {world['half_width']} m)")
    names = [t["name"] for t in out["traverses"]]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        ctx.fail("traverses", f"duplicate traverse names: {', '.join(dup)}")
    return copy.deepcopy(out)


def _search_dirs() -> list[Path]:
    """Where builtin scenes are looked for: the installed package data, then the source checkout."""
    dirs = []
    scenes = resources.files("vpr.render") / "scenes"
    if isinstance(scenes, Path):  # a wheel installs vpr/render/scenes/*.json (setup.py copies data/synthetic)
        dirs.append(scenes)
    # a source checkout or an editable install reads the repository's data/synthetic/ directly
    dirs.append(Path(__file__).resolve().parents[2] / "data" / "synthetic")
    return dirs


def builtin_spec_path(name: str) -> Path:
    """Path of the builtin scene ``name``: the package's ``vpr/render/scenes/``, else a checkout's
    ``data/synthetic/``. An unknown name raises FileNotFoundError listing the scenes and folders.
    """
    for d in _search_dirs():
        p = d / f"{name}.json"
        if p.is_file():
            return p
    raise FileNotFoundError(f"no builtin scene {name!r} (available: {', '.join(builtin_specs()) or 'none'}; "
                            f"searched {', '.join(str(d) for d in _search_dirs())})")


def builtin_specs() -> list[str]:
    """Names of the builtin scenes, sorted."""
    names = set()
    for d in _search_dirs():
        if d.is_dir():
            names.update(p.stem for p in d.glob("*.json"))
    return sorted(names)


def load_spec(spec) -> dict:
    """Load, validate and resolve a scene specification: every key present, defaults filled, presets expanded.

    ``spec``: a JSON file, a builtin scene name (:func:`builtin_specs`) or a dict. Neither file nor builtin raises
    FileNotFoundError; invalid JSON, keys, types or values ValueError naming the file and key.
    """
    if isinstance(spec, dict):
        return resolve(spec, "<spec>")
    if not isinstance(spec, (str, Path)):
        raise ValueError(f"spec: expected a path, a builtin scene name or a dict, got {type(spec).__name__}")
    p = Path(spec)
    if not p.is_file():
        if isinstance(spec, str) and _NAME_RE.match(spec) and not spec.endswith(".json"):
            p = builtin_spec_path(spec)
        else:
            raise FileNotFoundError(f"{spec}: scene specification not found")
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise ValueError(f"{p}: invalid JSON: {e}") from None
    return resolve(data, str(p))
