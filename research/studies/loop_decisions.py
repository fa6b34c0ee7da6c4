"""How ``vpr loops`` decides, frame by frame, between a loop closure and a new place: the rule behind LoopConf.

Every stream of :mod:`research.studies.loop_streams` is encoded with the loop encoder
of the ``default`` and of the ``fast`` preset (``--presets``) and scored with
:func:`vpr.shosm.loop_evidence` (exclude 30 frames); :func:`vpr.shosm.accept_loops` then decides each frame under a grid
of :class:`vpr.shosm.LoopConf` (``drift``, ``min_score``). For each rule the
table gives, per revisit stream, the recall of the accepted closures (correct
accepted closures over the frames that have a true loop) and how many accepted
closures are false; for the forward-only drives the number of accepted (all
false) closures, those onto an identical copy of a stretch counted apart.

The rule is chosen as: no false closure anywhere but onto identical copies
(which no appearance can tell from a revisit while the camera is inside them),
on the streams of every preset; then the best recalls over the revisit
streams, weakest first (the smallest recall decides, the next breaks ties). ``--leave-one-out``
repeats the choice without each stream in turn and prints what the rule chosen
without it does on it: a rule that only holds where it was chosen shows there.

``--sizes``: the rendered streams also at other sizes, each a stream of its own.

Closures are confirmed by the frames after them as ``vpr loops`` does (``LoopConf.confirm_frames``,
``--confirm-frames``, 0: decided at once), the frames leading up to a confirmed closure accepted with it
(``LoopConf.backfill_frames``, ``--backfill-frames``; ``--backfill-grid`` prints every stream under each of
:data:`BACKFILL_FRAMES`); ``--confirm-grid`` prints, for the default rule, every stream under
each ``confirm_frames`` x ``confirm_z`` of :data:`CONFIRM_FRAMES` x :data:`CONFIRM_Z` (with ``research.studies.run_on``,
where a revisit leaves the earlier route, the streams the confirmation was chosen on).

Usage: python -m research.studies.loop_decisions [--cache DIR] [--data DIR] [--presets default,fast] [--leave-one-out]
       [--decay D] [--sizes 160x120,320x240] [--confirm-frames N] [--backfill-frames N]
       [--confirm-grid] [--backfill-grid]
"""
from __future__ import annotations

import argparse
import itertools
import time
from pathlib import Path

import numpy as np

from research.studies import loop_streams
from research.studies.loop_streams import FORWARD, REAL_REVISITS, RENDERED_REVISITS, load_stream
from vpr.shosm import (
    Backfill,
    LoopConf,
    LoopEvidence,
    accept_loops,
    backfill_closures,
    confirm_closures,
    loop_evidence,
)
from vpr.types import Decision

DRIFTS = (1.0, 1.25, 1.5, 1.75)
SCORES = (16.0, 20.0, 24.0, 28.0, 32.0, 40.0)
REVISITS = (*REAL_REVISITS, *RENDERED_REVISITS)
CONFIRM_FRAMES = (0, 10, 20, 30)
CONFIRM_Z = (2.0, 2.5, 3.0)
#: the back-fill windows ``--backfill-grid`` prints
BACKFILL_FRAMES = (0, 10, 20, 30, 40, 60, 80)
EXCLUDE = 30


def evidence(stream, cache: Path, preset: str = "default", decay: float | None = None) -> LoopEvidence:
    """The stream's loop evidence (cached: it takes minutes on the whole Nordland rides); ``decay``: another
    than the conf's default."""
    path = cache / (f"evidence-{stream.name.replace('/', '-')}{'' if preset == 'default' else '-' + preset}"
                    f"{'' if decay is None else f'-decay{decay:g}'}.npz")
    if path.is_file():
        with np.load(path) as z:
            return LoopEvidence(z["S"], None, None, z["fill"], int(z["exclude"]))
    ev = loop_evidence(stream.x, exclude=EXCLUDE, **({} if decay is None else {"decay": decay}))
    np.savez(path, S=ev.similarity, fill=ev.fill, exclude=ev.exclude)
    return ev


