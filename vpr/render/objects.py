"""Street furniture and corridor objects: where they stand, and their sprites in each season."""
from __future__ import annotations

import cv2
import numpy as np

from .palettes import FACADE_PALETTE, VIVID, smooth_noise

__all__ = ["OBJECT_TYPES", "make_sprite", "variant_params", "place_street_objects", "place_corridor_objects"]

OBJECT_TYPES = {
    "street": ("tree", "lamp", "sign", "bin", "bollard", "car"),
    "corridor": ("extinguisher", "plant", "bin", "pillar", "exitsign", "bench"),
}


def variant_params(rng, typ):
    u = rng.uniform
    if typ == "tree":
        return {"w": u(2.5, 5.0), "h": u(5.0, 9.0), "base": 0.0, "trunk": u(0.2, 0.4), "crown": u(0.45, 0.7),
                "hue": u(-0.08, 0.08), "seed": int(rng.integers(1 << 31))}
    if typ == "lamp":
        return {"w": 1.4, "h": u(5.5, 7.0), "base": 0.0, "seed": int(rng.integers(1 << 31))}
    if typ == "sign":
        return {"w": 0.7, "h": u(2.5, 3.0), "base": 0.0, "shape": int(rng.integers(3)),
                "colour": VIVID[rng.integers(4)].tolist(), "seed": int(rng.integers(1 << 31))}
    if typ == "bin":
        return {"w": u(0.5, 0.8), "h": u(0.9, 1.2), "base": 0.0,
                "colour": (np.array([0.2, 0.35, 0.15]) * u(0.6, 1.6)).tolist(), "seed": int(rng.integers(1 << 31))}
    if typ == "bollard":
        return {"w": 0.22, "h": 0.9, "base": 0.0, "seed": int(rng.integers(1 << 31))}
    if typ == "car":
        return {"w": 1.8, "h": u(1.4, 1.7), "base": 0.0,
                "colour": np.clip(rng.choice(FACADE_PALETTE) * u(0.5, 1.3), 0.05, 0.95).tolist(),
                "seed": int(rng.integers(1 << 31))}
    if typ == "extinguisher":
        return {"w": 0.2, "h": 0.6, "base": 0.35, "seed": int(rng.integers(1 << 31))}
    if typ == "plant":
        return {"w": u(0.5, 0.9), "h": u(0.9, 1.6), "base": 0.0, "hue": u(-0.05, 0.05),
                "seed": int(rng.integers(1 << 31))}
    if typ == "pillar":
        return {"w": 0.5, "h": 3.0, "base": 0.0, "colour": u(0.55, 0.75), "seed": int(rng.integers(1 << 31))}
    if typ == "exitsign":
        return {"w": 0.45, "h": 0.22, "base": 2.25, "seed": int(rng.integers(1 << 31))}
    if typ == "bench":
        return {"w": 1.3, "h": 0.85, "base": 0.0, "colour": u(0.2, 0.5), "seed": int(rng.integers(1 << 31))}
    raise ValueError(f"unknown object type {typ!r}")


def place_street_objects(rng, a, b, hw, density, variants):
    rows = []  # (type, variant, x, z)
    sw = 2.5
    for side in (-1, 1):
        xs = side * (hw - 1.0)
        z = a + rng.uniform(0, 10)
        while z < b:  # tree stretches
            if rng.random() < 0.5 * min(1.0, density):
                z1 = z + rng.uniform(30, 90)
                tz = z
                while tz < min(z1, b):
                    rows.append((0, int(rng.integers(variants[0])), xs + rng.uniform(-0.3, 0.3), tz))
                    tz += rng.uniform(7, 13) / max(density, 0.2)
                z = z1
            else:
                z += rng.uniform(20, 60)
        for lz in np.arange(a + rng.uniform(0, 30), b, 30.0 / max(density, 0.2)):
            rows.append((1, int(rng.integers(variants[1])), side * (hw - 0.5), lz + rng.uniform(-2, 2)))
        n = int((b - a) / 25 * density)
        for t, nv, dx in ((2, variants[2], -0.4), (3, variants[3], -0.6), (4, variants[4], -2.3)):
            for z0 in rng.uniform(a, b, int(n * (0.5 if t != 2 else 0.8))):
                rows.append((t, int(rng.integers(nv)), side * (hw + dx), z0))
        z = a + rng.uniform(0, 30)
        while z < b:  # parked cars in clusters
            if rng.random() < 0.4 * min(1.0, density):
                for _ in range(int(rng.integers(1, 5))):
                    rows.append((5, int(rng.integers(variants[5])), side * (hw - sw - 1.1), z))
                    z += rng.uniform(5.0, 6.5)
            z += rng.uniform(15, 50)
    return rows


