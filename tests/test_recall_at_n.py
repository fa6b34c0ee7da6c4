"""Recall@N as the field computes it (every query the denominator) beside the project's (queries with a true match)."""
import json

import numpy as np
import pytest
import scipy.sparse as sp

from pipelines.cli import main
from tests.reference import field_recalls
from vpr import evaluate
from vpr.groundtruth import gt_from_positions

NS = (1, 5, 10, 20)


def _world(seed: int):
    rng = np.random.default_rng(seed)
    db = np.c_[np.arange(120) * 4.0, rng.normal(0, 2, 120)]  # a route, a frame every 4 m
    q = np.c_[rng.uniform(-30, 560, 90), rng.normal(0, 2, 90)]  # some queries off its ends: no positive
    S = np.round(rng.random((120, 90)), 2)  # rounded: ties, broken by the lower index
    near = np.abs(db[:, None, 0] - q[None, :, 0]) < 12
    S = S + near * rng.random((120, 90)) * 0.8  # true matches tend to rank high
    return db, q, S


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_recall_over_every_query_is_the_fields_digit_for_digit(seed):
    db, q, S = _world(seed)
    gt = gt_from_positions(db, q, 25.0)
    r = evaluate.recall_at_n(S, gt, ns=NS)
    want = field_recalls(S, db, q, NS, radius=25.0)
    assert [r["every_query"][str(n)] for n in NS] == want.tolist()
    assert r["queries"] == 90 and 0 < r["queries_with_true_match"] < 90
    # over the queries with a true match: the project's recall_at_k, the same hits on a smaller denominator
    for n in NS:
        assert r["with_true_match"][str(n)] == evaluate.recall_at_k(S, gt, k=n)
        hits = r["with_true_match"][str(n)] * r["queries_with_true_match"]
        assert r["every_query"][str(n)] * 90 == pytest.approx(hits)
    # a top-K similarity that keeps at least N per query ranks the same
    top = np.argsort(-S, axis=0, kind="stable")[:30]
    cols = np.repeat(np.arange(90), 30)
    sparse = sp.csr_matrix((S[top.T.ravel(), cols], (top.T.ravel(), cols)), shape=S.shape)
    assert evaluate.recall_at_n(sparse, sp.csr_matrix(gt), ns=NS) == r


def test_recall_at_n_refuses_what_is_not_an_n():
    db, q, S = _world(0)
    with pytest.raises(ValueError, match="positive integers"):
        evaluate.recall_at_n(S, gt_from_positions(db, q, 25.0), ns=(0, 5))


@pytest.mark.slow
def test_compare_prints_and_writes_both_recalls(scene_on_disk, tmp_path, capsys):
    s = scene_on_disk("two_seasons", (48, 32), 60)
    db, q = s[s["names"][0]], s[s["names"][1]]
    argv = ["compare", db, q, "--gt", s["gt"], "--radius", 3, "--methods", "pairwise", "--preset", "fast",
            "--no-progress"]
    assert main([str(a) for a in [*argv, "--out", tmp_path / "a", "--recall-at", "1,3"]]) == 0
    out = capsys.readouterr().out
    assert "Recall@N over every query (the field's: 60 queries)" in out and "R@3" in out
    m = json.loads((tmp_path / "a" / "metrics.json").read_text())["methods"]["pairwise"]["recall_at_n"]
    assert set(m["every_query"]) == {"1", "3"} and m["queries"] == 60
    assert m["with_true_match"]["1"] == json.loads((tmp_path / "a" / "metrics.json").read_text())[
        "methods"]["pairwise"]["recall_at_1"]
    assert "Recall@N over every query" in (tmp_path / "a" / "report.html").read_text()
    for bad in ("0,5", "x"):
        assert main([str(a) for a in [*argv, "--out", tmp_path / "b", "--recall-at", bad]]) == 2
        assert "--recall-at" in capsys.readouterr().err and not (tmp_path / "b").exists()
    no_gt = ["compare", db, q, "--methods", "pairwise", "--out", tmp_path / "c", "--recall-at", "5", "--no-progress"]
    assert main([str(a) for a in no_gt]) == 2
    assert "needs ground truth" in capsys.readouterr().err and not (tmp_path / "c").exists()


