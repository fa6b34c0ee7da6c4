"""Loop closure with rSHOSM-seq sequence evidence (vpr.shosm.loop_evidence) against SeqSLAM.

Streams: the paper's simulated loops; the rendered two_seasons route driven by
day then by night as one stream; rendered forward-only drives (no place is
revisited, so every accepted closure at least 30 frames back is false): the
two_seasons day traverse (its world repeats a 40 m stretch 210 m later, a
built-in perceptual alias) and the speed_change slow traverse (with stops);
optionally Nordland summer then winter (358 frames each, ``--nordland DIR``: the
``nordland_trimmed`` folder, every 10th file).

Loop AP: sklearn average precision over the pairs i <= j - exclude (soft pairs ignored).

Usage: python -m research.studies.loops_evidence [--frames 150] [--size 96x72] [--nordland DIR]
       [--standardise traverse|fit|causal] [--skip-paper]
       python -m research.studies.loops_evidence --cross-condition 160x120
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.sparse as sp

import encoders
from vpr import evaluate, groundtruth, methods, simulate
from vpr.shosm import EvidenceConf, loop_evidence
from vpr.types import EncodedTraverse


def loop_ap(S, gt, exclude, soft=None):
    """AP over the loop-closure pairs i <= j - exclude (soft-only pairs ignored)."""
    return evaluate.average_precision(S, gt, soft, mask=groundtruth.loop_closure_mask(S.shape[0], exclude=exclude))


def run(name, sdr, pixels, gt, exclude, soft=None, forward_only=False, **kw):
    t = time.perf_counter()
    ev = loop_evidence(sdr, exclude=exclude, conf=EvidenceConf(**kw))
    S = ev.similarity
    t_ev = time.perf_counter() - t
    f = EncodedTraverse(names=list(range(sdr.shape[0])), sdr=sdr, pixels=pixels,
                         desc=None if pixels is not None else sdr.toarray().astype(np.float32))
    conf = {} if pixels is not None else {"descriptor": "desc"}
    r = methods.loops("seqslam", f, exclude=exclude, conf=conf)
    d = ev.decision  # the default LoopConf, decided as the stream went (vpr loops)
    best, score, ok = d.best, d.score, d.accepted
    T = sdr.shape[0]
    far = ok & (np.arange(T) - best >= 30)
    line = f"{name:34s} T={T:4d} exclude={exclude:3d}"
    if gt is not None and gt.any():
        ap_s, ap_q = loop_ap(S, gt, exclude, soft), loop_ap(r.similarity, gt, exclude, soft)
        line += f"  AP rshosm-seq {ap_s:.3f}  seqslam {ap_q:.3f}"
    tp = ok & (gt[np.maximum(best, 0), np.arange(T)] if gt is not None else False)
    line += f"  accepted {int(ok.sum())} (>=30 back {int(far.sum())}, true {int(np.sum(tp))})"
    line += f"  seqslam accepted >=30 back {int((r.accepted & (np.arange(T) - r.best >= 30)).sum())}"
    line += f"  max path score {score.max():.1f}  {t_ev:.1f}s"
    print(line, flush=True)


def encode_stream(traverses, standardise="traverse"):
    """SDRs of the traverses as one stream: pixel encoder k=200, standardised per traverse (an oracle that knows
    where the condition changes), on the whole stream (``fit``), or causally (a sliding window, ``causal``)."""
    if standardise == "traverse":
        enc = encoders.get("pixel", k=200, standardise="fit")
        return sp.vstack([enc.fit(t).encode(t) for t in traverses]).tocsr()
    images = [im for t in traverses for im in t]
    enc = encoders.get("pixel", k=200, standardise=standardise)
    if standardise == "fit":
        enc.fit(images)
    return sp.csr_matrix(enc.encode(images))


def rendered(frames, size, exclude, forward_only=False, scene="two_seasons", standardise="traverse"):
    from vpr.render import render_scene

    scene = render_scene(scene, size=size, n_frames=frames)
    trs = scene.traverses[:1] if forward_only else scene.traverses
    images = np.concatenate([t.images for t in trs])
    xy = np.concatenate([t.xy for t in trs])
    trav = np.concatenate([np.full(len(t.images), k) for k, t in enumerate(trs)])
    sdr = encode_stream([list(t.images) for t in trs], standardise)
    from vpr import imageproc

    pixels = np.stack([imageproc.seqslam_preprocess(im).ravel() for im in images]).astype(np.float32)
    d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    gt = (d <= 4.0) & (trav[:, None] != trav[None])
    soft = (d <= 10.0) & (trav[:, None] != trav[None])
    return sdr, pixels, gt, soft


def nordland(path, exclude, standardise="traverse"):
    from pathlib import Path

    from vpr import imageproc
    from vpr.sources import open_source

    seasons, pix = [], []
    for season in ("summer", "winter"):
        images = [f.image for f in open_source(Path(path) / season, step=10)]
        seasons.append(images)
        pix.append(np.stack([imageproc.seqslam_preprocess(im).ravel() for im in images]))
    n = [len(t) for t in seasons]
    sdr = encode_stream(seasons, standardise)
    pos = np.concatenate([np.arange(k) for k in n])
    trav = np.repeat([0, 1], n)
    d = np.abs(pos[:, None] - pos[None])
    other = trav[:, None] != trav[None]
    return sdr, np.concatenate(pix).astype(np.float32), (d <= 1) & other, (d <= 3) & other


def cross_condition(size):
    """Why the rendered day + night stream fails: how well night frames match day frames at all.

    Prints, for two_seasons at ``size`` with the scenes' native frame counts: the
    loop stream with the ``default`` loop encoder (loop AP; AP and R@1 when only
    the day frames are candidates for the night frames, so no night frame can
    compete), and the two traverses matched as database (day) and query (night),
    each standardised on its own frames, with forward (causal) and both-direction
    rSHOSM-seq evidence, per encoder.
    """
    from vpr import presets
    from vpr.render import render_scene

    day, night = render_scene("two_seasons", size=size).traverses
    T, nd = len(day.images) + len(night.images), len(day.images)
    s = presets.resolve("default", loops=True)
    x = sp.csr_matrix(encoders.get(s["encoder"], **s["encoder_conf"]).encode(list(day.images) + list(night.images)))
    xy = np.concatenate([day.xy, night.xy])
    trav = np.repeat([0, 1], [nd, T - nd])
    d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    other = trav[:, None] != trav[None]
    gt, soft = (d <= 4.0) & other, (d <= 10.0) & other
    S, _ = loop_evidence(x, exclude=30)
    cross = np.zeros((T, T), bool)
    cross[:nd, nd:] = True
    mask = groundtruth.loop_closure_mask(T, exclude=30)
    best_day = np.argmax(S[:nd, nd:], axis=0)
    print(f"two_seasons day+night stream {size}: loop AP {loop_ap(S, gt, 30, soft):.3f}; day frames only as "
          f"candidates: AP {evaluate.average_precision(S, gt, soft, mask=mask & cross):.3f}, "
          f"R@1 {np.mean(gt[best_day, np.arange(nd, T)]):.3f}", flush=True)
    dq = np.linalg.norm(day.xy[:, None] - night.xy[None], axis=-1)
    for name, (enc, conf) in {
        "pixel k=200": ("pixel", {"k": 200}),
        "HOG k=200": ("projection", {"k": 200, "descriptor": "hog"}),
        "cnn k=200": ("cnn", {"k": 200}),
        "default (pixel+cnn)": (presets.PRESETS["default"]["encoder"], presets.PRESETS["default"]["encoder_conf"]),
    }.items():
        e = encoders.get(enc, **{**conf, "standardise": "fit"})
        db, q = (EncodedTraverse(names=list(range(len(t.images))), sdr=e.fit(list(t.images)).encode(
            list(t.images))) for t in (day, night))
        aps = [evaluate.average_precision(methods.get("rshosm-seq", direction=dr).match(db, q).similarity,
                                          dq <= 4.0, dq <= 10.0) for dr in ("forward", "both")]
        print(f"  day -> night as two traverses, {name}: rshosm-seq AP forward {aps[0]:.3f}, both {aps[1]:.3f}",
              flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--size", default="96x72")
    ap.add_argument("--exclude", type=int, default=30)
    ap.add_argument("--nordland", default=None)
    ap.add_argument("--skip-paper", action="store_true")
    ap.add_argument("--cross-condition", default=None, metavar="WxH",
                    help="only: how well night matches day on two_seasons at this size (e.g. 160x120)")
    ap.add_argument("--standardise", choices=("traverse", "fit", "causal"), default="traverse",
                    help="two-traverse streams: fit per traverse (oracle), on the whole stream, or causal")
    a = ap.parse_args(argv)
    if a.cross_condition:
        cross_condition(tuple(int(v) for v in a.cross_condition.split("x")))
        return
    size = tuple(int(v) for v in a.size.split("x"))
    rule: dict = {}
    for alias, noise in ((0, 0.0), (5, 0.3), (10, 0.5)) if not a.skip_paper else ():
        obs, traj = simulate.simulate_loops(aliasing=alias, noise=noise, seed=0)
        gt = traj[:, None] == traj[None]
        for kw in ({}, {"stay": None, "skip": None}):
            run(f"paper loops a={alias} n={noise} {kw or ''}", obs, None, gt, 10, **rule, **kw)
    sdr, pixels, gt, soft = rendered(a.frames, size, a.exclude, standardise=a.standardise)
    run(f"rendered two_seasons day+night ({a.standardise})", sdr, pixels, gt, a.exclude, soft, **rule)
    sdr, pixels, gt, soft = rendered(a.frames, size, a.exclude, forward_only=True)
    run("forward-only two_seasons day", sdr, pixels, gt, a.exclude, soft, **rule)
    sdr, pixels, gt, soft = rendered(a.frames, size, a.exclude, forward_only=True, scene="speed_change")
    run("forward-only speed_change slow", sdr, pixels, gt, a.exclude, soft, **rule)
    if a.nordland:
        sdr, pixels, gt, soft = nordland(a.nordland, a.exclude, a.standardise)
        run(f"nordland summer+winter 358 ({a.standardise})", sdr, pixels, gt, a.exclude, soft, **rule)


if __name__ == "__main__":
    main()
