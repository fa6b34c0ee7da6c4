"""Positions of frames from where robots and datasets keep them: trajectories, file names, EXIF."""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

__all__ = ["trajectory_format", "load_tum", "load_kitti", "utm_from_names", "exif_positions", "positions_at",
           "outages", "outage_limit", "short_gaps", "OUTAGE_S", "every", "latlon_to_metres",
           "EARTH_RADIUS", "TIME_RESOLUTION"]

#: Mean Earth radius, m: latitude and longitude to local metres (an equirectangular plane about the first
#: point, within a few centimetres per kilometre at the scale of a route).
EARTH_RADIUS = 6_371_008.8

_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


def latlon_to_metres(lat, lon, origin=None) -> np.ndarray:
    """(n, 2) east and north in metres from ``origin`` (latitude, longitude; default: the first point)."""
    lat, lon = np.asarray(lat, np.float64), np.asarray(lon, np.float64)
    lat0, lon0 = (lat[0], lon[0]) if origin is None else origin
    east = np.radians(lon - lon0) * EARTH_RADIUS * np.cos(np.radians(lat0))
    north = np.radians(lat - lat0) * EARTH_RADIUS
    return np.stack([east, north], axis=1)


def _rows(path) -> list[tuple[int, list[str]]]:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise FileNotFoundError(f"no such ground-truth file: {path}") from None
    except (UnicodeDecodeError, IsADirectoryError) as e:
        raise ValueError(f"{path}: not a text file ({type(e).__name__})") from None
    out = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if s and not s.startswith(("#", "%")):
            out.append((lineno, s.replace(",", " ").split()))
    return out


def trajectory_format(path) -> str | None:
    """``"tum"`` (8 numbers a line) or ``"kitti"`` (12), read from the file's first line; None for anything else."""
    try:
        rows = _rows(path)
    except (OSError, ValueError):
        return None
    if not rows or not all(_NUMBER.fullmatch(t) for t in rows[0][1]):
        return None
    return {8: "tum", 12: "kitti"}.get(len(rows[0][1]))


def _numbers(path, width: int, what: str) -> tuple[np.ndarray, list[int]]:
    rows = _rows(path)
    if not rows:
        raise ValueError(f"{path}: empty {what} file")
    out, lines = [], []
    for lineno, tokens in rows:
        if len(tokens) != width:
            raise ValueError(f"{path}:{lineno}: a {what} line has {width} numbers, this one {len(tokens)}")
        try:
            vals = [float(t) for t in tokens]
        except ValueError:
            raise ValueError(f"{path}:{lineno}: {what} values must be numbers") from None
        if not all(math.isfinite(v) for v in vals):
            raise ValueError(f"{path}:{lineno}: {what} values must be finite")
        out.append(vals)
        lines.append(lineno)
    return np.asarray(out, np.float64), lines


def load_tum(path) -> tuple[np.ndarray, np.ndarray]:
    """(times s, positions (n, 3)) of a TUM trajectory, in time order (``timestamp tx ty tz qx qy qz qw``)."""
    a, lines = _numbers(path, 8, "TUM trajectory")
    order = np.argsort(a[:, 0], kind="stable")
    t = a[order, 0]
    dup = np.flatnonzero(np.diff(t) == 0)
    if dup.size:
        raise ValueError(f"{path}:{lines[order[dup[0] + 1]]}: timestamp {t[dup[0]]} twice")
    return t, a[order, 1:4]


def load_kitti(path) -> np.ndarray:
    """Positions (n, 3) of KITTI poses, one 3 x 4 matrix per line and frame: the translation column."""
    a, _ = _numbers(path, 12, "KITTI pose")
    return a[:, [3, 7, 11]]


def utm_from_names(names) -> np.ndarray:
    """(n, 2) UTM east and north from file names ``...@EAST@NORTH@...`` (Pittsburgh, SF-XL, MSLS style)."""
    out = []
    for name in names:
        parts = Path(str(name)).stem.split("@")
        try:
            out.append((float(parts[1]), float(parts[2])))
        except (IndexError, ValueError):
            raise ValueError(f"{name}: no UTM coordinates in the name (expected ...@EAST@NORTH@..., as "
                             "the VPR datasets name their images)") from None
    return np.asarray(out, np.float64).reshape(-1, 2)


def _degrees(value, ref) -> float:
    d, m, s = (float(x) for x in value)
    deg = d + m / 60.0 + s / 3600.0
    return -deg if str(ref).upper() in ("S", "W") else deg


def exif_positions(paths) -> tuple[np.ndarray, list[int]]:
    """(latitude, longitude) rows of the photos whose EXIF holds a GPS position, and the rows without one."""
    from PIL import Image, UnidentifiedImageError  # Pillow: matplotlib's own dependency

    out, missing = [], []
    for k, p in enumerate(paths):
        try:
            with Image.open(p) as img:
                gps = img.getexif().get_ifd(0x8825)
            lat = _degrees(gps[2], gps[1])
            lon = _degrees(gps[4], gps[3])
        except (KeyError, TypeError, ValueError, ZeroDivisionError, OSError, UnidentifiedImageError):
            missing.append(k)
            out.append((np.nan, np.nan))
            continue
        out.append((lat, lon))
    return np.asarray(out, np.float64).reshape(-1, 2), missing


