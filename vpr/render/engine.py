"""Ray casting of the unrolled world, per-traverse lighting and camera effects."""
from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

from .objects import make_sprite
from .plan import TraversePlan, plan_traverse
from .world import LANE_CENTRE, WorldRaster

__all__ = ["Camera", "ConditionAtlas", "TraversePlan", "plan_traverse", "FrameRenderer", "texture_resolution"]

_N_MIP = 5
_SKY_ROWS, _SKY_COLS = 48, 360
_WARM = np.array([0.55, 0.82, 1.0], np.float32)  # BGR of tungsten light


def texture_resolution(kind: str, size, hfov: float, extent: float = 700.0, wall_height: float = 24.0,
                       width: float = 16.0, budget: float = 6e6) -> tuple[float, float]:
    """Texels per metre (walls, ground) so that a texel is about a pixel at a typical viewing distance.

    Long routes get coarser textures so that a wall (``extent`` x ``wall_height`` metres) or the ground (``extent`` x
    ``width``) stays within ``budget`` texels.
    """
    f = size[0] / 2.0 / math.tan(math.radians(hfov) / 2.0)
    if kind == "street":
        ppm, gppm = float(np.clip(round(f / 6.0), 4, 16)), float(np.clip(round(f / 8.0), 4, 12))
    else:
        ppm = gppm = float(np.clip(round(f / 2.5), 8, 40))
    ppm = min(ppm, max(1.0, math.floor(math.sqrt(budget / (extent * wall_height)))))
    gppm = min(gppm, max(1.0, math.floor(math.sqrt(budget / (extent * width)))))
    return ppm, gppm



class _Boards(NamedTuple):
    """The billboards on screen, one entry each: pixel columns ``u0 .. u1`` and rows ``r0 .. r1``, left edge ``lft``
    and width ``wpx`` (sub-pixel), top ``tp`` and bottom ``bt``, depth ``z``, the sprite's offset ``so``, height
    ``sh`` and width ``sw`` at its level, and the pixel ``area``."""

    u0: np.ndarray
    u1: np.ndarray
    r0: np.ndarray
    r1: np.ndarray
    lft: np.ndarray
    wpx: np.ndarray
    tp: np.ndarray
    bt: np.ndarray
    z: np.ndarray
    so: np.ndarray
    sh: np.ndarray
    sw: np.ndarray
    area: np.ndarray

class Camera:
    """Pinhole camera ray tables for one image size (``size`` = (width, height))."""

    def __init__(self, size, hfov: float):
        self.W, self.H = int(size[0]), int(size[1])
        self.f = self.W / 2.0 / math.tan(math.radians(hfov) / 2.0)
        self.cx = (self.W - 1) / 2.0
        self.cy = 0.48 * (self.H - 1)
        self.tx = ((np.arange(self.W) - self.cx) / self.f).astype(np.float64)
        self.ty = ((self.cy - np.arange(self.H)) / self.f).astype(np.float64)
        self.ty32 = self.ty.astype(np.float32)
        self.vh = int(np.searchsorted(-self.ty, 0.0, side="right"))  # first row below the horizon
        self.az = np.degrees(np.arctan(self.tx))
        el = np.degrees(np.arctan(np.maximum(self.ty[:self.vh], 0.0)))
        self.sky_row = np.clip((el / 90.0 * _SKY_ROWS).astype(np.int64), 0, _SKY_ROWS - 1)
        yy, xx = np.mgrid[0:self.H, 0:self.W]
        r2 = ((xx - self.cx) / (self.W / 2)) ** 2 + ((yy - (self.H - 1) / 2) / (self.H / 2)) ** 2
        self.r2 = (r2 / r2.max()).astype(np.float32)


def _pack(bgr_u8: np.ndarray) -> np.ndarray:
    """(…, 3) uint8 BGR -> (…) uint32 whose little-endian bytes are B, G, R, 0."""
    a = bgr_u8.astype(np.uint32)
    return a[..., 0] | (a[..., 1] << 8) | (a[..., 2] << 16)


