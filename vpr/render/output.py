"""Writing rendered scenes to disk: PNG folders, ground truth, contact sheets, videos, and ``vpr render``."""
from __future__ import annotations

import contextlib
import csv
import io
from pathlib import Path

import cv2
import numpy as np

from ..io import atomic_open, atomic_path, save_image, save_json
from .scene import SceneRenderer, apply_overrides, loop_pairs
from .spec import load_spec

__all__ = ["write_scene", "contact_sheet"]

GT_COLUMNS = ["frame", "traverse", "route_pos", "x", "y", "place_pos", "lateral", "yaw_deg", "image"]


def _sample_indices(plan, n_cols: int, length: float, loop: bool) -> list[int]:
    """Frames of one traverse nearest to ``n_cols`` evenly spaced places (first pass only)."""
    places = np.linspace(0.05, 0.9, n_cols) * length
    first = plan.route_pos - plan.route_pos[0] < (length if loop else np.inf)
    cand = np.nonzero(first)[0]
    d = np.abs(plan.place[cand][None, :] - places[:, None])
    return [int(cand[i]) for i in d.argmin(axis=1)]


def contact_sheet(rows: list[tuple[str, list[np.ndarray]]], tile_width: int = 240) -> np.ndarray:
    """A grid image: a labelled row of sample frames (uint8 BGR, equal sizes) per traverse, tiles
    ``tile_width`` wide.
    """
    if not rows:
        raise ValueError("contact_sheet: no rows")
    h0, w0 = rows[0][1][0].shape[:2]
    tw = int(tile_width)
    th = max(1, round(h0 * tw / w0))
    gap, label_h = 4, 22
    ncol = max(len(fr) for _, fr in rows)
    W = ncol * tw + (ncol + 1) * gap
    H = len(rows) * (th + label_h + gap) + gap
    sheet = np.full((H, W, 3), 255, np.uint8)
    y = gap
    for label, frames in rows:
        cv2.putText(sheet, label, (gap, y + 15), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (20, 20, 20), 1, cv2.LINE_AA)
        y += label_h
        for j, fr in enumerate(frames):
            x = gap + j * (tw + gap)
            sheet[y:y + th, x:x + tw] = cv2.resize(fr, (tw, th), interpolation=cv2.INTER_AREA)
        y += th + gap
    return sheet


def _label(t, kind: str) -> str:
    c = t["conditions"]
    what = f"{c['season']} {c['time']}, {c['weather']}" if kind == "street" else {
        "day": "lights on", "dusk": "lights dimmed", "night": "night lighting"}[c["time"]]
    return f"{t['name']}: {what}, speed {t['speed']['mean']:g} m/s"


def write_scene(spec, out_dir, preview: bool = False, video: bool = False, traverses=None,
                size=None, n_frames=None, seed=None, progress: bool = True, loop_radius: float = 5.0) -> dict:
    """Render a scene to ``out_dir`` (what ``vpr render`` does), each file written atomically.

    Writes ``<traverse>/000000.png ...``; ``ground_truth.csv`` (``frame, traverse, route_pos, x, y, place_pos,
    lateral, yaw_deg, image``, metres); ``scene.json`` (the resolved spec); with ``preview`` ``contact_sheet.png``;
    with ``video`` ``<traverse>.mp4``; for closed loops ``loop_pairs.csv`` (``traverse, frame_a, frame_b, distance``,
    the revisits within ``loop_radius`` metres, a < b).

    ``spec``: a file, builtin scene name or dict; ``traverses``: only these; ``size``, ``n_frames``, ``seed``: as
    :func:`vpr.render.render_scene`. Returns ``{"out_dir", "scene", "ground_truth", "preview", "loop_pairs",
    "traverses": {name: {"frames", "folder", "video"}}}``, paths as strings (None: not written).
    """
    from tqdm import tqdm

    resolved = apply_overrides(load_spec(spec), size, n_frames, traverses, seed)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"out_dir: {out} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    r = SceneRenderer(resolved, n_frames)
    fps = resolved["camera"]["fps"]
    W, H = resolved["camera"]["size"]
    summary = {"out_dir": str(out), "scene": str(out / "scene.json"), "ground_truth": str(out / "ground_truth.csv"),
               "preview": None, "loop_pairs": None, "traverses": {}}
    gt = io.StringIO()
    wr = csv.writer(gt, lineterminator="\n")
    wr.writerow(GT_COLUMNS)
    sheet_rows = []
    L, loop = resolved["world"]["length"], resolved["world"]["loop"]
    plans = {}
    for t in resolved["traverses"]:
        plan = plans[t["name"]] = r.plan(t)
        folder = out / t["name"]
        folder.mkdir(parents=True, exist_ok=True)
        samples = set(_sample_indices(plan, 6, L, loop)) if preview else set()
        picked = {}
        with contextlib.ExitStack() as stack:
            writer = None
            if video:
                # callbacks run last-in first-out: the writer is released before the rename
                tmp = stack.enter_context(atomic_path(out / f"{t['name']}.mp4"))
                writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (W, H))
                stack.callback(writer.release)
                if not writer.isOpened():
                    raise OSError(f"{out / (t['name'] + '.mp4')}: OpenCV could not open an mp4v video writer")
            frames = r.frames(t, plan)
            if progress:
                frames = stack.enter_context(tqdm(frames, total=plan.n, desc=f"render {t['name']}", unit="frame"))
            for k, img in enumerate(frames):
                name = f"{k:06d}.png"
                save_image(folder / name, img)
                if writer is not None:
                    writer.write(img)
                if k in samples:
                    picked[k] = img
                wr.writerow([k, t["name"], f"{plan.route_pos[k]:.3f}", f"{plan.xy[k, 0]:.3f}", f"{plan.xy[k, 1]:.3f}",
                             f"{plan.place[k]:.3f}", f"{plan.lateral[k]:.3f}", f"{np.degrees(plan.yaw[k]):.3f}",
                             f"{t['name']}/{name}"])
        summary["traverses"][t["name"]] = {"frames": plan.n, "folder": str(folder),
                                           "video": str(out / f"{t['name']}.mp4") if video else None}
        if preview:
            sheet_rows.append((_label(t, resolved["world"]["kind"]), [picked[k] for k in sorted(picked)]))
    with atomic_open(out / "ground_truth.csv", "w", encoding="utf-8", newline="") as fh:
        fh.write(gt.getvalue())
    if loop:
        # revisits of the same place, as loop_pairs() gives them, upper triangle only
        lp = io.StringIO()
        lw = csv.writer(lp, lineterminator="\n")
        lw.writerow(["traverse", "frame_a", "frame_b", "distance"])
        for t in resolved["traverses"]:
            tr = r.make_traverse(t, plans[t["name"]], None)
            i, j = np.nonzero(np.triu(loop_pairs(tr, loop_radius)))
            d = np.linalg.norm(tr.xy[i] - tr.xy[j], axis=1)
            lw.writerows([t["name"], a, b, f"{dd:.3f}"] for a, b, dd in zip(i.tolist(), j.tolist(), d, strict=False))
        with atomic_open(out / "loop_pairs.csv", "w", encoding="utf-8", newline="") as fh:
            fh.write(lp.getvalue())
        summary["loop_pairs"] = str(out / "loop_pairs.csv")
    save_json(out / "scene.json", resolved)
    if preview:
        summary["preview"] = str(save_image(out / "contact_sheet.png", contact_sheet(sheet_rows)))
    return summary
