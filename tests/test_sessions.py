"""Sessions: a robot's runs joined into one stream without a seam between them.

At a session start what was learned stays (later runs close loops onto earlier
ones) and nothing of the last run's last moment carries over: the memory's
context, the beam's evidence, the decision's path. ``exclude`` holds within a
session. The batch (``loop_evidence``, ``vpr loops S1 S2``) and the online
detector (``new_session``, a ``#session`` line on stdin) give the same answers.
"""
import csv
import json
import shutil

import numpy as np
import pytest
import scipy.sparse as sp

from pipelines.cli import main
from vpr import evaluate, sdr
from vpr.groundtruth import loop_closure_mask
from vpr.shosm import LoopDecider, LoopDetector, LoopStream, RshosmSeqConf, loop_evidence
from vpr.similarity import candidate_limit, mask_recent
from vpr.types import Column


def _stream(seed=0):
    """Session 1: 80 places; session 2: a noisy revisit of them."""
    places = sdr.random_sdrs(80, 1024, 40, seed=seed)
    return sp.vstack([places, sdr.add_noise(places, 0.2, seed=seed + 1)]).tocsr()


LOOSE = {"min_score": 6.0, "drift": 0.5, "n_inputs": 1024}


def test_candidates_hold_exclude_within_a_session_only():
    n = candidate_limit(10, 3, starts=[0, 6])
    assert n.tolist() == [0, 0, 0, 1, 2, 3, 6, 6, 6, 7]  # frames 6..8 see all of session 1
    m = loop_closure_mask(10, 3, starts=[0, 6])
    assert m[:6, 6].all() and not m[6:, 6].any() and m[6, 9] and not m[7, 9]
    S = mask_recent(np.ones((10, 10)), 3, starts=[0, 6])
    assert np.isfinite(S[5, 6]) and np.isinf(S[6, 7])


def test_a_path_does_not_move_on_across_a_session_boundary():
    def run(new_sessions):
        d = LoopDecider(RshosmSeqConf.build({"drift": 0.5, "min_score": 1e9}).loop(), n_bits=256, capacity=400)
        scores = []
        for j in range(260):
            if j in new_sessions:
                d.new_session()
            if j < 200:
                scores.append(d.decide(Column(np.zeros(0, np.int64), np.zeros(0, np.float32), 0.0, 0, j)).score)
                continue
            b = 90 + (j - 200)  # the best earlier frame walks from session 1 (..99) into session 2 (100..)
            rows = np.arange(200, dtype=np.int64)
            vals = np.where(rows == b, 5.0, 0.0).astype(np.float32)
            scores.append(d.decide(Column(rows, vals, 0.0, 200, j)).score)
        return np.array(scores)

    joined, sessions = run(()), run((100, 200))
    assert joined[215] > joined[205] > 0  # one stream: 99 -> 100 is "moving on"
    assert sessions[209] > 0 and sessions[210] == pytest.approx(4.5)  # a new path at frame 100, the next session


def test_batch_sessions_equal_the_online_detector_and_close_loops_onto_the_first_session():
    x = _stream()
    batch = loop_evidence(x, exclude=30, sessions=[80], **LOOSE)
    det = LoopDetector(exclude=30, **LOOSE)
    out = []
    for j in range(x.shape[0]):
        if j == 80:
            det.new_session()  # the first session's waiting closures are decided here
        d = det.update(x[j])
        out.extend([*det.take_late(), *([] if d is None else [d])])
    det.flush()
    out.extend(det.take_late())
    assert [r.frame for r in out] == list(range(x.shape[0]))
    d = batch.decision
    np.testing.assert_array_equal([r.best for r in out], d.best)
    np.testing.assert_array_equal([r.accepted for r in out], d.accepted)
    assert batch.starts == (0, 80)
    # every frame of session 2 may close onto session 1, also the first ones (exclude holds within a session)
    assert d.best[80] >= 0 and d.accepted[85:].mean() > 0.8
    right = np.abs(d.best[80:] - np.arange(80)) <= 1
    assert right[d.accepted[80:]].all()


