"""Procedural worlds for the renderer: a street or an indoor corridor, unrolled along the route."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .objects import OBJECT_TYPES, place_corridor_objects, place_street_objects, variant_params
from .palettes import CORRIDOR_WALLS, FACADE_PALETTE, VIVID, smooth_noise

__all__ = ["WorldRaster", "build_world", "route_polyline", "LANE_CENTRE"]

LANE_CENTRE = 1.75  # metres right of a street's centre line: where the camera drives



@dataclass
class WorldRaster:
    """Rasterised world at a given texture resolution (``docs/internals.md``).

    Walls are indexed ``[side]`` with side 0 = left, 1 = right; wall rows start at the ground (row 0 = height 0). Wall
    column ``c`` covers ``z = zlo + (c + 0.5) / ppm``; ground/ceiling row ``i`` covers ``x = -half_width + (i + 0.5) /
    gppm`` and column ``j`` covers ``z = zlo + (j + 0.5) / gppm``.
    """

    kind: str
    length: float
    loop: bool
    half_width: float
    ceiling: float | None
    zlo: float
    zhi: float
    ppm: float
    gppm: float
    wall_alb: list
    wall_emit: list
    wall_snow: list
    wall_top: list
    ground_alb: np.ndarray
    ground_kind: np.ndarray  # 0 road, 1 sidewalk/floor, 2 paint, 3 kerb
    ground_emit: np.ndarray
    ceil_alb: np.ndarray | None
    ceil_emit: np.ndarray | None
    objects: dict
    sprite_keys: list
    sprite_params: list
    sky_noise: np.ndarray
    seed: int
    extras: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------- route geometry

def route_polyline(length: float, loop: bool, seed: int, step: float = 0.5) -> np.ndarray:
    """(x, y) in metres of the route at arc lengths ``0, step, 2 step, ... >= length``.

    Open routes meander with a heading that never deviates more than ~70 degrees from the mean direction, so they
    cannot cross themselves; loops are a perturbed circle of perimeter ``length`` (star-shaped, hence simple).
    """
    rng = np.random.default_rng([seed, 7])
    n = int(np.ceil(length / step)) + 1
    s = np.arange(n) * step
    if loop:
        th = np.linspace(0.0, 2 * np.pi, 4097)
        a = rng.uniform(0.03, 0.12, 2)
        ph = rng.uniform(0, 2 * np.pi, 2)
        r = 1.0 + a[0] * np.cos(2 * th + ph[0]) + a[1] * np.cos(3 * th + ph[1])
        pts = np.stack([r * np.cos(th), r * np.sin(th)], 1)
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        cum = np.concatenate([[0.0], np.cumsum(seg)])
        pts *= length / cum[-1]
        cum *= length / cum[-1]
        sm = np.mod(s, length)
        return np.stack([np.interp(sm, cum, pts[:, 0]), np.interp(sm, cum, pts[:, 1])], 1)
    k = 3
    lam = rng.uniform(150.0, 600.0, k)
    amp = rng.uniform(0.2, 0.4, k)
    ph = rng.uniform(0, 2 * np.pi, k)
    h0 = rng.uniform(0, 2 * np.pi)
    heading = h0 + (amp[:, None] * np.sin(2 * np.pi * s[None, :] / lam[:, None] + ph[:, None])).sum(0)
    d = np.stack([np.cos(heading), np.sin(heading)], 1) * step
    return np.concatenate([[[0.0, 0.0]], np.cumsum(d[:-1], axis=0)])


# ----------------------------------------------------------------------------- helpers

def _cols(zc, z0, z1):
    """Column slice covering [z0, z1) given sorted column centres ``zc``."""
    return slice(int(np.searchsorted(zc, z0)), int(np.searchsorted(zc, z1)))


# ----------------------------------------------------------------------------- street facades

def _plan_street_side(rng, a, b, loop):
    segs = []
    z = a
    while z < b:
        if segs and rng.random() < 0.12:
            w = rng.uniform(2.0, 6.0)
            segs.append({"type": "gap", "z0": z, "w": w, "height": rng.uniform(1.8, 9.0),
                         "colour": FACADE_PALETTE[rng.integers(len(FACADE_PALETTE))] * 0.45,
                         "fence": bool(rng.random() < 0.5)})
        else:
            w = rng.uniform(7.0, 22.0)
            fh = rng.uniform(2.9, 3.5)
            nfl = int(rng.integers(2, 8))
            ww = rng.uniform(0.8, 1.5)
            segs.append({
                "type": "building", "z0": z, "w": w, "floor_h": fh, "floors": nfl,
                "height": nfl * fh + rng.uniform(0.5, 1.2),
                "colour": np.clip(FACADE_PALETTE[rng.integers(len(FACADE_PALETTE))] +
                                  rng.uniform(-0.06, 0.06, 3), 0.05, 0.95).astype(np.float32),
                "win_w": ww, "win_h": rng.uniform(1.2, 1.8), "spacing": ww + rng.uniform(0.8, 2.2),
                "sill": rng.uniform(0.7, 1.0), "frame": np.float32(rng.choice([0.85, 0.2, 0.6])),
                "glass": np.array([0.33, 0.28, 0.24], np.float32) * rng.uniform(0.7, 1.3),
                "shop": bool(rng.random() < 0.55), "awning": VIVID[rng.integers(len(VIVID))],
                "brick": bool(rng.random() < 0.4), "band": bool(rng.random() < 0.35),
                "door": rng.uniform(0.15, 0.85),
                "win_seed": int(rng.integers(1 << 31)),
            })
        z += w
        segs[-1]["w"] = w
    if loop:
        # the last segment closes the loop exactly at b
        segs[-1]["w"] = b - segs[-1]["z0"]
        if segs[-1]["w"] < 2.0 and len(segs) > 1:
            segs.pop()
            segs[-1]["w"] = b - segs[-1]["z0"]
    return segs


def _raster_street_side(segs, zc, hr, alb, emit, snow, top):
    for sg in segs:
        cs = _cols(zc, sg["z0"], sg["z0"] + sg["w"])
        if cs.stop <= cs.start:
            continue
        zz = zc[cs] - sg["z0"]
        blk, em, sn = alb[:, cs], emit[:, cs], snow[:, cs]
        hb = sg["height"]
        top[cs] = hb
        blk[:] = sg["colour"]
        if sg["type"] == "gap":
            if sg["fence"]:
                slats = (np.mod(zz, 0.25) < 0.08)[None, :] & (hr < 1.8)[:, None]
                blk[slats] *= 0.6
            sn[np.abs(hr - hb) < 0.15, :] = True
            continue
        wrng = np.random.default_rng(sg["win_seed"])
        fh, sp, ww, wh, sill = sg["floor_h"], sg["spacing"], sg["win_w"], sg["win_h"], sg["sill"]
        nwin = max(1, int((sg["w"] - 1.0 + sp - ww) // sp))
        m0 = (sg["w"] - (nwin * sp - (sp - ww))) / 2.0
        k = np.floor((zz - m0) / sp).astype(int)
        loc = zz - m0 - k * sp
        fl = np.floor(hr / fh).astype(int)
        lr = hr - fl * fh
        if sg["brick"]:
            mortar = np.mod(hr, 0.3) < 0.045
            blk[mortar] *= 0.8
        if sg["band"]:
            band = (lr < 0.25) & (fl >= 1)
            blk[band] = np.clip(sg["colour"] * 1.25 + 0.05, 0, 1)
        # cornice and drainpipe
        blk[(hr > hb - 0.45) & (hr < hb - 0.15)] *= 0.7
        sn[(hr > hb - 0.15) & (hr < hb + 0.1), :] = True
        pipe = (zz > 0.15) & (zz < 0.27)
        blk[:, pipe] = 0.25
        in_col = (k >= 0) & (k < nwin) & (loc < ww)
        frame_col = (k >= 0) & (k < nwin) & (loc > -0.08) & (loc < ww + 0.08)
        upper = (fl >= 1) & (fl < sg["floors"])
        in_row = upper & (lr >= sill) & (lr < sill + wh)
        frame_row = upper & (lr >= sill - 0.08) & (lr < sill + wh + 0.08)
        sill_row = upper & (lr >= sill - 0.2) & (lr < sill - 0.08)
        blk[np.ix_(frame_row, frame_col)] = sg["frame"]
        blk[np.ix_(sill_row, frame_col)] = 0.75
        sn[np.ix_(sill_row, frame_col)] = True
        nf = sg["floors"] + 1
        gl = sg["glass"][None, None, :] * wrng.uniform(0.6, 1.5, (nf, nwin, 1)).astype(np.float32)
        curtains = wrng.random((nf, nwin)) < 0.3
        gl[curtains] = np.array([0.62, 0.70, 0.75], np.float32) * wrng.uniform(0.7, 1.1)
        rank = wrng.uniform(0.001, 1.0, (nf, nwin)).astype(np.float32)
        ri, ci = np.nonzero(in_row)[0], np.nonzero(in_col)[0]
        if len(ri) and len(ci):
            F, K = np.meshgrid(fl[ri], np.clip(k[ci], 0, nwin - 1), indexing="ij")
            blk[np.ix_(ri, ci)] = gl[F, K]
            em[np.ix_(ri, ci)] = rank[F, K]
            mull = np.abs(loc[ci] - ww / 2) < 0.04
            sub = blk[np.ix_(ri, ci[mull])]
            blk[np.ix_(ri, ci[mull])] = sg["frame"] * 0.9 + sub * 0.1
        # ground floor: shop front or plain windows + door
        door_z = sg["door"] * (sg["w"] - 1.4) + 0.2
        if sg["shop"]:
            shopwin = (hr > 0.5) & (hr < 2.55)
            panes = (zz > 0.5) & (zz < sg["w"] - 0.5) & (np.mod(zz, 2.0) > 0.1)
            blk[np.ix_(shopwin, panes)] = sg["glass"] * 1.2 + 0.05
            em[np.ix_(shopwin, panes)] = wrng.uniform(0.001, 0.5)
            aw = (hr > 2.7) & (hr < 3.3)
            blk[aw, :] = sg["awning"]
            text = (hr > 2.85) & (hr < 3.15)
            tz = (zz > sg["w"] * 0.25) & (zz < sg["w"] * 0.75)
            glyphs = tz & (wrng.random(len(zz)) < 0.5) & (np.mod(zz, 0.35) < 0.22)
            blk[np.ix_(text, glyphs)] = 0.92 if sg["awning"].mean() < 0.5 else 0.1
        else:
            gw = (hr > sill) & (hr < sill + wh)
            gz = in_col & (np.abs(zz - door_z - 0.6) > 1.2)
            blk[np.ix_(gw, gz)] = sg["glass"]
            em[np.ix_(gw, gz)] = rank[0, 0]
        door = (zz > door_z) & (zz < door_z + 1.2)
        blk[np.ix_(hr < 2.3, door)] = sg["awning"] * 0.5 + 0.08
        blk[np.ix_(hr < 0.3, np.ones(len(zz), bool))] *= 0.75  # plinth


# ----------------------------------------------------------------------------- corridor walls

def _plan_corridor_side(rng, a, b, loop):
    zones, z = [], a
    while z < b:
        w = rng.uniform(15.0, 35.0)
        doors, d = [], z + rng.uniform(1.0, 4.0)
        while d < z + w - 1.5:
            doors.append({"z": d, "w": rng.uniform(0.85, 1.1),
                          "colour": np.clip(rng.choice([[0.25, 0.38, 0.55], [0.55, 0.35, 0.15], [0.30, 0.30, 0.32],
                                                        [0.70, 0.72, 0.72]]) + rng.uniform(-0.05, 0.05, 3), 0, 1),
                          "glass": bool(rng.random() < 0.4)})
            d += doors[-1]["w"] + rng.uniform(2.0, 7.0)
        boards = [{"z": float(rng.uniform(z, z + w - 1.5)), "w": float(rng.uniform(0.8, 1.6)),
                   "seed": int(rng.integers(1 << 31))} for _ in range(int(rng.integers(0, 3)))]
        zones.append({"z0": z, "w": w, "colour": np.clip(CORRIDOR_WALLS[rng.integers(len(CORRIDOR_WALLS))] +
                                                          rng.uniform(-0.04, 0.04, 3), 0, 1).astype(np.float32),
                      "doors": doors, "boards": boards, "rail": bool(rng.random() < 0.5)})
        z += w
    if loop:
        zones[-1]["w"] = b - zones[-1]["z0"]
    return zones


def _raster_corridor_side(zones, zc, hr, alb, emit, snow, top, ceiling):
    top[:] = ceiling
    for zn in zones:
        cs = _cols(zc, zn["z0"], zn["z0"] + zn["w"])
        if cs.stop <= cs.start:
            continue
        blk = alb[:, cs]
        zz = zc[cs]
        blk[:] = zn["colour"]
        blk[hr < 0.12] = 0.18  # skirting
        if zn["rail"]:
            blk[(hr > 0.88) & (hr < 0.96)] = [0.25, 0.40, 0.55]
        for dr in zn["doors"]:
            fz = (zz > dr["z"] - 0.07) & (zz < dr["z"] + dr["w"] + 0.07)
            blk[np.ix_(hr < 2.17, fz)] = 0.55
            dz = (zz > dr["z"]) & (zz < dr["z"] + dr["w"])
            blk[np.ix_(hr < 2.1, dz)] = dr["colour"]
            if dr["glass"]:
                gz = dz & (np.abs(zz - dr["z"] - dr["w"] / 2) < 0.12)
                gr = (hr > 1.2) & (hr < 1.8)
                blk[np.ix_(gr, gz)] = [0.45, 0.40, 0.35]
                emit[np.ix_(gr, np.nonzero(gz)[0] + cs.start)] = 0.5
            hz = dz & (np.abs(zz - dr["z"] - dr["w"] * 0.85) < 0.06)
            blk[np.ix_((hr > 0.95) & (hr < 1.05), hz)] = 0.1
            pz = dz & (np.abs(zz - dr["z"] - dr["w"] / 2) < 0.1)
            blk[np.ix_((hr > 1.55) & (hr < 1.65), pz)] = 0.95
        for bd in zn["boards"]:
            bz = (zz > bd["z"]) & (zz < bd["z"] + bd["w"])
            br = (hr > 1.1) & (hr < 1.95)
            blk[np.ix_(br, bz)] = [0.25, 0.45, 0.62]
            brng = np.random.default_rng(bd["seed"])
            for _ in range(int(brng.integers(2, 7))):
                z0 = bd["z"] + brng.uniform(0.05, bd["w"] - 0.3)
                y0 = brng.uniform(1.15, 1.6)
                pz = (zz > z0) & (zz < z0 + brng.uniform(0.15, 0.3))
                py = (hr > y0) & (hr < y0 + brng.uniform(0.2, 0.3))
                blk[np.ix_(py, pz)] = brng.choice([0.95, 0.85, 0.6]) * np.array([1.0, 1.0, brng.uniform(0.8, 1.0)])
    snow[:] = False


# ----------------------------------------------------------------------------- ground / ceiling

def _raster_street_ground(rng, xg, zg, hw, alb, kind, a, b):
    sw = 2.5
    road_hw = hw - sw
    ax = np.abs(xg)[:, None]
    noise = 0.04 * smooth_noise(rng, alb.shape[:2], 6) + 0.03 * rng.standard_normal(alb.shape[:2]).astype(np.float32)
    side = ax > road_hw
    alb[:] = 0.27
    kind[:] = 0
    tiles = (np.mod(xg, 0.5) < 0.04)[:, None] | (np.mod(zg, 0.5) < 0.04)[None, :]
    pav = np.broadcast_to(side, alb.shape[:2])
    alb[pav] = [0.50, 0.54, 0.56]
    alb[pav & tiles] = [0.38, 0.40, 0.42]
    kind[pav] = 1
    kerb = np.broadcast_to((ax > road_hw - 0.05) & (ax <= road_hw + 0.15), alb.shape[:2])
    alb[kerb] = 0.62
    kind[kerb] = 3
    centre = (np.abs(xg) < 0.07)[:, None] & (np.mod(zg, 9.0) < 3.0)[None, :]
    edge = ((ax > road_hw - 0.45) & (ax < road_hw - 0.3)) & np.ones((1, len(zg)), bool)
    for m in (centre, edge):
        alb[m] = 0.82
        kind[m] = 2
    # crossings, patches and manholes make the road surface place-specific
    for zc in np.arange(a + rng.uniform(20, 80), b, rng.uniform(60, 140)):
        cz = (zg > zc) & (zg < zc + 3.5)
        m = ((np.abs(xg) < road_hw - 0.3) & (np.mod(xg, 1.0) < 0.5))[:, None] & cz[None, :]
        alb[m] = 0.85
        kind[m] = 2
    for _ in range(int((b - a) / 15)):
        z0, x0 = rng.uniform(a, b), rng.uniform(-road_hw, road_hw)
        cz = _cols(zg, z0, z0 + rng.uniform(2, 8))
        cx = _cols(xg, x0, x0 + rng.uniform(1, 4))
        sub = kind[cx, cz] == 0
        alb[cx, cz][sub] *= rng.uniform(0.75, 1.3)
    for _ in range(int((b - a) / 25)):
        z0, x0 = rng.uniform(a, b), rng.uniform(-road_hw + 0.5, road_hw - 0.5)
        cz = _cols(zg, z0 - 0.5, z0 + 0.5)
        r = np.hypot(xg[:, None] - x0, zg[None, cz] - z0)
        alb[:, cz][r < 0.35] = 0.15
        alb[:, cz][(r < 0.4) & (r >= 0.35)] = 0.45
    alb *= (1.0 + noise)[..., None]


def _raster_corridor_floor(rng, xg, zg, hw, alb, kind, zones):
    alb[:] = [0.45, 0.48, 0.50]
    for zn in zones:
        cz = _cols(zg, zn["z0"], zn["z0"] + zn["w"])
        alb[:, cz] = np.clip(zn["colour"] * 0.55 + rng.uniform(-0.05, 0.05, 3), 0, 1)
    tiles = (np.mod(xg + hw, 0.6) < 0.03)[:, None] | (np.mod(zg, 0.6) < 0.03)[None, :]
    alb[tiles] *= 0.85
    worn = np.exp(-(xg / 0.45) ** 2)[:, None] * (0.12 + 0.08 * smooth_noise(rng, alb.shape[:2], 10))
    alb *= (1.0 - worn)[..., None]
    alb *= (1.0 + 0.03 * rng.standard_normal(alb.shape[:2]).astype(np.float32))[..., None]
    kind[:] = 1


def _raster_ceiling(rng, xg, zg, alb, emit, a, b):
    alb[:] = 0.82
    grid = (np.mod(xg, 0.6) < 0.03)[:, None] | (np.mod(zg, 0.6) < 0.03)[None, :]
    alb[grid] = 0.62
    z = a + rng.uniform(0.5, 2.0)
    while z < b:
        cz = _cols(zg, z, z + 1.2)
        cx = _cols(xg, -0.3, 0.3)
        alb[cx, cz] = 0.95
        emit[cx, cz] = rng.uniform(0.001, 1.0)
        z += rng.choice([2.4, 3.0, 3.6])
    for _ in range(int((b - a) / 12)):
        z0 = rng.uniform(a, b)
        cz, cx = _cols(zg, z0, z0 + 0.6), _cols(xg, 0.5, 1.1) if rng.random() < 0.5 else _cols(xg, -1.1, -0.5)
        alb[cx, cz] = 0.55
        alb[cx, cz][::2] = 0.4


# ----------------------------------------------------------------------------- the world

def build_world(wspec: dict, ppm: float, gppm: float, max_depth: float, sprite_ppm: float = 24.0) -> WorldRaster:
    """Rasterise the world of a resolved ``world`` spec at ``ppm`` texels per metre (walls), ``gppm`` (ground).

    The plan (buildings, doors, objects) depends only on ``wspec['seed']``; the resolution only changes how finely it
    is sampled.
    """
    kind, L, loop = wspec["kind"], float(wspec["length"]), bool(wspec["loop"])
    hw = float(wspec["half_width"])
    seed = int(wspec["seed"])
    margin = 12.0
    zlo, zhi = -margin, L + max_depth + margin
    a, b = (0.0, L) if loop else (zlo, zhi)
    if loop:
        # whole numbers of texels per loop, so that the texture wraps without a seam
        ppm = round(L * ppm) / L
        gppm = round(L * gppm) / L
    rng_plan = np.random.default_rng([seed, 1])
    rng_tex = np.random.default_rng([seed, 2])
    ncols = int(round((b - a) * ppm))
    ngz = int(round((b - a) * gppm))
    zc = a + (np.arange(ncols) + 0.5) / ppm
    zg = a + (np.arange(ngz) + 0.5) / gppm
    nx = max(2, int(round(2 * hw * gppm)))
    xg = -hw + (np.arange(nx) + 0.5) / gppm
    ceiling = wspec.get("ceiling")
    height = 24.0 if kind == "street" else float(ceiling)
    hpx = int(np.ceil(height * ppm)) + 1
    hr = (np.arange(hpx) + 0.5) / ppm

    walls_alb, walls_emit, walls_snow, walls_top, plans = [], [], [], [], []
    for _side in range(2):
        alb = np.zeros((hpx, ncols, 3), np.float32)
        emit = np.zeros((hpx, ncols), np.float32)
        snow = np.zeros((hpx, ncols), bool)
        top = np.zeros(ncols, np.float32)
        if kind == "street":
            segs = _plan_street_side(rng_plan, a, b, loop)
            _raster_street_side(segs, zc, hr, alb, emit, snow, top)
        else:
            segs = _plan_corridor_side(rng_plan, a, b, loop)
            _raster_corridor_side(segs, zc, hr, alb, emit, snow, top, float(ceiling))
        plans.append(segs)
        # stains and grain so that plain walls still carry some texture
        alb *= (1.0 + 0.06 * smooth_noise(rng_tex, (hpx, ncols), max(2.0, ppm * 1.5))
                + 0.03 * rng_tex.standard_normal((hpx, ncols)).astype(np.float32))[..., None]
        np.clip(alb, 0.0, 1.0, out=alb)
        walls_alb.append(alb)
        walls_emit.append(emit)
        walls_snow.append(snow)
        walls_top.append(top)

    galb = np.zeros((nx, ngz, 3), np.float32)
    gkind = np.zeros((nx, ngz), np.uint8)
    gemit = np.zeros((nx, ngz), np.float32)
    calb = cemit = None
    if kind == "street":
        _raster_street_ground(rng_tex, xg, zg, hw, galb, gkind, a, b)
    else:
        _raster_corridor_floor(rng_tex, xg, zg, hw, galb, gkind, plans[0])
        calb = np.zeros((nx, ngz, 3), np.float32)
        cemit = np.zeros((nx, ngz), np.float32)
        _raster_ceiling(rng_tex, xg, zg, calb, cemit, a, b)
    np.clip(galb, 0.0, 1.0, out=galb)

    types = OBJECT_TYPES[kind]
    nvar = [6, 2, 6, 3, 1, 8] if kind == "street" else [1, 3, 2, 1, 1, 2]
    vparams = [[variant_params(rng_plan, t) for _ in range(n)] for t, n in zip(types, nvar, strict=False)]
    if kind == "street":
        rows = place_street_objects(rng_plan, a, b, hw, wspec["density"], nvar)
    else:
        rows = place_corridor_objects(rng_plan, a, b, hw, wspec["density"], nvar)
    obj = np.array(rows, np.float64).reshape(-1, 4)
    if loop:
        obj[:, 3] = np.mod(obj[:, 3], L)

    # place aliasing: copy a stretch of walls, ground and objects onto another
    for al in wspec.get("aliasing", []):
        src, dst, ln = al["source"], al["target"], al["length"]
        n = int(round(ln * ppm))
        c_s, c_d = int(round((src - a) * ppm)), int(round((dst - a) * ppm))
        for side in range(2):
            walls_alb[side][:, c_d:c_d + n] = walls_alb[side][:, c_s:c_s + n]
            walls_emit[side][:, c_d:c_d + n] = walls_emit[side][:, c_s:c_s + n]
            walls_snow[side][:, c_d:c_d + n] = walls_snow[side][:, c_s:c_s + n]
            walls_top[side][c_d:c_d + n] = walls_top[side][c_s:c_s + n]
        ng = int(round(ln * gppm))
        g_s, g_d = int(round((src - a) * gppm)), int(round((dst - a) * gppm))
        for arr in (galb, gkind, gemit, calb, cemit):
            if arr is not None:
                arr[:, g_d:g_d + ng] = arr[:, g_s:g_s + ng]
        keep = ~((obj[:, 3] >= dst) & (obj[:, 3] < dst + ln))
        cp = obj[(obj[:, 3] >= src) & (obj[:, 3] < src + ln)].copy()
        cp[:, 3] += dst - src
        obj = np.concatenate([obj[keep], cp])

    if loop:
        # extend the periodic textures to [zlo, zhi] so lookups never wrap per pixel
        ext = np.mod(np.floor((zlo + (np.arange(int(round((zhi - zlo) * ppm))) + 0.5) / ppm - a) * ppm).astype(int),
                     ncols)
        gext = np.mod(np.floor((zlo + (np.arange(int(round((zhi - zlo) * gppm))) + 0.5) / gppm) * gppm)
                      .astype(int), ngz)
        walls_alb = [w[:, ext] for w in walls_alb]
        walls_emit = [w[:, ext] for w in walls_emit]
        walls_snow = [w[:, ext] for w in walls_snow]
        walls_top = [w[ext] for w in walls_top]
        galb, gkind, gemit = galb[:, gext], gkind[:, gext], gemit[:, gext]
        if calb is not None:
            calb, cemit = calb[:, gext], cemit[:, gext]
        obj = np.concatenate([obj + [0, 0, 0, k * L] for k in range(-1, int(np.ceil(zhi / L)) + 1)])
        obj = obj[(obj[:, 3] >= zlo) & (obj[:, 3] <= zhi)]

    if kind == "street":
        # street lamps light a pool of ground around them (used at night)
        lamps = obj[obj[:, 0] == 1]
        zg_full = zlo + (np.arange(galb.shape[1]) + 0.5) / gppm
        for _, _, lx, lz in lamps:
            cz = _cols(zg_full, lz - 9, lz + 9)
            r2 = (xg[:, None] - lx * 0.7) ** 2 + (zg_full[None, cz] - lz) ** 2
            gemit[:, cz] += np.exp(-r2 / (2 * 2.5 ** 2)).astype(np.float32)

    order = np.argsort(obj[:, 3], kind="stable")
    obj = obj[order]
    keys = [(t, v) for t in range(len(types)) for v in range(nvar[t])]
    key_index = {k: i for i, k in enumerate(keys)}
    sprite_id = np.array([key_index[(int(t), int(v))] for t, v in obj[:, :2]], np.int32)
    sp = [vparams[t][v] for t, v in keys]
    objects = {
        "sprite": sprite_id,
        "x": obj[:, 2].astype(np.float32),
        "z": obj[:, 3].astype(np.float64),
        "w": np.array([sp[i]["w"] for i in sprite_id], np.float32),
        "h": np.array([sp[i]["h"] for i in sprite_id], np.float32),
        "base": np.array([sp[i]["base"] for i in sprite_id], np.float32),
    }
    return WorldRaster(
        kind=kind, length=L, loop=loop, half_width=hw, ceiling=ceiling, zlo=zlo, zhi=zhi,
        ppm=ppm, gppm=gppm, wall_alb=walls_alb, wall_emit=walls_emit, wall_snow=walls_snow, wall_top=walls_top,
        ground_alb=galb, ground_kind=gkind, ground_emit=gemit, ceil_alb=calb, ceil_emit=cemit,
        objects=objects, sprite_keys=[(types[t], v) for t, v in keys], sprite_params=sp,
        sky_noise=smooth_noise(np.random.default_rng([seed, 3]), (48, 360), 8), seed=seed,
        extras={"sprite_ppm": sprite_ppm})
