"""Where the camera is along the route at each frame of a traverse: its speed, lateral offset, yaw and height, and
the frame's random draws."""
from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

from .world import route_polyline

__all__ = ["TraversePlan", "plan_traverse"]


class TraversePlan:
    """Camera states of one traverse (all arrays length N) and its per-frame random draws."""

    def __init__(self, **kw):
        self.__dict__.update(kw)


def _smooth_along(rng, d, corr):
    """Zero-mean, unit-std smooth random function of travelled distance ``d`` (correlation ``corr`` m)."""
    n = int(np.ceil(d.max() if len(d) else 0.0)) + int(6 * corr) + 2
    white = rng.standard_normal(n)
    sm = gaussian_filter1d(white, corr, mode="wrap")
    sm /= max(sm.std(), 1e-9)
    return np.interp(d, np.arange(n), sm)


def plan_traverse(tspec: dict, world: dict, camera: dict, n_frames: int | None = None,
                  route_xy: np.ndarray | None = None, route_step: float = 0.5) -> TraversePlan:
    """Frame positions, lateral offsets, yaw and ground truth of one resolved traverse spec.

    The speed profile is integrated over time at ``camera['fps']``; ``n_frames`` instead spreads exactly that many
    frames over the same path (same stops and speed changes, coarser in time).
    """
    if n_frames is not None and (isinstance(n_frames, bool) or int(n_frames) != n_frames or n_frames < 1):
        raise ValueError(f"n_frames must be a positive integer, got {n_frames!r}")
    L, loop = world["length"], world["loop"]
    start, end = tspec["start"], tspec["end"]
    if loop:
        span = (end - start) % L or L
        D = (tspec["laps"] - 1) * L + span
    else:
        D = end - start
    rng = np.random.default_rng([tspec["seed"], 101])
    sp = tspec["speed"]
    step = 0.05
    dg = np.arange(0.0, D + step, step)
    dg[-1] = D
    pos = start + dg
    place = np.mod(pos, L) if loop else pos
    v = np.full_like(dg, sp["mean"])
    if sp["profile"]:
        pp = np.array(sp["profile"], float)
        v *= np.interp(place, pp[:, 0], pp[:, 1])
    if sp["variation"] > 0:
        v *= np.clip(1.0 + sp["variation"] * _smooth_along(rng, dg, 40.0), 0.1, None)
    tg = np.concatenate([[0.0], np.cumsum(np.diff(dg) / (0.5 * (v[1:] + v[:-1])))])
    for s_pos, dur in sp["stops"]:
        if dur <= 0:
            continue
        first = (s_pos - start) % L if loop else s_pos - start
        reps = np.arange(first, D, L) if loop else ([first] if 0 <= first <= D else [])
        for ds in reps:
            tg[dg > ds] += dur
    fps = camera["fps"]
    if n_frames is None:
        n = int(np.floor(tg[-1] * fps + 1e-9)) + 1
        times = np.arange(n) / fps
    else:
        n = int(n_frames)
        times = np.linspace(0.0, tg[-1], n)
    d = np.interp(times, tg, dg)
    cond = tspec["conditions"]
    lateral = cond["lane"] + cond["lateral_offset"] * _smooth_along(rng, d, 25.0)
    yaw = np.radians(cond["yaw_jitter"]) * (0.9 * _smooth_along(rng, d, 12.0) + 0.2 * rng.standard_normal(n))
    hcam = camera["height"] * (1.0 + 0.01 * _smooth_along(rng, d, 8.0))
    route_pos = start + d
    place = np.mod(route_pos, L) if loop else route_pos
    if route_xy is None:
        route_xy = route_polyline(L, loop, world["seed"], route_step)
    s_tab = np.arange(len(route_xy)) * route_step
    cxy = np.stack([np.interp(place, s_tab, route_xy[:, 0]), np.interp(place, s_tab, route_xy[:, 1])], 1)
    tang = np.stack([np.interp(place + 0.5, s_tab, route_xy[:, 0]) - np.interp(place - 0.5, s_tab, route_xy[:, 0]),
                     np.interp(place + 0.5, s_tab, route_xy[:, 1]) - np.interp(place - 0.5, s_tab, route_xy[:, 1])], 1)
    tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), 1e-9)
    right = np.stack([tang[:, 1], -tang[:, 0]], 1)
    xy = cxy + lateral[:, None] * right
    frame_rng = np.random.default_rng([tspec["seed"], 202])
    return TraversePlan(
        n=n, times=times, route_pos=route_pos, place=place, lateral=lateral, yaw=yaw, hcam=hcam, xy=xy,
        exposure=np.clip(1.0 + cond["exposure_jitter"] * frame_rng.standard_normal(n), 0.5, 1.5),
        noise_off=frame_rng.integers(0, 1 << 30, (n, 2)), rain_pick=frame_rng.integers(0, 1 << 30, n),
        seed=tspec["seed"])