def aliases(name: str) -> np.ndarray | None:
    """(T x T bool) pairs of a rendered stream that see an identical copy of each other, or None: both frames have
    the copied stretch ahead in view (or just passed it) and lie at the copy's offset, within 10 m."""
    if "/" not in name:
        return None
    from vpr.render import render_scene

    scene, traverse = name.split("/")
    sc = render_scene(scene, size=(32, 24), traverses=[traverse])
    pos = sc.traverses[0].route_pos
    out = np.zeros((len(pos), len(pos)), bool)
    regions: dict = {}
    view = float(sc.spec["camera"]["max_depth"])  # the camera sees a stretch from this far ahead
    for a in sc.spec["world"].get("aliasing", []):
        regions.setdefault((a["source"], a["length"]), [a["source"]]).append(a["target"])
    for (_, length), starts in regions.items():
        for s1, s2 in itertools.permutations(starts, 2):
            # the copy in view (ahead of the camera, up to what it sees) and the evidence's tail after it (decay
            # 0.9: about 10 frames, 20 m here); the pair at the copy's offset (the same view of it)
            r1 = (pos >= s1 - view) & (pos <= s1 + length + 20)
            r2 = (pos >= s2 - view) & (pos <= s2 + length + 20)
            out |= r1[:, None] & r2[None] & (np.abs(pos[None] - pos[:, None] - (s2 - s1)) <= 10)
    return out


def confirmed(stream, ev, conf: LoopConf):
    """The stream's decisions under ``conf``'s path rule, its closures confirmed by the frames after them
    (``conf.confirm_frames``; the frames' standardised overlaps kept on the stream)."""
    d = accept_loops(ev, conf, sdr=stream.x)
    if not conf.confirm_frames:
        return d
    return confirm_closures(d, stream.x, EXCLUDE, conf.as_dict(), scored=stream.scored)


def decide(stream, ev, conf: LoopConf):
    """The stream's decisions under ``conf`` as ``vpr loops`` takes them: :func:`confirmed`, the frames leading up
    to a confirmed closure accepted with it (``conf.backfill_frames``)."""
    d = confirmed(stream, ev, conf)
    if conf.backfill_frames:
        d = backfill_closures(d, conf.backfill_frames, conf.back, conf.ahead, conf.min_score)
    return d


def backfill_waits(stream, ev, conf: LoopConf) -> np.ndarray:
    """Per frame, how many frames its decision waits online in :class:`vpr.shosm.Backfill` (after the
    confirmation; 0: it leaves at once)."""
    d = confirmed(stream, ev, conf)
    b, T = Backfill(conf.backfill_frames, conf.back, conf.ahead, conf.min_score), len(d.best)
    wait = np.zeros(T, np.int64)
    for j in range(T):
        for o in b.push([Decision(int(d.best[j]), float(d.score[j]), bool(d.accepted[j]), 0.0, j)]):
            wait[o.frame] = j - o.frame
    for o in b.flush():
        wait[o.frame] = T - o.frame
    return wait


def count(stream, ev, alias, conf: LoopConf) -> dict:
    """Accepted closures of one stream under one rule: correct, false, onto a copy; frames with a loop."""
    d = decide(stream, ev, conf)
    j = np.flatnonzero(d.accepted)
    b = d.best[j]
    if stream.forward_only:
        on_copy = alias[b, j] if alias is not None else np.zeros(j.size, bool)
        return {"true": 0, "false": int((~on_copy).sum()), "copy": int(on_copy.sum()), "frames": 0}
    true = stream.hard[b, j]
    soft = stream.soft[b, j] & ~true
    frames = int(np.triu(stream.hard, EXCLUDE).any(axis=0).sum())
    return {"true": int(true.sum()), "false": int((~true & ~soft).sum()), "copy": 0, "frames": frames}


def _stream_of(key: str) -> str:
    """The stream name of a result key (``"fast: gardens_point"``, ``"gardens_point"``, a render at another size
    ``"loop_revisits/laps@320x240"``)."""
    return key.split(": ")[-1].split("@")[0]


def choose(results: dict, streams: list[str]):
    """The rule with no false closure (but onto copies) on ``streams`` whose recalls are best, weakest first.

    Rules are compared on their revisit recalls sorted from the smallest up
    (leximin): the weakest stream decides, the next weakest breaks ties, and
    so on; then the larger ``min_score`` (the safer rule).
    """
    best, best_key = None, None
    for rule, per in results.items():
        if any(per[s]["false"] for s in streams):
            continue
        recalls = sorted(round(per[s]["true"] / per[s]["frames"], 2) for s in streams if _stream_of(s) in REVISITS)
        key = (recalls, rule[1])
        if best_key is None or key > best_key:
            best, best_key = rule, key
    return best


def stream_cells(per: dict, names) -> str:
    """Each stream's cell: a revisit stream's recall (false closures), a forward drive's false (+ onto a copy)."""
    out = []
    for s in names:
        c = per[s]
        if _stream_of(s) in REVISITS:
            out.append(f"{c['true'] / c['frames']:.2f} ({c['false']})")
        else:
            out.append(f"{c['false']}" + (f" (+{c['copy']})" if c["copy"] else ""))
    return " | ".join(out)