def test_the_seam_is_not_learned():
    """The first frame of a session is nobody's successor: the last frame of the run before predicts nothing of it."""
    x = _stream()
    seq = RshosmSeqConf.build(LOOSE)
    joined, split = LoopStream(30, seq), LoopStream(30, seq)
    for j in range(81):
        if j == 80:
            split.new_session()
        joined.step(x[j])
        split.step(x[j])
    assert joined.mem.n_connections > split.mem.n_connections  # the seam 79 -> 80 is learned only when joined


def test_session_pairs_report_which_session_revisits_which():
    gt = np.zeros((6, 6), bool)
    gt[0, 3] = gt[3, 0] = gt[1, 4] = gt[4, 1] = True
    best = np.array([-1, -1, -1, 0, 2, -1])
    acc = np.array([False, False, False, True, True, False])
    pairs = evaluate.session_pairs(best, acc, gt, [0, 3], names=["a", "b"])
    by = {(p["session"], p["onto"]): p for p in pairs}
    assert by[("b", "a")] == {"session": "b", "onto": "a", "frames": 2, "accepted": 2, "precision": 0.5,
                              "recall": 0.5}
    assert by[("a", "a")]["precision"] is None and by[("b", "b")]["accepted"] == 0


@pytest.mark.slow
def test_vpr_loops_of_two_sessions_closes_across_them(scene_on_disk, tmp_path, capsys, monkeypatch):
    import io

    s = scene_on_disk("loop_revisits", (48, 36), 240)
    with open(s["gt"]) as fh:
        rows = {int(r["frame"]): (float(r["x"]), float(r["y"])) for r in csv.DictReader(fh) if r["traverse"] == "laps"}
    frames = sorted(s["laps"].glob("*.png"))
    half = len(frames) // 2
    folders = []
    for k, part in enumerate((frames[:half], frames[half:])):
        f = tmp_path / f"run{k + 1}"
        f.mkdir()
        with open(tmp_path / f"run{k + 1}.csv", "w") as fh:
            fh.write("frame,x,y\n")
            for i, p in enumerate(part):
                shutil.copy(p, f / p.name)
                x, y = rows[int(p.stem)]
                fh.write(f"{i},{x},{y}\n")
        folders.append(f)
    argv = ["--exclude", "12", "--no-progress"]  # the default preset and its rule decide
    code = main([str(a) for a in ["loops", *folders, "--out", tmp_path / "o", "--gt", tmp_path / "run1.csv",
                                  tmp_path / "run2.csv", "--radius", 4, "--gt-soft", 8, *argv]])
    out, err = capsys.readouterr()
    assert code == 0, err
    m = json.loads((tmp_path / "o" / "metrics.json").read_text())
    pairs = {(p["session"], p["onto"]): p for p in m["methods"]["rshosm-seq"]["sessions"]}
    across = pairs[("run2", "run1")]
    assert across["accepted"] > 10 and across["precision"] == 1.0
    assert m["params"]["sessions"][1]["first_frame"] == half
    # the same online, sessions marked on stdin
    text = "\n".join(sorted(str(p) for p in folders[0].glob("*.png"))) + "\n#session\n" + \
        "\n".join(sorted(str(p) for p in folders[1].glob("*.png"))) + "\n"
    monkeypatch.setattr("sys.stdin", io.StringIO(text))
    code = main([str(a) for a in ["loops", "-", "--out", tmp_path / "online", *argv]])
    out, err = capsys.readouterr()
    assert code == 0, err
    online = [json.loads(line) for line in out.splitlines()]
    with open(tmp_path / "o" / "rshosm-seq" / "matches.csv") as fh:
        batch = [(int(r["best_db"]), r["accepted"] == "1") for r in csv.DictReader(fh)]
    assert [(r["best_db"] if r["best_db"] is not None else -1, r["accepted"]) for r in online] == batch
