"""Which loop closures of rSHOSM-seq to accept: the rule behind ``z_min`` and ``confirm``.

``vpr loops`` must report no false closure on a forward-only drive by default,
and still find revisits. This study scores every frame of rendered streams with
:func:`vpr.shosm.loop_evidence` (exclude 30 frames, 160x120, the scenes'
native frame counts at 5 fps) and counts, for each rule
:func:`vpr.shosm.accept_loops` (``z_min``, ``confirm``):

- forward-only drives, no place revisited: ``two_seasons`` summer_day and
  winter_night, ``speed_change`` slow and fast. An accepted closure at least 30
  frames back and more than 10 m away is false. The ``two_seasons`` world
  repeats a 40 m stretch 210 m later, identically (a built-in perceptual alias
  that no appearance can resolve while inside it): closures from the copy onto
  its source are counted apart ("onto the alias"), as are those of the
  ``aliased_corridor`` traverse (three identical 30 m stretches).
- ``loop_revisits`` (three laps): accepted closures within 5 m are true; the
  recall is over the frames that have an earlier frame within 5 m.
- optionally Nordland summer then winter as one stream (``--nordland DIR``, 358
  + 358 frames, true within 1 frame of the other traverse), and each whole
  Nordland traverse alone (3,576 frames, a forward-only train ride: any accepted
  closure more than 3 frames from its own frame is false; the train stands at
  stations, which :func:`vpr.shosm.stationary_closures` must tell from loops).

Worlds: the scenes' own (``spec``) and ``--select`` seeds choose the rule; the
``--confirm-seeds`` worlds were not looked at while choosing it.

Usage: python -m studies.loops_acceptance [--encoder fast|default] [--select spec,101]
       [--confirm-seeds 102,103] [--nordland DIR]
"""
from __future__ import annotations

import argparse

import numpy as np
import scipy.sparse as sp

import encoders
from vpr import presets
from vpr.shosm import accept_loops, loop_evidence

FORWARD = [("two_seasons", "summer_day"), ("two_seasons", "winter_night"), ("speed_change", "slow"),
           ("speed_change", "fast")]
ALIASED = [("aliased_corridor", "lights_on")]
REVISITS = [("loop_revisits", "laps")]
RULES = [(4.5, 0), (5.0, 0), (5.5, 0), (6.0, 0), (4.5, 2), (5.0, 2), (5.5, 2), (6.0, 2), (4.5, 4), (5.0, 4), (5.5, 4),
         (6.0, 4), (4.5, 8), (5.0, 8), (6.0, 8)]


def encoder_for(name: str):
    """The encoder of preset ``name`` with its loop conf (causal standardisation)."""
    s = presets.resolve(name, loops=True)
    return encoders.get(s["encoder"], **s["encoder_conf"])


def encode(enc, images) -> sp.csr_matrix:
    if enc.conf.get("standardise") == "fit":
        enc.fit(images)
    return sp.csr_matrix(enc.encode(images))


def rendered_stream(enc, scene: str, traverse: str, seed):
    """(loop matrix, distance in m between frames, pairs from an aliased copy onto its source) of one traverse."""
    from vpr.render import render_scene

    sc = render_scene(scene, size=(160, 120), traverses=[traverse], seed=seed)
    t = sc.traverses[0]
    x = encode(enc, list(t.images))
    S, _ = loop_evidence(x, exclude=30)
    pos = t.route_pos
    alias = np.zeros((len(pos), len(pos)), bool)
    for a in sc.spec["world"].get("aliasing", []):
        src = (pos >= a["source"] - 5) & (pos <= a["source"] + a["length"] + 5)
        dst = (pos >= a["target"] - 5) & (pos <= a["target"] + a["length"] + 5)
        shift = np.abs((pos[None] - pos[:, None]) - (a["target"] - a["source"])) <= 10
        alias |= src[:, None] & dst[None] & shift
    return S, np.linalg.norm(t.xy[:, None] - t.xy[None], axis=-1), alias, x


def nordland_stream(enc, path):
    """Nordland summer then winter (every 10th file) as one stream; distance = frames apart, or 99 in one traverse."""
    from pathlib import Path

    from vpr.sources import open_source

    frames = [[f.image for f in open_source(Path(path) / s, step=10)] for s in ("summer", "winter")]
    x = encode(enc, frames[0] + frames[1])
    S, _ = loop_evidence(x, exclude=30)
    pos = np.concatenate([np.arange(len(f)) for f in frames]).astype(float)
    trav = np.repeat([0, 1], [len(f) for f in frames])
    d = np.abs(pos[:, None] - pos[None])
    return S, np.where(trav[:, None] != trav[None], d, 99.0), np.zeros(d.shape, bool), x