def row(rule, per: dict, names) -> str:
    return f"| {rule[0]} | {rule[1]:g} | {stream_cells(per, names)} |"


def report(stream, ev, alias, conf: LoopConf) -> dict:
    """What ``vpr loops`` reports for one stream under ``conf``: R@1, accepted closures, their precision and
    recall, and the recall at 100 % precision of the per-frame decisions (:func:`vpr.evaluate.decision_curve`)."""
    from vpr.evaluate import decision_curve
    from vpr.groundtruth import loop_closure_mask

    d = decide(stream, ev, conf)
    c = count(stream, ev, alias, conf)
    out = {"frames": len(stream), "accepted": int(d.accepted.sum()), "false": c["false"], "copy": c["copy"]}
    if stream.forward_only:
        return out
    T = len(stream)
    mask = loop_closure_mask(T, EXCLUDE)
    j = np.flatnonzero((stream.hard & mask).any(axis=0))
    b = d.best[j]
    dm, _ = decision_curve(d.best, d.score, stream.hard, stream.soft, mask)
    out.update(with_loop=int(j.size), r1=float(np.mean((b >= 0) & stream.hard[np.maximum(b, 0), j])),
               precision=(c["true"] / (c["true"] + c["false"])) if c["true"] + c["false"] else None,
               recall=c["true"] / j.size, r100p=dm["recall_at_100p"])
    return out