@pytest.mark.slow
def test_utm_names_alone_score_within_the_fields_25_m(scene_on_disk, tmp_path, capsys):
    import csv
    import shutil

    s = scene_on_disk("two_seasons", (48, 32), 60)
    with open(s["gt"], newline="") as fh:
        rows = list(csv.DictReader(fh))
    for trav in s["names"][:2]:  # the VPR datasets' naming: @UTM_EAST@UTM_NORTH@... (metres)
        (tmp_path / trav).mkdir()
        for r in (r for r in rows if r["traverse"] == trav):
            x, y = 500000 + float(r["x"]), 4000000 + float(r["y"])
            shutil.copy(s["dir"] / r["image"], tmp_path / trav / f"@{x:.2f}@{y:.2f}@{int(r['frame']):05d}.png")
    argv = ["compare", tmp_path / s["names"][0], tmp_path / s["names"][1], "--gt", "names", "--methods", "pairwise",
            "--preset", "fast", "--out", tmp_path / "o", "--no-progress"]
    assert main([str(a) for a in argv]) == 0, capsys.readouterr().err
    m = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert m["params"]["ground_truth"]["radius"] == 25.0
    assert m["methods"]["pairwise"]["recall_at_n"]["queries_with_true_match"] > 0


def test_loop_recall_ranks_each_frames_earlier_frames_only():
    """One stream: frame j's candidates are the frames at least ``exclude`` before it; a hit at N is a true earlier
    frame among its N best of those (brute force)."""
    from vpr.groundtruth import loop_closure_mask

    rng = np.random.default_rng(3)
    T, exclude = 80, 5
    place = np.r_[np.arange(40), np.arange(40)]  # a loop: frame 40 + i revisits frame i
    S = np.round(rng.random((T, T)), 2)
    gt = np.abs(place[:, None] - place[None, :]) <= 1
    S = S + gt * rng.random((T, T)) * 0.6
    mask = loop_closure_mask(T, exclude=exclude)
    r = evaluate.recall_at_n(S, gt, ns=(1, 3), mask=mask)
    want, with_match = {1: 0, 3: 0}, 0
    for j in range(T):
        rows = np.flatnonzero(mask[:, j])
        if not gt[rows, j].any():
            continue
        with_match += 1
        order = rows[np.lexsort((rows, -S[rows, j]))]  # similarity descending, ties by the lower index
        for n in want:
            want[n] += bool(gt[order[:n], j].any())
    assert r["queries_with_true_match"] == with_match == 40 and r["queries"] == T
    assert r["with_true_match"] == {str(n): want[n] / with_match for n in want}
    assert r["every_query"] == {str(n): want[n] / T for n in want}


@pytest.mark.slow
def test_loops_and_localize_print_and_write_recall_at_n(scene_on_disk, tmp_path, capsys, monkeypatch):
    import io

    s = scene_on_disk("loop_revisits", (48, 36), 240)
    gt = ["--gt", s["gt"], "--radius", 4]
    argv = ["loops", s["laps"], *gt, "--preset", "fast", "--recall-at", "1,3", "--no-progress"]
    assert main([str(a) for a in [*argv, "--out", tmp_path / "batch"]]) == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    assert "frames with an earlier true match (R@1 above)" in out and "R@3" in out
    m = json.loads((tmp_path / "batch" / "metrics.json").read_text())["methods"]["rshosm-seq"]
    assert set(m["recall_at_n"]["with_true_match"]) == {"1", "3"}
    assert m["recall_at_n"]["with_true_match"]["1"] == m["recall_at_1"]
    assert "frames with an earlier true match" in (tmp_path / "batch" / "report.html").read_text()
    # online, the frames' paths on stdin
    paths = sorted(p for p in s["laps"].iterdir() if p.suffix == ".png")
    monkeypatch.setattr("sys.stdin", io.StringIO("".join(f"{p}\n" for p in paths)))
    online = ["loops", "-", *gt, "--preset", "fast", "--recall-at", "2", "--out", tmp_path / "online"]
    assert main([str(a) for a in online]) == 0, capsys.readouterr().err
    m = json.loads((tmp_path / "online" / "metrics.json").read_text())["methods"]["rshosm-seq"]
    assert set(m["recall_at_n"]["with_true_match"]) == {"2"} and m["recall_at_n"]["queries_with_true_match"] > 0
    # localize: the same option
    two = scene_on_disk("two_seasons", (48, 32), 60)
    loc = ["localize", two[two["names"][0]], two[two["names"][1]], "--gt", two["gt"], "--radius", 9, "--preset",
           "fast", "--recall-at", "1,4", "--out", tmp_path / "loc", "--no-progress"]
    assert main([str(a) for a in loc]) == 0, capsys.readouterr().err
    m = json.loads((tmp_path / "loc" / "metrics.json").read_text())["methods"]["rshosm-seq"]["recall_at_n"]
    assert set(m["every_query"]) == {"1", "4"}
    capsys.readouterr()
    assert main([str(a) for a in [*argv[:2], "--recall-at", "1", "--out", tmp_path / "no_gt"]]) == 2
    assert "needs ground truth" in capsys.readouterr().err and not (tmp_path / "no_gt").exists()