#: A gap between two samples of a trajectory longer than this (seconds), or than ``OUTAGE_INTERVALS`` of its
#: median sampling interval if that is longer, is an outage (a GPS without a fix, odometry that stopped): the
#: frames inside it get no position, since a straight line across a minute of driving is no ground truth.
OUTAGE_S = 5.0
OUTAGE_INTERVALS = 10


def outages(traj_t) -> np.ndarray:
    """(k, 2) start and end times of the gaps in a trajectory's times that are outages (see :data:`OUTAGE_S`)."""
    t = np.asarray(traj_t, np.float64)
    if t.size < 2:
        return np.zeros((0, 2))
    dt = np.diff(t)
    k = np.flatnonzero(dt > outage_limit(t))
    return np.stack([t[k], t[k + 1]], axis=1)


def outage_limit(traj_t) -> float:
    """The gap (seconds) beyond which a trajectory with these sample times has an outage (:data:`OUTAGE_S`)."""
    t = np.asarray(traj_t, np.float64)
    return max(OUTAGE_S, OUTAGE_INTERVALS * float(np.median(np.diff(t)))) if t.size > 1 else OUTAGE_S


#: A gap between two samples longer than this many of the trajectory's median intervals, and no outage, is a
#: short gap (a few fixes without a position): the frames inside it are interpolated across, and that is said.
SHORT_GAP_INTERVALS = 3


def short_gaps(traj_t) -> np.ndarray:
    """(k, 2) start and end times of the gaps in a trajectory's times that are longer than
    :data:`SHORT_GAP_INTERVALS` median intervals but are not :func:`outages`."""
    t = np.asarray(traj_t, np.float64)
    if t.size < 2:
        return np.zeros((0, 2))
    dt = np.diff(t)
    if not (dt > 0).any():
        return np.zeros((0, 2))
    k = np.flatnonzero((dt > SHORT_GAP_INTERVALS * float(np.median(dt[dt > 0]))) & (dt <= outage_limit(t)))
    return np.stack([t[k], t[k + 1]], axis=1)


#: seconds: the resolution of the times trajectories are written with (TUM: 6 decimals); a frame's time within it of
#: the trajectory's first or last sample is at that sample
TIME_RESOLUTION = 1e-6


def positions_at(times, traj_t, traj_xy) -> tuple[np.ndarray, np.ndarray]:
    """The trajectory's position at each of ``times``, linearly interpolated; and why a time has none.

    Returns ``(xy, why)``: ``why`` 0 where the time has a position, 1 before the first or after the last sample (never
    extrapolated), 2 inside an outage (:func:`outages`; never interpolated across); ``xy`` is NaN where ``why`` is not
    0.
    """
    times = np.asarray(times, np.float64)
    traj_t = np.asarray(traj_t, np.float64)
    traj_xy = np.asarray(traj_xy, np.float64)
    # a time at either end up to the files' resolution (a TUM trajectory's microseconds) is at that end
    why = np.where((times >= traj_t[0] - TIME_RESOLUTION) & (times <= traj_t[-1] + TIME_RESOLUTION), 0, 1)
    for a, b in outages(traj_t):
        why[(times > a) & (times < b)] = 2
    xy = np.full((times.size, traj_xy.shape[1]), np.nan)
    ok = why == 0
    if ok.any():
        xy[ok] = np.stack([np.interp(times[ok], traj_t, traj_xy[:, d]) for d in range(traj_xy.shape[1])], axis=1)
    return xy, why



def every(xy, metres: float) -> np.ndarray:
    """Positions of the frames to keep: the frame nearest each multiple of ``metres`` of travel.

    Travel is summed along the path (a stop adds nothing; a loop adds its length), so a robot standing at a traffic
    light keeps one frame. The k-th frame kept lies within half a frame's travel of ``k * metres``, whatever the frame
    rate and speed, so two traverses of one route sampled alike keep frames that pair one to one. A frame nearest two
    marks is kept once. Frames without a position (NaN) are never kept; travel runs from one frame with a position to
    the next.
    """
    xy = np.asarray(xy, np.float64)
    known = np.flatnonzero(~np.isnan(xy).any(axis=1)) if xy.ndim == 2 else np.zeros(0, np.int64)
    if known.size == 0:
        return np.zeros(0, np.int64)
    travel = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xy[known], axis=0), axis=1))]
    marks = np.arange(0.0, travel[-1] + metres / 2, metres)
    after = np.minimum(np.searchsorted(travel, marks), travel.size - 1)
    before = np.maximum(after - 1, 0)
    # the first frame at a mark (searchsorted) or the one before it, whichever is nearer; ties to the earlier
    nearer = np.where(marks - travel[before] <= travel[after] - marks, before, after)
    # a stop: the first frame of a run at one travel
    first = np.searchsorted(travel, travel[nearer])
    return known[np.unique(first)]