def _mips(img_u8: np.ndarray, n: int) -> list[np.ndarray]:
    out = [img_u8]
    for _ in range(n - 1):
        h, w = out[-1].shape[:2]
        if h < 2 or w < 2:
            break
        out.append(cv2.resize(out[-1], ((w + 1) // 2, (h + 1) // 2), interpolation=cv2.INTER_AREA))
    return out


def _lighting(cond: dict, kind: str) -> dict:
    time, weather = cond["time"], cond["weather"]
    if kind == "street":
        amb = {"day": np.array([1.0, 1.0, 1.0]), "dusk": np.array([0.32, 0.38, 0.5]),
               "night": np.array([0.13, 0.12, 0.11])}[time]
        lamps = {"day": 0.0, "dusk": 0.35, "night": 0.6}[time]
        windows = {"day": 0.0, "dusk": 0.6, "night": 1.0}[time]
    else:
        amb = {"day": np.array([0.95, 0.97, 1.0]), "dusk": np.array([0.7, 0.75, 0.8]),
               "night": np.array([0.18, 0.17, 0.16])}[time]
        lamps = {"day": 0.25, "dusk": 0.25, "night": 0.5}[time]
        windows = {"day": 0.2, "dusk": 0.4, "night": 0.8}[time]
    if weather in ("overcast", "rain", "fog") and time == "day":
        amb = amb * 0.8
    return {"ambient": amb.astype(np.float32), "lamps": lamps, "windows": windows}


def _sky(cond: dict, noise: np.ndarray) -> np.ndarray:
    """Sky radiance (rows = elevation 0..90 deg, cols = azimuth) before gain/gamma."""
    t = (np.arange(_SKY_ROWS) / (_SKY_ROWS - 1))[:, None, None].astype(np.float32)
    time, weather = cond["time"], cond["weather"]
    hor, zen = {"day": ([0.95, 0.88, 0.80], [0.88, 0.60, 0.35]),
                "dusk": ([0.35, 0.50, 0.85], [0.35, 0.22, 0.20]),
                "night": ([0.13, 0.16, 0.2], [0.04, 0.03, 0.03])}[time]
    if weather != "clear" or cond["season"] == "winter":
        grey = {"day": 0.78, "dusk": 0.35, "night": 0.14}[time]
        hor = [grey * 1.02, grey, grey * 0.98]
        zen = [grey * 0.9, grey * 0.88, grey * 0.85]
    sky = np.array(hor, np.float32) * (1 - t) + np.array(zen, np.float32) * t
    sky = np.broadcast_to(sky, (_SKY_ROWS, _SKY_COLS, 3)).copy()
    cloud = np.clip(noise * 0.8 - 0.2, 0, 1)[..., None] * (t > 0.03)
    ccol = {"day": 0.97, "dusk": 0.55, "night": 0.08}[time]
    sky = sky * (1 - 0.7 * cloud) + 0.7 * cloud * ccol
    return sky


def _finish(lin: np.ndarray, cond: dict) -> np.ndarray:
    """Camera response: gain, clip, gamma; float [0, 1] linear -> uint8."""
    v = np.clip(lin * cond["gain"], 0.0, 1.0)
    if cond["gamma"] != 1.0:
        np.power(v, cond["gamma"], out=v)
    return (v * 255.0 + 0.5).astype(np.uint8)


def _season_albedo(alb: np.ndarray, season: str) -> np.ndarray:
    if season == "winter":
        grey = alb.mean(axis=-1, keepdims=True)
        alb = (0.7 * alb + 0.3 * grey) * np.array([1.06, 1.0, 0.94], np.float32)
    elif season == "autumn":
        alb = alb * np.array([0.92, 0.98, 1.06], np.float32)
    elif season == "spring":
        alb = alb * np.array([0.98, 1.03, 0.98], np.float32)
    return alb


class ConditionAtlas:
    """All textures and sprites of a world lit for one condition, packed for fast gathers."""

    def __init__(self, world: WorldRaster, cond: dict):
        self.cond = cond
        light = _lighting(cond, world.kind)
        amb = light["ambient"]
        blocks, self.layout = [], {}
        offset = 0

        def add(name, img_u8):
            nonlocal offset
            levels = _mips(img_u8, _N_MIP)
            info = []
            for lv in levels:
                p = _pack(lv)
                blocks.append(p.ravel())
                info.append((offset, p.shape[0], p.shape[1]))
                offset += p.size
            self.layout[name] = info

        winter = cond["season"] == "winter"
        for side in range(2):
            alb = _season_albedo(world.wall_alb[side], cond["season"])
            if winter and world.kind == "street":
                alb = np.where(world.wall_snow[side][..., None], np.float32(0.92), alb)
            rank = world.wall_emit[side]
            lit = ((rank > 0) & (rank <= cond["lit_windows"])).astype(np.float32) * light["windows"]
            lin = alb * amb + lit[..., None] * (0.4 * _WARM)
            add(("wall", side), _finish(lin, cond))
            del alb, lin, lit
        galb = _season_albedo(world.ground_alb, cond["season"])
        gk = world.ground_kind
        hw = world.half_width
        xg = (-hw + (np.arange(galb.shape[0]) + 0.5) / world.gppm)[:, None]
        trng = np.random.default_rng([world.seed, 11])
        if world.kind == "street":
            if winter:
                n = (0.05 * trng.standard_normal(galb.shape[:2])).astype(np.float32)
                snow = (0.9 + n)[..., None] * np.array([1.02, 1.0, 0.97], np.float32)
                # wheel tracks of the traffic in both lanes stay dark and wet
                track = np.zeros_like(xg, dtype=bool)
                for c in (LANE_CENTRE, -LANE_CENTRE):
                    track |= np.abs(np.abs(xg - c) - 0.8) < 0.25
                slush = np.float32(0.32) + 0.08 * n[..., None]
                road = (gk == 0) | (gk == 2)
                galb = np.where((road & track)[..., None], slush, snow)
            elif cond["season"] == "autumn":
                leaves = (trng.random(galb.shape[:2]) < 0.25) & (gk == 1)
                galb = np.where(leaves[..., None], np.array([0.1, 0.35, 0.6], np.float32), galb)
            if cond["weather"] == "rain" and not winter:
                galb = galb * 0.6
        # lamps light the ground: their pools scale the albedo like the ambient light does
        glin = galb * (amb + (world.ground_emit * light["lamps"])[..., None] * _WARM)
        add("ground", _finish(glin, cond))
        del galb, glin
        if world.ceil_alb is not None:
            on = {"day": 1.0, "dusk": 0.8, "night": 0.35}[cond["time"]]
            rank = world.ceil_emit
            lit = ((rank > 0) & (rank <= on)).astype(np.float32)
            clin = world.ceil_alb * amb + lit[..., None] * np.float32(1.0)
            add("ceiling", _finish(clin, cond))
        sky = _sky(cond, world.sky_noise)
        add("sky", _finish(sky, cond))
        self.atlas = np.concatenate(blocks)
        # fog colour: the horizon of the sky outdoors, a dim wall colour indoors
        if world.kind == "street":
            self.fog_colour = _finish(sky[1:2, :1].copy(), cond)[0, 0].astype(np.float32)
        else:
            self.fog_colour = _finish((np.float32(0.35) * amb)[None, None, :], cond)[0, 0].astype(np.float32)
        self.sprites = []
        sppm = world.extras.get("sprite_ppm", 24.0)
        for (typ, _), params in zip(world.sprite_keys, world.sprite_params, strict=False):
            alb, alpha, emit = make_sprite(typ, params, cond["season"], sppm)
            strength = light["lamps"] * 2.0 if typ in ("lamp", "exitsign") else light["lamps"]
            lin = _season_albedo(alb, cond["season"]) * amb + (emit * strength)[..., None] * _WARM
            rgb = _finish(lin, cond)
            lv_rgb = _mips(rgb, 6)
            lv_a = [alpha]
            for lv in lv_rgb[1:]:
                lv_a.append(cv2.resize(lv_a[-1], (lv.shape[1], lv.shape[0]), interpolation=cv2.INTER_AREA))
            self.sprites.append([(_pack(r), a > 0.5) for r, a in zip(lv_rgb, lv_a, strict=False)])
        # the same sprites in one flat array (alpha in the top byte) for drawing many small objects at once
        flat, tab, off = [], [], 0
        for levels in self.sprites:
            row = []
            for rgb, a in levels:
                flat.append((rgb | (a.astype(np.uint32) << 24)).ravel())
                row.append((off, rgb.shape[0], rgb.shape[1]))
                off += rgb.size
            tab.append(row + [row[-1]] * (8 - len(row)))
        self.sprite_flat = np.concatenate(flat)
        self.sprite_tab = np.array(tab, np.int64)  # (n_sprites, 8 levels, 3): offset, rows, cols
        self.sprite_nlev = np.array([len(levels) for levels in self.sprites], np.int64)


class FrameRenderer:
    """Renders frames of one traverse: world + camera + condition atlas + per-traverse effect banks."""

    def __init__(self, world: WorldRaster, camera: Camera, atlas: ConditionAtlas, cond: dict, seed: int,
                 max_depth: float):
        self.w, self.cam, self.a, self.cond = world, camera, atlas, cond
        self.tmax = float(max_depth)
        W, H = camera.W, camera.H
        rng = np.random.default_rng([seed, 303])
        self.pad = 16
        self.noise = None
        if cond["noise"] > 0:
            self.noise = (rng.standard_normal((H + self.pad, W + self.pad, 3)) * cond["noise"]).astype(np.float32)
        self.rain = []
        if cond["rain"] > 0:
            light = _lighting(cond, world.kind)["ambient"].mean()
            for _ in range(6):
                m = np.zeros((H, W), np.float32)
                k = int(cond["rain"] * W * H / 250)
                x0 = rng.uniform(0, W, k)
                y0 = rng.uniform(-H * 0.1, H, k)
                ln = rng.uniform(0.04, 0.12, k) * H
                slant = rng.normal(0.15, 0.03, k)
                for xa, ya, la, sa in zip(x0, y0, ln, slant, strict=False):
                    cv2.line(m, (int(xa), int(ya)), (int(xa + sa * la), int(ya + la)), 1.0, 1)
                m = cv2.GaussianBlur(m, (0, 0), 0.6) * np.float32(60.0 * (0.35 + 0.65 * light) * cond["rain"])
                self.rain.append(cv2.cvtColor(m, cv2.COLOR_GRAY2BGR))
        fog = cond["fog"]
        if fog is None:
            fog = 700.0 if world.kind == "street" else 90.0  # aerial perspective / dim far end
        self.fog = float(fog)
        self.vig = (1.0 - cond["vignette"] * camera.r2).astype(np.float32)
        self.fog_scalar = tuple(float(v) for v in atlas.fog_colour) + (0.0,)
        self.blur = cond["blur"] * W / 640.0
        # per-level lookup tables of the atlas layout
        if atlas.atlas.size >= 2 ** 31:
            raise ValueError("texture atlas too large for 32-bit indices; use a shorter route or smaller images")
        self.wall_tab = np.array([[lv for lv in atlas.layout[("wall", s)]] for s in range(2)], np.int64)
        self.wall_nlev = self.wall_tab.shape[1]
        self.ground_tab = np.array(atlas.layout["ground"], np.int64)
        self.ceil_tab = np.array(atlas.layout["ceiling"], np.int64) if "ceiling" in atlas.layout else None
        self.sky_base = atlas.layout["sky"][0][0]
        wt = world.wall_top
        self.top = np.stack(wt)  # (2, ncols)

    def _plane_rows(self, tab, t, dx, dz, p, xcam, ppm, dh):
        """Atlas indices of a horizontal plane ``dh`` metres above/below the camera for rows at distances ``t``."""
        cam, hw = self.cam, self.w.half_width
        # geometric mean of the across (t/f) and along (t^2/(f dh)) pixel footprints
        foot = t / cam.f * np.sqrt(np.maximum(t / dh, 1.0))
        lev = np.clip(np.floor(np.log2(np.maximum(foot * ppm, 1.0))).astype(np.int64), 0, len(tab) - 1)
        base, nx, nz = tab[lev, 0], tab[lev, 1], tab[lev, 2]
        scale = (ppm / (2.0 ** lev)).astype(np.float32)
        ts = (t * scale).astype(np.float32)[:, None]
        ix = (((xcam + hw) * scale)[:, None] + ts * dx[None, :]).astype(np.int32)
        iz = (((p - self.w.zlo) * scale)[:, None] + ts * dz[None, :]).astype(np.int32)
        # only the edge columns at the walls can step outside the texture
        np.minimum(np.maximum(ix, 0, out=ix), (nx - 1)[:, None], out=ix)
        np.minimum(np.maximum(iz, 0, out=iz), (nz - 1)[:, None], out=iz)
        ix *= nz[:, None]
        ix += base[:, None]
        ix += iz
        return ix

    def render(self, p: float, xcam: float, yaw: float, hcam: float, exposure: float = 1.0,
               noise_off=(0, 0), rain_pick: int = 0) -> np.ndarray:
        """One uint8 BGR frame with the camera at route position ``p`` (metres, world z)."""
        w, cam, tmax = self.w, self.cam, self.tmax
        W, f = cam.W, cam.f
        c, s = math.cos(yaw), math.sin(yaw)
        dx = s + cam.tx * c
        dz = c - cam.tx * s
        hw = w.half_width
        right = dx > 0
        dist = np.where(right, hw - xcam, hw + xcam)
        tw = np.minimum(dist / np.maximum(np.abs(dx), 1e-9), tmax)
        zhit = p + tw * dz
        side = right.astype(np.int64)
        col0 = np.clip(((zhit - w.zlo) * w.ppm).astype(np.int64), 0, self.top.shape[1] - 1)
        top = self.top[side, col0]
        # mip level per column: texel footprint along the wall and vertically
        fz = np.abs(np.gradient(zhit)) if W > 1 else np.zeros_like(zhit)
        foot = np.maximum(fz, tw / f) * w.ppm
        lev = np.clip(np.floor(np.log2(np.maximum(foot, 1.0))).astype(np.int64), 0, self.wall_nlev - 1)
        tab = self.wall_tab[side, lev]  # (W, 3): base, rows, cols
        scale = w.ppm / (2.0 ** lev)
        colw = np.clip(((zhit - w.zlo) * scale).astype(np.int64), 0, tab[:, 2] - 1)
        tw32 = tw.astype(np.float32)
        hgt = cam.ty32[:, None] * tw32[None, :]
        hgt += np.float32(hcam)
        on_wall = (hgt >= 0.0) & (hgt < top.astype(np.float32)[None, :])
        # rows off the wall are not clipped: np.where below never selects them
        roww = hgt * scale.astype(np.float32)[None, :]
        idx = roww.astype(np.int32)
        idx *= tab[:, 2].astype(np.int32)[None, :]
        idx += (tab[:, 0] + colw).astype(np.int32)[None, :]
        vh = cam.vh
        # ground below the horizon
        tg = np.minimum(hcam / np.maximum(-cam.ty[vh:], 1e-9), tmax * 1.5)
        dx32, dz32 = dx.astype(np.float32), dz.astype(np.float32)
        idx_g = self._plane_rows(self.ground_tab, tg, dx32, dz32, p, xcam, w.gppm, hcam)
        # sky or ceiling above
        if self.ceil_tab is not None:
            tc = np.minimum((w.ceiling - hcam) / np.maximum(cam.ty[:vh], 1e-9), tmax * 1.5)
            idx_u = self._plane_rows(self.ceil_tab, tc, dx32, dz32, p, xcam, w.gppm, w.ceiling - hcam)
            row_depth = np.concatenate([tc, tg]).astype(np.float32)
        else:
            az = np.mod(np.round(cam.az + math.degrees(yaw)).astype(np.int32), _SKY_COLS)
            idx_u = (self.sky_base + cam.sky_row[:, None] * _SKY_COLS + az[None, :]).astype(np.int32)
            row_depth = np.concatenate([np.full(vh, tmax * 3.0), tg]).astype(np.float32)
        off = ~on_wall
        np.copyto(idx[:vh], idx_u, where=off[:vh])
        np.copyto(idx[vh:], idx_g, where=off[vh:])
        depth = np.where(on_wall, tw32[None, :], row_depth[:, None])
        img = np.take(self.a.atlas, idx)
        self._objects(img, depth, p, xcam, c, s, hcam)
        return self._camera_effects(img, depth, exposure, noise_off, rain_pick)

    def _objects(self, img, depth, p, xcam, c, s, hcam):
        o, cam = self.w.objects, self.cam
        i0 = int(np.searchsorted(o["z"], p - 2.0))
        i1 = int(np.searchsorted(o["z"], p + self.tmax))
        if i1 <= i0:
            return
        rx = o["x"][i0:i1] - xcam
        rz = o["z"][i0:i1] - p
        xc = rx * c - rz * s
        zc = rx * s + rz * c
        ok = zc > 0.4
        if not ok.any():
            return
        ids = np.nonzero(ok)[0]
        zc, xc = zc[ids], xc[ids]
        ids = ids + i0
        ww, hh, bb = o["w"][ids], o["h"][ids], o["base"][ids]
        left = cam.cx + cam.f * (xc - ww / 2) / zc
        right = cam.cx + cam.f * (xc + ww / 2) / zc
        vtop = cam.cy - cam.f * (bb + hh - hcam) / zc
        vbot = cam.cy - cam.f * (bb - hcam) / zc
        vis = (right > -0.5) & (left < cam.W - 0.5) & (vbot > -0.5) & (vtop < cam.H - 0.5) & (right - left > 0.3)
        if not vis.any():
            return
        H, W = cam.H, cam.W
        # integer pixel bounds for all objects at once; a depth test makes the drawing order irrelevant
        j = np.nonzero(vis)[0]
        lft, rgt, tp, bt, zj = left[j], right[j], vtop[j], vbot[j], zc[j].astype(np.float32)
        u0 = np.maximum(np.ceil(lft - 0.5), 0).astype(np.int64)
        u1 = np.minimum(np.ceil(rgt - 0.5), W).astype(np.int64)
        thin = u1 <= u0
        u0[thin] = np.clip(np.floor((lft[thin] + rgt[thin]) / 2), 0, W - 1).astype(np.int64)
        u1[thin] = u0[thin] + 1
        r0 = np.maximum(np.ceil(tp - 0.5), 0).astype(np.int64)
        r1 = np.minimum(np.ceil(bt - 0.5), H).astype(np.int64)
        sid = o["sprite"][ids[j]]
        # sprite level: the coarsest whose width still covers the on-screen width
        wpx = rgt - lft
        tab = self.a.sprite_tab[sid]  # (k, 8, 3)
        lev = np.minimum(((tab[:, :, 2] >= wpx[:, None]).sum(1) - 1).clip(0), self.a.sprite_nlev[sid] - 1)
        so, sh, sw = (tab[np.arange(len(sid)), lev, i] for i in range(3))
        area = np.maximum(r1 - r0, 0) * (u1 - u0)
        small = (area > 0) & (area <= 256)
        if small.any():
            self._small_objects(img, depth, small, _Boards(u0, u1, r0, r1, lft, wpx, tp, bt, zj, so, sh, sw, area))
        flat = self.a.sprite_flat
        for k in np.nonzero(area > 256)[0].tolist():
            ci = np.minimum(np.maximum(((np.arange(u0[k], u1[k]) + 0.5 - lft[k]) * (sw[k] / wpx[k])).astype(np.int64),
                                       0), sw[k] - 1)
            ri = np.minimum(((np.arange(r0[k], r1[k]) + 0.5 - tp[k]) * (sh[k] / (bt[k] - tp[k]))).astype(np.int64),
                            sh[k] - 1)
            v = flat[so[k] + ri[:, None] * sw[k] + ci[None, :]]
            dreg = depth[r0[k]:r1[k], u0[k]:u1[k]]
            m = (v >= (1 << 24)) & (dreg > zj[k])
            np.copyto(img[r0[k]:r1[k], u0[k]:u1[k]], v, where=m)
            np.copyto(dreg, zj[k], where=m)

    def _small_objects(self, img, depth, sel, boards: _Boards):
        """Draw the ``sel`` of many small billboards with a few whole-array operations (nearest wins per pixel)."""
        u0, u1, r0, r1, lft, wpx, tp, bt, zj, so, sh, sw, area = boards
        k = np.nonzero(sel)[0]
        a = area[k]
        nw = (u1 - u0)[k]
        obj = np.repeat(np.arange(len(k)), a)
        li = np.arange(int(a.sum())) - np.repeat(np.cumsum(a) - a, a)
        row = li // nw[obj]
        col = li - row * nw[obj]
        kk = k[obj]
        pr = r0[kk] + row
        pc = u0[kk] + col
        ci = np.minimum(np.maximum(((pc + 0.5 - lft[kk]) * (sw[kk] / wpx[kk])).astype(np.int64), 0), sw[kk] - 1)
        ri = np.minimum(((pr + 0.5 - tp[kk]) * (sh[kk] / (bt[kk] - tp[kk]))).astype(np.int64), sh[kk] - 1)
        v = self.a.sprite_flat[so[kk] + ri * sw[kk] + ci]
        pix = pr * self.cam.W + pc
        z = zj[kk]
        keep = (v >= (1 << 24)) & (z < depth.ravel()[pix])
        if not keep.any():
            return
        pix, v, z = pix[keep], v[keep], z[keep]
        order = np.lexsort((z, pix))
        pix, v, z = pix[order], v[order], z[order]
        first = np.ones(len(pix), bool)
        first[1:] = pix[1:] != pix[:-1]
        img.ravel()[pix[first]] = v[first]
        depth.ravel()[pix[first]] = z[first]

    def _camera_effects(self, img32, depth, exposure, noise_off, rain_pick):
        H, W = self.cam.H, self.cam.W
        # OpenCV's saturating SIMD arithmetic is several times faster than NumPy here
        img = cv2.cvtColor(img32.view(np.uint8).reshape(H, W, 4), cv2.COLOR_BGRA2BGR)
        t = cv2.exp(depth * np.float32(-1.0 / self.fog))  # fog / aerial perspective transmittance
        g = self.vig * np.float32(exposure)
        a = cv2.cvtColor(t * g, cv2.COLOR_GRAY2BGR)
        b = cv2.multiply(cv2.cvtColor((1.0 - t) * g, cv2.COLOR_GRAY2BGR), self.fog_scalar)
        f = cv2.add(cv2.multiply(img, a, dtype=cv2.CV_32F), b)
        if self.rain:
            f = cv2.add(f, self.rain[int(rain_pick) % len(self.rain)])
        if self.blur > 0.05:
            f = cv2.GaussianBlur(f, (0, 0), self.blur)
        if self.noise is not None:
            oy, ox = int(noise_off[0]) % self.pad, int(noise_off[1]) % self.pad
            return cv2.add(f, self.noise[oy:oy + H, ox:ox + W], dtype=cv2.CV_8U)
        return cv2.add(f, np.zeros_like(f), dtype=cv2.CV_8U)
