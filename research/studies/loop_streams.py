"""The loop-closure streams the loop decision is chosen and reported on, encoded once and cached.

Every stream is one sequence of frames with loop ground truth: ``hard[i, j]``
(frame ``j`` revisits earlier frame ``i``), ``soft`` (pairs neither right nor
wrong), and, for forward-only drives, nothing (every accepted closure is
false, including those onto a world's identical copy of a stretch).

- ``gardens_point``: Gardens Point day_left then day_right (200 + 200 frames,
  960x540): frame 200 + k revisits k; hard within 2 frames, soft within 8.
- ``nordland_stream``: Nordland summer then winter, every 10th file (358 +
  358): hard within 1 frame of the other traverse, soft within 3.
- ``nordland_full``: the same at the full frame rate (3,576 + 3,576 frames):
  hard within 10 frames, soft within 30. Ten times the frames per place: the
  sequence evidence (decay 0.9, about ten frames) spans one place, not ten.
- ``nordland_summer``, ``nordland_winter``: each whole ride (3,576 frames),
  forward only (the train stands at stations: a stop is not a loop).
- rendered at 160x120 and the scenes' native frame counts: ``loop_revisits``
  (three laps: hard within 5 m, soft within 10 m); forward only:
  ``two_seasons/summer_day``, ``two_seasons/winter_night``,
  ``speed_change/slow``, ``speed_change/fast`` and ``aliased_corridor/lights_on``
  (three identical stretches). ``--seed`` renders other worlds of the same specs.

Streams are encoded with a preset's loop encoder (causal standardisation) and
cached in ``--cache`` (SDRs and ground truth; the datasets under ``--data`` or
``$VPR_DATASETS``).
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import scipy.sparse as sp

import encoders
from vpr import presets
from vpr.sources import open_source

__all__ = ["REAL_REVISITS", "RENDERED_REVISITS", "FORWARD", "Stream", "load_stream", "encoder_for"]

REAL_REVISITS = ("gardens_point", "nordland_stream", "nordland_full")
#: The size rendered streams are rendered at (a study may render them larger to give geometry more pixels).
RENDER_SIZE = (160, 120)
RENDERED_REVISITS = ("loop_revisits/laps",)
FORWARD = ("nordland_summer", "nordland_winter", "two_seasons/summer_day", "two_seasons/winter_night",
           "speed_change/slow", "speed_change/fast", "aliased_corridor/lights_on")


class Stream:
    """One encoded stream: ``x`` (SDRs), ``hard`` / ``soft`` (T x T bool over pairs i < j, or None: forward only),
    the source ``images`` loader (for verification at full resolution), a name, and ``scored`` (a cache of
    :func:`vpr.shosm.confirm_closures`)."""

    def __init__(self, name: str, x: sp.csr_matrix, hard, soft, frames: list[str] | None = None):
        self.name, self.x, self.hard, self.soft, self.frames = name, x, hard, soft, frames
        self.scored: dict = {}  # the frames' standardised overlaps, kept for confirming closures (confirm_closures)

    @property
    def forward_only(self) -> bool:
        return self.hard is None

    def __len__(self) -> int:
        return self.x.shape[0]


def encoder_for(preset: str):
    """The loop encoder of ``preset`` (with its causal standardisation)."""
    s = presets.resolve(preset, loops=True)
    return encoders.get(s["encoder"], **s["encoder_conf"])


def _band(pos, trav, hard: float, soft: float):
    """Pairs of different traverses within ``hard`` / ``soft`` of each other along the route."""
    d = np.abs(pos[:, None] - pos[None])
    other = trav[:, None] != trav[None]
    upper = np.triu(np.ones(d.shape, bool), 1)
    return other & upper & (d <= hard), other & upper & (d <= soft)


def _encode(enc, images) -> sp.csr_matrix:
    return sp.csr_matrix(enc.encode(images))


def _build(name: str, preset: str, data: Path, seed):
    enc = encoder_for(preset)
    if name == "gardens_point":
        files = [sorted((data / "gardens_point_day" / t).glob("*.jpg")) for t in ("day_left", "day_right")]
        frames = [str(f) for fs in files for f in fs]
        images = [f.image for t in ("day_left", "day_right") for f in open_source(data / "gardens_point_day" / t)]
        pos = np.concatenate([np.arange(len(f)) for f in files]).astype(float)
        trav = np.repeat([0, 1], [len(f) for f in files])
        hard, soft = _band(pos, trav, 2, 8)
        return _encode(enc, images), hard, soft, frames
    if name in ("nordland_stream", "nordland_full"):
        root = data / "nordland_trimmed"
        step = 10 if name == "nordland_stream" else None
        srcs = [open_source(root / s, step=step) for s in ("summer", "winter")]
        frames = [str(root / s / n) for s, src in zip(("summer", "winter"), srcs, strict=True) for n in src.names()]
        images = [f.image for src in srcs for f in src]
        pos = np.concatenate([np.arange(len(src.names())) for src in srcs]).astype(float)
        trav = np.repeat([0, 1], [len(src.names()) for src in srcs])
        hard, soft = _band(pos, trav, *((1, 3) if step else (10, 30)))
        return _encode(enc, images), hard, soft, frames
    if name in ("nordland_summer", "nordland_winter"):
        src = open_source(data / "nordland_trimmed" / name.split("_")[1])
        frames = [str(src.path / n) for n in src.names()]
        return _encode(enc, [f.image for f in src]), None, None, frames
    from vpr.render import render_scene

    scene, traverse = name.split("/")
    t = render_scene(scene, size=RENDER_SIZE, traverses=[traverse], seed=seed).traverses[0]
    x = _encode(enc, list(t.images))
    if name in RENDERED_REVISITS:
        d = np.linalg.norm(t.xy[:, None] - t.xy[None], axis=-1)
        upper = np.triu(np.ones(d.shape, bool), 1)
        return x, upper & (d <= 5.0), upper & (d <= 10.0), None
    return x, None, None, None


def load_stream(name: str, preset: str = "default", cache: Path | str = "results/loop_streams", data=None,
                seed=None) -> Stream:
    """The encoded stream ``name`` (see the module docstring), from the cache when it is there."""
    import os

    data = Path(data or os.environ.get("VPR_DATASETS", "../shared/datasets"))
    size = [] if RENDER_SIZE == (160, 120) or "/" not in name else [list(RENDER_SIZE)]
    key = hashlib.sha1(json.dumps([name, preset, seed, 1, *size]).encode()).hexdigest()[:10]
    path = Path(cache) / f"{name.replace('/', '-')}-{preset}-{seed}-{key}.npz"
    if path.is_file():
        with np.load(path, allow_pickle=False) as z:
            x = sp.csr_matrix((np.ones(z["idx"].size, bool), z["idx"], z["ptr"]), shape=tuple(z["shape"]))
            hard = sp.csr_matrix((np.ones(z["h_i"].size, bool), (z["h_i"], z["h_j"])), shape=x.shape[:1] * 2) \
                if "h_i" in z.files else None
            soft = sp.csr_matrix((np.ones(z["s_i"].size, bool), (z["s_i"], z["s_j"])), shape=x.shape[:1] * 2) \
                if "s_i" in z.files else None
            frames = z["frames"].tolist() if "frames" in z.files else None
        return Stream(name, x, None if hard is None else hard.toarray(), None if soft is None else soft.toarray(),
                      frames)
    x, hard, soft, frames = _build(name, preset, data, seed)
    arrays = {"idx": x.indices, "ptr": x.indptr, "shape": np.array(x.shape)}
    if hard is not None:
        arrays["h_i"], arrays["h_j"] = np.nonzero(hard)
        arrays["s_i"], arrays["s_j"] = np.nonzero(soft)
    if frames is not None:
        arrays["frames"] = np.array(frames)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **arrays)
    return Stream(name, x, hard, soft, frames)
