"""In-memory rendering of a scene: traverses with frames and ground truth."""
from __future__ import annotations

import copy
import json
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from .engine import Camera, ConditionAtlas, FrameRenderer, plan_traverse, texture_resolution
from .spec import SpecContext, check_spec_size, load_spec
from .world import LANE_CENTRE, build_world, route_polyline

__all__ = ["Traverse", "Scene", "SceneRenderer", "render_scene", "gt_matrix", "loop_pairs", "apply_overrides",
           "MAX_FRAMES"]

#: Most frames a traverse may be rendered with (about 28 hours at 10 frames per second): a larger count is a typo.
MAX_FRAMES = 1_000_000


@dataclass
class Traverse:
    """One rendered pass along the route; per-frame arrays have N rows.

    Attributes
    ----------
    name : str
    images : np.ndarray
        uint8 (N, H, W, 3) BGR frames.
    route_pos : np.ndarray
        Metres along the route, growing over the laps of a loop.
    xy : np.ndarray
        (N, 2) camera position in metres (lateral offset included).
    conditions : dict
        The resolved conditions.
    place_pos : np.ndarray
        ``route_pos`` modulo the loop length: equal values see the same place.
    lateral, yaw_deg : np.ndarray
        The camera's offset from the lane centre (m) and yaw jitter (degrees).
    loop_length : float or None
        None for open routes.
    fps : float
        The spec's nominal frame rate.
    """

    name: str
    images: np.ndarray
    route_pos: np.ndarray
    xy: np.ndarray
    conditions: dict
    place_pos: np.ndarray = field(default=None)
    lateral: np.ndarray = field(default=None)
    yaw_deg: np.ndarray = field(default=None)
    loop_length: float | None = None
    fps: float = 10.0

    def __len__(self) -> int:
        return len(self.route_pos)


@dataclass
class Scene:
    """A rendered scene: the resolved spec (with the overrides applied) and its traverses."""

    spec: dict
    traverses: list

    def __getitem__(self, name: str) -> Traverse:
        for t in self.traverses:
            if t.name == name:
                return t
        raise KeyError(f"no traverse {name!r} (have: {', '.join(t.name for t in self.traverses)})")

    @property
    def names(self) -> list[str]:
        return [t.name for t in self.traverses]


def apply_overrides(spec, size=None, n_frames=None, traverses=None, seed=None) -> dict:
    spec = copy.deepcopy(spec)
    ctx = SpecContext("render_scene")
    if size is not None:
        if not isinstance(size, (tuple, list)) or len(size) != 2 or not all(
                isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in size):
            raise ValueError(f"size: expected (width, height) integers, got {size!r}")
        check_spec_size(ctx, "size", (int(size[0]), int(size[1])))
        spec["camera"]["size"] = [int(size[0]), int(size[1])]
    if n_frames is not None:
        if isinstance(n_frames, bool) or not isinstance(n_frames, (int, np.integer)) or n_frames < 1:
            raise ValueError(f"n_frames: expected a positive integer number of frames, got {n_frames!r}")
        if n_frames > MAX_FRAMES:
            raise ValueError(f"n_frames: at most {MAX_FRAMES} frames per traverse, got {n_frames}")
    if seed is not None:
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed: expected a non-negative integer, got {seed!r}")
        spec["world"]["seed"] = int(seed)
    if traverses is not None:
        if isinstance(traverses, str):
            traverses = [traverses]
        have = [t["name"] for t in spec["traverses"]]
        unknown = [n for n in traverses if n not in have]
        if unknown:
            raise ValueError(f"traverses: unknown traverse(s) {', '.join(map(repr, unknown))} "
                             f"(spec has: {', '.join(have)})")
        spec["traverses"] = [t for t in spec["traverses"] if t["name"] in traverses]
    return spec