def nordland_forward(enc, path, season):
    """One whole Nordland traverse (3,576 frames): a ride with stops at stations; distance = frames apart."""
    from pathlib import Path

    from vpr.sources import open_source

    x = encode(enc, [f.image for f in open_source(Path(path) / season)])
    S, _ = loop_evidence(x, exclude=30)
    idx = np.arange(x.shape[0], dtype=float)
    return S, np.abs(idx[:, None] - idx[None]), np.zeros((len(idx), len(idx)), bool), x


def count(S, d, alias, x, z_min, confirm, near, far, exclude=30, stop_ratio=0.35):
    """Accepted (false, onto an alias, true) and frames with a true closure, of one stream under one rule."""
    best, _, ok = accept_loops(S, z_min=z_min, confirm=confirm, sdr=x, stop_ratio=stop_ratio)
    T = len(best)
    back = np.arange(T) - best
    dist = d[np.maximum(best, 0), np.arange(T)]
    onto_alias = alias[np.maximum(best, 0), np.arange(T)]
    ok &= back >= exclude
    has = ((d <= near) & np.triu(np.ones((T, T), bool), exclude)).any(axis=0)
    false = ok & (dist > far)
    return (int((false & ~onto_alias).sum()), int((false & onto_alias).sum()), int((ok & (dist <= near)).sum()),
            int(has.sum()))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--encoder", default="fast", choices=presets.available(), help="preset whose loop encoder is used")
    ap.add_argument("--select", default="spec,101", help="worlds the rule was chosen on")
    ap.add_argument("--confirm-seeds", default="102", help="worlds held out from the choice")
    ap.add_argument("--nordland", default=None, help="the nordland_trimmed folder")
    ap.add_argument("--stop-ratio", type=float, default=0.35, help="vpr.shosm.stationary_closures (0: off)")
    a = ap.parse_args(argv)
    enc = encoder_for(a.encoder)
    print(f"encoder {enc.name} {enc.conf}")
    groups = {"select": a.select.split(","), "held out": a.confirm_seeds.split(",")}
    streams = {}
    for group, seeds in groups.items():
        for seed in seeds:
            s = None if seed == "spec" else int(seed)
            for kind, jobs in (("forward", FORWARD), ("aliased", ALIASED), ("revisits", REVISITS)):
                for scene, trav in jobs:
                    streams[(group, kind, f"{scene}/{trav}/{seed}")] = rendered_stream(enc, scene, trav, s)
    if a.nordland:
        streams[("real", "nordland", "nordland summer+winter")] = nordland_stream(enc, a.nordland)
        for season in ("summer", "winter"):
            streams[("real", "forward", season)] = nordland_forward(enc, a.nordland, season)
    print("| z_min | confirm | " + " | ".join(
        f"{g}: forward-only false (onto the alias) | {g}: corridor false | {g}: loop_revisits true / frames (false)"
        for g in groups) + (" | Nordland true / winter frames (false) | Nordland summer, winter alone (3,576 "
                             "frames each): false" if a.nordland else "") + " |")
    for z_min, confirm in RULES:
        cells = []
        for g in groups:
            tot = {"forward": [0] * 4, "aliased": [0] * 4, "revisits": [0] * 4}
            for (group, kind, _), (S, d, alias, x) in streams.items():
                if group == g:
                    c = count(S, d, alias, x, z_min, confirm, 5.0, 10.0, stop_ratio=a.stop_ratio)
                    tot[kind] = [x + y for x, y in zip(tot[kind], c, strict=True)]
            fw, al, rv = tot["forward"], tot["aliased"], tot["revisits"]
            cells += [f"{fw[0]} ({fw[1]})", str(al[0] + al[1]), f"{rv[2]} / {rv[3]} ({rv[0]})"]
        if a.nordland:
            f, _, t, n = count(*streams[("real", "nordland", "nordland summer+winter")], z_min, confirm, 1.0, 3.0,
                               stop_ratio=a.stop_ratio)
            cells.append(f"{t} / {n} ({f})")
            fw = [count(*streams[("real", "forward", s)], z_min, confirm, 1.0, 3.0, stop_ratio=a.stop_ratio)[0]
                  for s in ("summer", "winter")]
            cells.append(f"{fw[0]}, {fw[1]}")
        print(f"| {z_min} | {confirm} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
