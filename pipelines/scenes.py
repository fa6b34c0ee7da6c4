"""How an image encoder fares on the rendered scenes: every traverse pair scored frame by frame and as sequences.

:func:`score_encoder` renders the builtin scenes of :mod:`vpr.render` (or the
ones given), encodes every traverse with one encoder (fitted on each traverse
first when its conf says ``standardise=fit``, which removes the appearance a
whole traverse shares) and scores every ordered pair of a scene's traverses
with :data:`vpr.presets.ENCODER_TEST_METHODS` (SDR overlap of single frames,
and a sequence memory learned on the database traverse): average precision and recall@1
against :func:`vpr.render.gt_matrix` within ``radius`` (pairs within twice
that are ignored). A scene of one traverse is scored as loop closure against
its own past (the single-frame method only).
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from encoders import available, get, get_class
from vpr import evaluate, methods, presets, render
from vpr.evaluate import recall_at_k
from vpr.types import EncodedTraverse

__all__ = ["EncoderTest", "METHODS", "score_encoder", "list_encoders", "average_precision"]

METHODS = presets.ENCODER_TEST_METHODS


@dataclass
class EncoderTest:
    """Settings of :func:`test_encoder` (``vpr encoders test``)."""

    encoder: str
    out: Path
    conf: dict = field(default_factory=dict)
    scenes: list = field(default_factory=render.builtin_specs)
    size: tuple = (160, 120)
    n_frames: int | None = None
    radius: float = 5.0

    def __post_init__(self):
        if not self.scenes:
            raise ValueError("scenes: need at least one scene")
        if self.n_frames is not None and int(self.n_frames) < 2:
            raise ValueError(f"frames: need at least 2 per traverse, got {self.n_frames}")
        if not self.radius > 0:
            raise ValueError(f"radius: must be > 0 metres, got {self.radius!r}")
        self.out = Path(self.out)
        self.size = (int(self.size[0]), int(self.size[1]))


def similarity(method: str, db_sdr: sp.csr_matrix, q_sdr: sp.csr_matrix):
    """db x query similarity of ``method`` on two SDR traverses."""
    names = list(range(max(db_sdr.shape[0], q_sdr.shape[0])))
    conf = methods.get_class(method).conf_for_sdrs({}, db_sdr.shape[1])  # the memory reads the encoder's width
    return methods.get(method, **conf).match(EncodedTraverse(names[: db_sdr.shape[0]], sdr=db_sdr),
                                     EncodedTraverse(names[: q_sdr.shape[0]], sdr=q_sdr)).similarity


def average_precision(S, gt_hard, gt_soft=None, mask=None) -> float:
    """AP over the evaluated pairs, NaN when no evaluated pair is a true match."""
    hard = gt_hard.toarray() if sp.issparse(gt_hard) else np.asarray(gt_hard, bool)
    if not (hard if mask is None else hard & np.asarray(mask, bool)).any():
        return float("nan")
    return evaluate.average_precision(S, gt_hard, gt_soft, mask=mask)


def list_encoders() -> dict:
    """Every registered encoder's name -> default conf (merged over its base classes, as the encoder does)."""
    out = {}
    for name in available():
        conf: dict = {}
        for cls in reversed(get_class(name).__mro__):
            conf.update(getattr(cls, "default_conf", {}) or {})
        out[name] = conf
    return out


def _encode(enc, images, fit: bool) -> sp.csr_matrix:
    """SDRs of one traverse; fitted on that traverse first when ``fit``."""
    if hasattr(enc, "encode_descriptors"):
        desc = enc.describe(images)  # describe once: fitting and encoding share the descriptors
        if fit:
            enc.fit_descriptors(desc)
        return enc.encode_descriptors(desc)
    return enc.fit(images).encode(images) if fit else enc.encode(images)


def _pairs(scene, radius: float) -> list[tuple]:
    """(db index, query index, gt_hard, gt_soft, mask) of every evaluated traverse pair of a scene."""
    trs = scene.traverses
    if len(trs) == 1:
        # loop closure against the own past, skipping frames of the same pass (as render.loop_pairs)
        tr = trs[0]
        hard = render.loop_pairs(tr, radius)
        excl = tr.loop_length / 2 if tr.loop_length else 10.0 * radius
        d = tr.route_pos
        mask = np.triu(np.abs(d[:, None] - d[None, :]) >= excl, k=1)
        return [(0, 0, hard, render.loop_pairs(tr, 2 * radius) | hard, mask)]
    return [(a, b, render.gt_matrix(trs[a], trs[b], radius), render.gt_matrix(trs[a], trs[b], 2 * radius), None)
            for a in range(len(trs)) for b in range(len(trs)) if a != b]


def score_encoder(cfg: EncoderTest, log=print) -> dict:
    """Render, encode and score every traverse pair of the scenes; return the document.

    Raises
    ------
    ValueError
        Unknown encoder, conf key or scene (the message names it).
    """
    enc = get(cfg.encoder, **cfg.conf)
    fit = enc.conf.get("standardise") == "fit"
    rows, seconds = [], {"encode": 0.0, **{m: 0.0 for m in METHODS}}
    for name in cfg.scenes:
        scene = render.render_scene(name, size=cfg.size, n_frames=cfg.n_frames)
        scene_name = scene.spec.get("name", str(name))
        t = time.perf_counter()
        sdrs = [_encode(enc, tr.images, fit) for tr in scene.traverses]
        seconds["encode"] += time.perf_counter() - t
        for a, b, hard, soft, mask in _pairs(scene, cfg.radius):
            row = {"scene": scene_name, "db": scene.traverses[a].name, "query": scene.traverses[b].name,
                   "n_db": sdrs[a].shape[0], "n_query": sdrs[b].shape[0]}
            for method in METHODS:
                if methods.get_class(method).follows_sequences and a == b:
                    row[method] = None  # a sequence memory matches two traverses, not one against itself
                    continue
                t = time.perf_counter()
                S = similarity(method, sdrs[a], sdrs[b])
                seconds[method] += time.perf_counter() - t
                row[method] = {"ap": average_precision(S, hard, soft, mask),
                               "recall_at_1": recall_at_k(S, hard, soft, k=1, mask=mask)}
            rows.append(row)
        log(f"  {scene_name}: {len(scene.traverses)} traverse(s), {len(rows)} pairs so far")
    doc = {"encoder": cfg.encoder, "conf": enc.conf, "fit_per_traverse": fit,
           "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(cfg).items()},
           "methods": list(METHODS), "rows": rows, "seconds": seconds}
    return doc