class SceneRenderer:
    """Builds the world of a resolved spec once and renders its traverses frame by frame.

    Use :func:`render_scene` for the in-memory API; this class exists so that ``vpr render`` can stream frames to disk
    without holding them all.
    """

    def __init__(self, spec: dict, n_frames: int | None = None):
        self.spec = spec
        cam, wspec = spec["camera"], spec["world"]
        self.n_frames = n_frames
        self.camera = Camera(cam["size"], cam["hfov"])
        ppm, gppm = texture_resolution(wspec["kind"], cam["size"], cam["hfov"],
                                       extent=wspec["length"] + cam["max_depth"] + 24.0,
                                       wall_height=24.0 if wspec["kind"] == "street" else wspec["ceiling"],
                                       width=2 * wspec["half_width"])
        # objects are seen closer than walls (a metre away in a corridor): finer sprites
        f = self.camera.f
        sprite_ppm = float(np.clip(round(f / (1.5 if wspec["kind"] == "corridor" else 4.0)), 16, 64))
        self.world = build_world(wspec, ppm, gppm, cam["max_depth"], sprite_ppm)
        self.route_xy = route_polyline(wspec["length"], wspec["loop"], wspec["seed"], 0.5)
        self._atlases = {}

    def plan(self, tspec):
        return plan_traverse(tspec, self.spec["world"], self.spec["camera"], self.n_frames, self.route_xy, 0.5)

    def _atlas(self, cond):
        # traverses that differ only in camera effects share the lit textures
        keys = ("time", "season", "weather", "gain", "gamma", "lit_windows")
        k = json.dumps({kk: cond[kk] for kk in keys}, sort_keys=True)
        if k not in self._atlases:
            self._atlases[k] = ConditionAtlas(self.world, cond)
        return self._atlases[k]

    def frames(self, tspec, plan=None):
        """Yield the uint8 BGR frames of one traverse in order."""
        plan = plan if plan is not None else self.plan(tspec)
        cond = tspec["conditions"]
        fr = FrameRenderer(self.world, self.camera, self._atlas(cond), cond, tspec["seed"],
                           self.spec["camera"]["max_depth"])
        # world z of the camera: positions wrap for loops so texture lookups stay in range
        z = np.mod(plan.route_pos, self.world.length) if self.world.loop else plan.route_pos
        # the route polyline is the centre of the driving lane: the right-hand lane of a street
        x = plan.lateral + (LANE_CENTRE if self.world.kind == "street" else 0.0)
        # a rare swing of the random lateral wander must not take the camera through a wall
        lim = self.world.half_width - 0.2
        x = np.clip(x, -lim, lim)
        for k in range(plan.n):
            yield fr.render(float(z[k]), float(x[k]), float(plan.yaw[k]), float(plan.hcam[k]),
                            float(plan.exposure[k]), plan.noise_off[k], int(plan.rain_pick[k]))

    def traverse(self, tspec, progress: bool = False) -> Traverse:
        plan = self.plan(tspec)
        W, H = self.camera.W, self.camera.H
        images = np.empty((plan.n, H, W, 3), np.uint8)
        it = self.frames(tspec, plan)
        if progress:
            from tqdm import tqdm
            it = tqdm(it, total=plan.n, desc=f"render {tspec['name']}", unit="frame")
        for k, img in enumerate(it):
            images[k] = img
        return self.make_traverse(tspec, plan, images)

    def make_traverse(self, tspec, plan, images) -> Traverse:
        w = self.spec["world"]
        return Traverse(name=tspec["name"], images=images, route_pos=plan.route_pos.copy(), xy=plan.xy.copy(),
                        conditions=copy.deepcopy(tspec["conditions"]), place_pos=plan.place.copy(),
                        lateral=plan.lateral.copy(), yaw_deg=np.degrees(plan.yaw),
                        loop_length=float(w["length"]) if w["loop"] else None, fps=float(self.spec["camera"]["fps"]))


def render_scene(spec, size=None, n_frames=None, traverses=None, seed=None, progress: bool = False) -> Scene:
    """Render every traverse of a scene in memory; returns a :class:`Scene`.

    ``spec``: a file, builtin name or dict (:func:`vpr.render.load_spec`). Overrides: ``size`` (width, height >= 16),
    ``n_frames`` (the same path sampled with this many frames), ``traverses`` (only these), ``seed`` (another world by
    the same rules). ``progress``: a tqdm bar per traverse.
    """
    resolved = apply_overrides(load_spec(spec), size, n_frames, traverses, seed)
    r = SceneRenderer(resolved, n_frames)
    return Scene(spec=resolved, traverses=[r.traverse(t, progress) for t in resolved["traverses"]])


def _xy(t, name):
    xy = t.xy if isinstance(t, Traverse) else np.asarray(t, float)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"{name}: expected a Traverse or (N, 2) positions, got shape {xy.shape}")
    return xy


def gt_matrix(db, query, radius: float) -> np.ndarray:
    """Bool (N_db, N_query): True where the camera positions are within ``radius`` metres.

    ``db`` and ``query`` are :class:`Traverse` objects (or (N, 2) position arrays).
    """
    if isinstance(radius, bool) or not isinstance(radius, (int, float, np.number)) or not radius >= 0:
        raise ValueError(f"radius: expected a non-negative number of metres, got {radius!r}")
    a, b = _xy(db, "db"), _xy(query, "query")
    G = np.zeros((len(a), len(b)), bool)
    if len(a) and len(b):
        for i, js in enumerate(cKDTree(b).query_ball_point(a, r=float(radius))):
            G[i, js] = True
    return G


def loop_pairs(traverse: Traverse, radius: float, exclude: float | None = None) -> np.ndarray:
    """Bool T x T matrix of frame pairs of one traverse that see the same place again.

    A pair (i, j) is a revisit when the camera positions are within ``radius`` metres and the camera travelled at
    least ``exclude`` metres between the two frames (so that neighbouring frames of the same pass and frames during a
    stop are not counted). ``exclude`` defaults to half the loop length for loops and to ``10 * radius`` for open
    routes. The matrix is symmetric with a False diagonal.
    """
    if not isinstance(traverse, Traverse):
        raise ValueError(f"traverse: expected a Traverse, got {type(traverse).__name__}")
    if exclude is None:
        exclude = traverse.loop_length / 2 if traverse.loop_length else 10.0 * float(radius)
    if isinstance(exclude, bool) or not isinstance(exclude, (int, float, np.number)) or exclude < 0:
        raise ValueError(f"exclude: expected a non-negative distance in metres, got {exclude!r}")
    G = gt_matrix(traverse, traverse, radius)
    d = traverse.route_pos
    G &= np.abs(d[:, None] - d[None, :]) >= exclude
    np.fill_diagonal(G, False)
    return G