def _held_cell(stream: str, c: dict | None) -> str:
    """What the rule chosen without ``stream`` does on it."""
    if c is None:
        return "-"
    if _stream_of(stream) in REVISITS:
        return f"recall {c['true'] / c['frames']:.2f}, {c['false']} false"
    return f"{c['false']} false" + (f" (+{c['copy']} onto a copy)" if c["copy"] else "")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", default="results/loop_streams", help="encodings and evidence are cached here")
    ap.add_argument("--data", default=None, help="datasets folder (default: $VPR_DATASETS or ../shared/datasets)")
    ap.add_argument("--presets", default="default,fast", help="presets whose loop encoders are used")
    ap.add_argument("--leave-one-out", action="store_true", help="choose without each stream, check it")
    ap.add_argument("--decay", type=float, default=None,
                    help="the evidence's decay per frame (default: rshosm-seq's), e.g. 0.95 for a longer memory")
    ap.add_argument("--confirm-frames", type=int, default=LoopConf().confirm_frames,
                    help="frames after a closure that confirm it (default: LoopConf's; 0: decided at once)")
    ap.add_argument("--backfill-frames", type=int, default=LoopConf().backfill_frames,
                    help="frames before a confirmed closure accepted with it (default: LoopConf's; 0: none)")
    ap.add_argument("--backfill-grid", action="store_true",
                    help="the default rule under every backfill_frames of the grid, each stream's recall to 3 places")
    ap.add_argument("--confirm-grid", action="store_true",
                    help="the default rule under every confirm_frames x confirm_z of the grid")
    ap.add_argument("--sizes", default="160x120",
                    help="the sizes the rendered streams are rendered at, each a stream of its own (the first unnamed)")
    a = ap.parse_args(argv)
    cache = Path(a.cache)
    cache.mkdir(parents=True, exist_ok=True)
    presets = [p.strip() for p in a.presets.split(",") if p.strip()]
    names, data, copies = [], {}, {}
    for k, size in enumerate(a.sizes.lower().split(",")):
        loop_streams.RENDER_SIZE = tuple(int(v) for v in size.split("x"))
        at = cache if k == 0 else cache.with_name(f"{cache.name}_{size}")
        at.mkdir(parents=True, exist_ok=True)
        for preset in presets:
            for n in [*REVISITS, *FORWARD]:
                if k and "/" not in n:  # the real streams have their own size
                    continue
                t = time.perf_counter()
                s = load_stream(n, preset=preset, cache=at, data=a.data)
                if n not in copies:
                    copies[n] = aliases(n)
                key = (n if len(presets) == 1 else f"{preset}: {n}") + ("" if k == 0 else f"@{size}")
                names.append(key)
                data[key] = (s, evidence(s, at, preset, a.decay), copies[n])
                print(f"{key}: {len(s)} frames ({time.perf_counter() - t:.0f} s)", flush=True)
    results = {}
    for rule in itertools.product(DRIFTS, SCORES):
        conf = LoopConf(drift=rule[0], min_score=rule[1], confirm_frames=a.confirm_frames,
                        backfill_frames=a.backfill_frames)
        results[rule] = {n: count(*data[n], conf) for n in names}
    print("\nRevisit streams: recall of the accepted closures (false accepted); forward-only drives: false "
          "closures (+ onto an identical copy).\n")
    print("| drift | min_score | " + " | ".join(names) + " |")
    print("|---|---|" + "---|" * len(names))
    for rule, per in results.items():
        print(row(rule, per, names))
    chosen = choose(results, names)
    print(f"\nchosen on every stream: drift {chosen[0]}, min_score {chosen[1]:g}" if chosen else "\nno rule qualifies")
    conf = LoopConf(confirm_frames=a.confirm_frames, backfill_frames=a.backfill_frames)
    print(f"\nWith the defaults (LoopConf: drift {conf.drift}, min_score {conf.min_score:g}), what `vpr loops` reports "
          "(R@100P: recall at 100 % precision of the per-frame decisions; accepted closures onto an identical copy "
          "in brackets):\n")
    print("| stream | frames | frames with a loop | R@1 | accepted | precision of accepted | recall of accepted | "
          "R@100P | false closures |")
    print("|---|---|---|---|---|---|---|---|---|")
    for n in names:
        r = report(*data[n], conf)
        if "with_loop" in r:
            prec = "-" if r["precision"] is None else f"{r['precision']:.2f}"
            print(f"| {n} | {r['frames']:,} | {r['with_loop']:,} | {r['r1']:.2f} | {r['accepted']} | {prec} | "
                  f"{r['recall']:.2f} | {r['r100p']:.2f} | {r['false']} |")
        else:
            print(f"| {n} | {r['frames']:,} | forward only | - | {r['accepted']} | - | - | - | {r['false']}"
                  + (f" (+{r['copy']})" if r["copy"] else "") + " |")
    if a.confirm_grid:
        print("\nThe default rule, its closures confirmed by the frames after them (confirm_frames, confirm_z; 0: "
              "decided at once): revisit streams' recall (false), forward drives' false (+ onto a copy)\n")
        print("| confirm_frames | confirm_z | " + " | ".join(names) + " |")
        print("|---|---|" + "---|" * len(names))
        for frames, z in [(0, None), *itertools.product(CONFIRM_FRAMES[1:], CONFIRM_Z)]:
            conf = LoopConf(confirm_frames=frames, backfill_frames=a.backfill_frames,
                            **({} if z is None else {"confirm_z": z}))
            per = {n: count(*data[n], conf) for n in names}
            print(f"| {frames} | {'-' if z is None else f'{z:g}'} | {stream_cells(per, names)} |", flush=True)
    if a.backfill_grid:
        print("\nThe default rule, the frames leading up to a confirmed closure accepted with it (backfill_frames): "
              "revisit streams' recall (false), forward drives' false (+ onto a copy)\n")
        print("| backfill_frames | " + " | ".join(names) + " |")
        print("|---|" + "---|" * len(names))
        for frames in BACKFILL_FRAMES:
            conf = LoopConf(confirm_frames=a.confirm_frames, backfill_frames=frames)
            per = {n: count(*data[n], conf) for n in names}
            cells = [f"{per[n]['true'] / per[n]['frames']:.3f} ({per[n]['false']})" if _stream_of(n) in REVISITS
                     else f"{per[n]['false']}" + (f" (+{per[n]['copy']})" if per[n]["copy"] else "") for n in names]
            print(f"| {frames} | {' | '.join(cells)} |", flush=True)
        conf = LoopConf(confirm_frames=a.confirm_frames, backfill_frames=a.backfill_frames)
        print(f"\nWhat waits for a later closure online (backfill_frames {conf.backfill_frames}, after the "
              "confirmation): the share of frames that wait, the median wait of those, the longest (frames)\n")
        print("| stream | waiting | median | longest |")
        print("|---|---|---|---|")
        for n in names:
            w = backfill_waits(*data[n][:2], conf)
            print(f"| {n} | {np.mean(w > 0):.2f} | {np.median(w[w > 0]) if (w > 0).any() else 0:g} | {w.max()} |")
    if a.leave_one_out:
        print("\n| held out (every preset's) | rule chosen without it | on the held-out stream |")
        print("|---|---|---|")
        for n in [*REVISITS, *FORWARD]:
            held = [k for k in names if _stream_of(k) == n]
            rule = choose(results, [m for m in names if m not in held])
            cells = []
            for k in held:
                preset = k.split(": ")[0] if ": " in k else ""
                cells.append(f"{preset} {_held_cell(n, results[rule][k] if rule else None)}".strip())
            chosen_without = f"drift {rule[0]}, min_score {rule[1]:g}" if rule else "none"
            print(f"| {n} | {chosen_without} | {'; '.join(cells) if rule else '-'} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