def place_corridor_objects(rng, a, b, hw, density, variants):
    rows = []
    for side in (-1, 1):
        for t, every, dx in ((0, 25, 0.12), (1, 30, 0.4), (2, 35, 0.35), (5, 45, 0.35)):
            for z0 in rng.uniform(a, b, int((b - a) / every * density)):
                rows.append((t, int(rng.integers(variants[t])), side * (hw - dx), z0))
    for z0 in np.arange(a + rng.uniform(5, 20), b, 24.0 / max(density, 0.2)):  # pillars pairs
        if rng.random() < 0.5:
            for side in (-1, 1):
                rows.append((3, 0, side * (hw - 0.25), z0))
    for z0 in np.arange(a + rng.uniform(5, 20), b, 20.0 / max(density, 0.2)):
        rows.append((4, 0, 0.0, z0 + rng.uniform(-3, 3)))
    return rows


def make_sprite(typ: str, p: dict, season: str, ppm: float = 24.0):
    """Albedo (h, w, 3), alpha (h, w), emissive (h, w) float32 of one object, bottom row at its base."""
    h_px = max(4, int(round(p["h"] * ppm)))
    w_px = max(2, int(round(p["w"] * ppm)))
    alb = np.zeros((h_px, w_px, 3), np.float32)
    alpha = np.zeros((h_px, w_px), np.float32)
    emit = np.zeros((h_px, w_px), np.float32)
    rng = np.random.default_rng(p["seed"])
    cx = w_px / 2.0

    def rect(x0, y0, x1, y1, col, a=1.0):
        # y measured upwards from the base in metres, x from the left edge
        r0, r1 = h_px - int(round(y1 * ppm)), h_px - int(round(y0 * ppm))
        c0, c1 = int(round(x0 * ppm)), int(round(x1 * ppm))
        r0, c0 = max(r0, 0), max(c0, 0)
        if r1 > r0 and c1 > c0:
            alb[r0:r1, c0:c1] = col
            alpha[r0:r1, c0:c1] = a
        return slice(r0, r1), slice(c0, c1)

    W, H = p["w"], p["h"]
    if typ == "tree":
        rect(W / 2 - p["trunk"] / 2, 0, W / 2 + p["trunk"] / 2, H * 0.75, [0.12, 0.18, 0.25])
        yy, xx = np.mgrid[0:h_px, 0:w_px].astype(np.float32)
        ry, rx = h_px * p["crown"] / 2, w_px / 2
        ccy = h_px * p["crown"] / 2
        n = smooth_noise(rng, (h_px, w_px), max(2.0, w_px / 6))
        d = np.sqrt(((yy - ccy) / ry) ** 2 + ((xx - cx) / rx) ** 2) + 0.15 * n
        crown = d < 0.95
        shade = (0.8 + 0.25 * n - 0.25 * (yy - ccy) / ry)[..., None]
        if season == "winter":
            # bare branches: a few thick strokes from the trunk upwards
            br = np.zeros((h_px, w_px), np.uint8)
            for _ in range(9):
                x1 = int(cx + rng.uniform(-1, 1) * rx * 0.9)
                y1 = int(ccy + rng.uniform(-1, 0.6) * ry)
                cv2.line(br, (int(cx), int(h_px * 0.7)), (x1, y1), 1, max(1, w_px // 40))
            m = (br > 0) | ((d < 0.95) & (rng.random((h_px, w_px)) < 0.07))
            alb[m] = [0.14, 0.17, 0.2]
            alpha[m] = 1.0
        else:
            base = {"summer": [0.12, 0.42, 0.22], "spring": [0.2, 0.6, 0.35],
                    "autumn": [0.08, 0.38, 0.72]}[season]
            col = np.clip(np.array(base, np.float32) + [0, p["hue"], -p["hue"]], 0, 1)
            alb[crown] = (col[None, None, :] * shade)[crown]
            alpha[crown] = 1.0
    elif typ == "lamp":
        rect(0.05, 0, 0.2, H, [0.22, 0.22, 0.24])
        rect(0.05, H - 0.12, 1.3, H, [0.22, 0.22, 0.24])
        rows, cols = rect(0.9, H - 0.3, 1.4, H - 0.05, [0.35, 0.38, 0.4])
        emit[rows, cols] = 1.0
    elif typ == "sign":
        rect(W / 2 - 0.04, 0, W / 2 + 0.04, H - 0.3, [0.5, 0.5, 0.5])
        plate = np.zeros((h_px, w_px), np.uint8)
        r = int(W * ppm / 2) - 1
        cyp = int(h_px - (H - 0.3) * ppm)
        if p["shape"] == 0:
            cv2.circle(plate, (int(cx), cyp), r, 1, -1)
        elif p["shape"] == 1:
            cv2.rectangle(plate, (1, max(0, cyp - r)), (w_px - 2, cyp + r), 1, -1)
        else:
            pts = np.array([[int(cx), max(0, cyp - r)], [w_px - 1, cyp], [int(cx), cyp + r], [0, cyp]], np.int32)
            cv2.fillPoly(plate, [pts], 1)
        m = plate > 0
        alb[m] = p["colour"]
        inner = cv2.erode(plate, np.ones((3, 3), np.uint8), iterations=max(1, r // 3)) > 0
        alb[inner] = 0.9
        alpha[m] = 1.0
    elif typ == "bin":
        rect(0, 0, W, H, p["colour"])
        rect(0, H - 0.1, W, H, np.array(p["colour"]) * 0.6)
    elif typ == "bollard":
        rect(0, 0, W, H, [0.3, 0.3, 0.32])
        rect(0, H - 0.25, W, H - 0.15, [0.9, 0.9, 0.9])
    elif typ == "car":
        c = np.array(p["colour"], np.float32)
        rect(0, 0.25, W, H * 0.62, c)
        rect(0.22, H * 0.62, W - 0.22, H, c * 0.9)
        rect(0.3, H * 0.64, W - 0.3, H * 0.95, [0.12, 0.1, 0.1])
        rect(0.05, 0, 0.35, 0.35, [0.05, 0.05, 0.05])
        rect(W - 0.35, 0, W - 0.05, 0.35, [0.05, 0.05, 0.05])
        for x0 in (0.05, W - 0.3):
            rows, cols = rect(x0, H * 0.45, x0 + 0.25, H * 0.55, [0.1, 0.1, 0.7])
            emit[rows, cols] = 0.8
        rect(W / 2 - 0.25, 0.35, W / 2 + 0.25, 0.48, [0.92, 0.92, 0.92])
    elif typ == "extinguisher":
        rect(0.02, 0, W - 0.02, H * 0.85, [0.1, 0.1, 0.75])
        rect(W * 0.3, H * 0.85, W * 0.7, H, [0.1, 0.1, 0.1])
    elif typ == "plant":
        rect(W * 0.25, 0, W * 0.75, 0.4, [0.15, 0.3, 0.5])
        yy, xx = np.mgrid[0:h_px, 0:w_px].astype(np.float32)
        n = smooth_noise(rng, (h_px, w_px), max(2.0, w_px / 5))
        ccy, ry = h_px * 0.35, h_px * 0.38
        d = np.sqrt(((yy - ccy) / ry) ** 2 + ((xx - cx) / (w_px / 2)) ** 2) + 0.2 * n
        m = d < 0.95
        alb[m] = np.clip(np.array([0.15, 0.45 + p["hue"], 0.2]) * (0.8 + 0.3 * n[m, None]), 0, 1)
        alpha[m] = 1.0
    elif typ == "pillar":
        rect(0, 0, W, H, p["colour"])
        rect(0, 0, W, 0.12, 0.2)
    elif typ == "exitsign":
        rect(0, 0, W, H, [0.2, 0.6, 0.1])
        rows, cols = rect(0.05, 0.04, W - 0.05, H - 0.04, [0.3, 0.85, 0.2])
        emit[rows, cols] = 0.9
        rect(0.1, 0.07, 0.2, H - 0.07, 0.95)
        rect(W / 2 - 0.01, H, W / 2 + 0.01, H, 0.3)
    elif typ == "bench":
        rect(0, 0.4, W, 0.5, p["colour"])
        rect(0, 0.6, W, 0.85, p["colour"] * 0.9)
        rect(0.1, 0, 0.18, 0.45, 0.15)
        rect(W - 0.18, 0, W - 0.1, 0.45, 0.15)
    if season == "winter":
        # snow caps: the top few opaque pixels of every column
        op = alpha > 0
        first = np.argmax(op, axis=0)
        has = op.any(axis=0)
        depth = max(1, int(round(0.12 * ppm)))
        r = np.arange(h_px)[:, None]
        cap = has[None, :] & (r >= first[None, :]) & (r < first[None, :] + depth) & op
        if typ not in ("extinguisher", "exitsign", "plant", "pillar", "bench"):
            alb[cap] = 0.92
    return alb, alpha, emit
