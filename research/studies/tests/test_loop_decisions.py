import numpy as np

from research.studies.loop_decisions import choose, count
from research.studies.loop_streams import Stream
from vpr import sdr
from vpr.shosm import LoopConf, LoopEvidence


def _stream(forward: bool):
    """A 50-frame stream whose frames 40-42 revisit 0-2 and 30-32 look exactly like 10-12 (a copy)."""
    T = 50
    S = np.full((T, T), -np.inf, np.float32)
    i, j = np.indices((T, T))
    S[i <= j - 5] = 0.0
    for q, b in ((30, 10), (31, 11), (32, 12), (40, 0), (41, 1), (42, 2), (20, 5)):
        S[b, q] = 9.0
    hard = np.zeros((T, T), bool)
    hard[0:3, 40:43] = True
    alias = np.zeros((T, T), bool)
    alias[10:13, 30:33] = True
    x = sdr.random_sdrs(T, 256, 20, seed=0)  # every frame unlike the others: no stop
    stream = Stream("toy", x, None if forward else hard, None if forward else hard.copy())
    return stream, LoopEvidence(S, None, None, np.zeros(T, np.float32), 5), alias


def test_count_splits_false_copy_and_true_closures():
    # one frame standing out by 9 is accepted (decided at once: the toy's SDRs are random)
    conf = LoopConf(drift=1.0, min_score=8.0, island=5.0, confirm_frames=0)
    s, ev, alias = _stream(forward=True)
    assert count(s, ev, alias, conf) == {"true": 0, "false": 4, "copy": 3, "frames": 0}
    s, ev, _ = _stream(forward=False)
    assert count(s, ev, None, conf) == {"true": 3, "false": 4, "copy": 0, "frames": 3}
    # a path must build up: with min_score 20 only the third frame of each run (score 24) is accepted, and the
    # frames that led up to it on its path with it
    build = {"drift": 1.0, "min_score": 20.0, "island": 5.0, "confirm_frames": 0}
    assert count(s, ev, None, LoopConf(**build, backfill_frames=0))["true"] == 1
    assert count(s, ev, None, LoopConf(**build))["true"] == 3


def test_choose_takes_the_rule_without_false_closures_and_the_best_worst_recall():
    results = {(1.0, 10.0): {"gardens_point": {"true": 9, "false": 1, "frames": 10}},
               (1.5, 10.0): {"gardens_point": {"true": 7, "false": 0, "frames": 10}},
               (1.5, 20.0): {"gardens_point": {"true": 6, "false": 0, "frames": 10}}}
    assert choose(results, ["gardens_point"]) == (1.5, 10.0)


def test_choose_breaks_ties_of_the_weakest_stream_on_the_next_weakest():
    per = {"a": {"true": 0, "false": 0, "frames": 10}}
    results = {(1.0, 20.0): {**per, "gardens_point": {"true": 60, "false": 0, "frames": 100}},
               (1.5, 20.0): {**per, "gardens_point": {"true": 67, "false": 0, "frames": 100}},
               (2.0, 20.0): {**per, "gardens_point": {"true": 90, "false": 2, "frames": 100}}}
    renamed = {r: {("fast: gardens_point" if k == "a" else k): v for k, v in p.items()} for r, p in results.items()}
    assert choose(renamed, list(renamed[(1.0, 20.0)])) == (1.5, 20.0)
