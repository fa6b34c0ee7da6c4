"""Tests for vpr.groundtruth: pair files, position files, tolerance."""
from __future__ import annotations

import re

import numpy as np
import pytest
import scipy.sparse as sp

from vpr.groundtruth import (
    GroundTruthSpec,
    build_gt,
    gt_from_position_files,
    gt_from_tolerance,
    load_pairs_csv,
    load_positions_csv,
    load_traverse_positions,
    positions_of_frames,
)


def _file(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def _line_error(path, line):
    return re.escape(f"{path}:{line}:")


# ---------------------------------------------------------------- pairs

def test_pairs_with_and_without_header(tmp_path):
    expected = np.zeros((4, 3), dtype=bool)
    expected[[2, 0, 3], [0, 1, 1]] = True
    plain = _file(tmp_path, "p.csv", "0,2\n1,0\n\n# a comment\n1, 3\n")
    assert np.array_equal(load_pairs_csv(plain, 4, 3), expected)
    header = _file(tmp_path, "h.csv", "query,db\n0,2\n1,0\n1,3\n")
    assert np.array_equal(load_pairs_csv(header, 4, 3), expected)
    spaces = _file(tmp_path, "s.txt", "query db\n0 2\n1\t0\n1 3\n")
    assert np.array_equal(load_pairs_csv(spaces, 4, 3), expected)


def test_pairs_beyond_the_dense_limit_are_sparse(tmp_path, monkeypatch):
    from vpr import similarity as g

    monkeypatch.setattr(g, "DENSE_PAIRS_LIMIT", 10)
    gt = load_pairs_csv(_file(tmp_path, "p.csv", "0,2\n1,0\n1,3\n1,3\n"), 4, 3)
    assert sp.issparse(gt) and gt.dtype == bool and gt.nnz == 3
    expected = np.zeros((4, 3), dtype=bool)
    expected[[2, 0, 3], [0, 1, 1]] = True
    assert np.array_equal(gt.toarray(), expected)


def test_pairs_by_name(tmp_path):
    db_names = ["d0.png", "d1.png", "d2.png"]
    q_names = ["imgs/q0.jpg", "imgs/q1.jpg"]
    p = _file(tmp_path, "p.csv", "query,db\nimgs/q1.jpg,d2.png\nq0.jpg,d1\n1,0\n")
    gt = load_pairs_csv(p, 3, 2, db_names=db_names, q_names=q_names)
    expected = np.zeros((3, 2), dtype=bool)
    expected[2, 1] = expected[1, 0] = expected[0, 1] = True
    assert np.array_equal(gt, expected)


def test_pairs_with_frame_numbers_of_a_subsampled_source(tmp_path):
    # db read frames 0, 5, 10; query read frames 3, 4 (frame 2 skipped)
    p = _file(tmp_path, "p.csv", "3,5\n4,10\n2,0\n4,7\n")
    with pytest.warns(UserWarning, match="2 pairs"):
        gt = load_pairs_csv(p, 3, 2, db_indices=[0, 5, 10], q_indices=[3, 4])
    expected = np.zeros((3, 2), dtype=bool)
    expected[1, 0] = expected[2, 1] = True
    assert np.array_equal(gt, expected)


@pytest.mark.parametrize("text, line, reason", [
    ("0,1\n1,2,3\n", 2, "expected 2 columns"),
    ("0,1\n\n1\n", 3, "expected 2 columns"),
    ("0,1\n1,x\n", 2, "db 'x' is not an integer"),
    ("0,1\n1.5,1\n", 2, "query '1.5' is not an integer"),
    ("q,5\n", 1, "query 'q' is not an integer"),
    ("0,1\n1,4\n", 2, r"db frame number 4 out of range 0\.\.3"),
    ("query,db\n0,1\n3,0\n", 3, r"query frame number 3 out of range 0\.\.2"),
    ("0,1\n-1,0\n", 2, "query frame number -1 is negative"),
    ("0,1\n,1\n", 2, "empty query field"),
    ('0,1\n"1,0\n', 2, ""),
])
def test_pairs_errors_name_the_line(tmp_path, text, line, reason):
    p = _file(tmp_path, "bad.csv", text)
    with pytest.raises(ValueError, match=_line_error(p, line) + ".*" + reason):
        load_pairs_csv(p, 4, 3)


def test_pairs_unknown_name_names_the_line(tmp_path):
    p = _file(tmp_path, "bad.csv", "a.png,b.png\nc.png,z.png\n")
    with pytest.raises(ValueError, match=_line_error(p, 2) + " db 'z.png' is not a known frame name"):
        load_pairs_csv(p, 2, 2, db_names=["b.png", "y.png"], q_names=["a.png", "c.png"])


def test_pairs_ambiguous_name_is_an_error(tmp_path):
    p = _file(tmp_path, "bad.csv", "q.png,a.png\n")
    with pytest.raises(ValueError, match=_line_error(p, 1) + " db frame name 'a.png' matches several"):
        load_pairs_csv(p, 2, 1, db_names=["x/a.png", "y/a.png"], q_names=["q.png"])


def test_pairs_empty_and_header_only_files(tmp_path):
    empty = _file(tmp_path, "empty.csv", "")
    with pytest.raises(ValueError, match=re.escape(f"{empty}: empty file")):
        load_pairs_csv(empty, 2, 2)
    comments = _file(tmp_path, "comments.csv", "# nothing\n\n")
    with pytest.raises(ValueError, match="empty file"):
        load_pairs_csv(comments, 2, 2)
    header = _file(tmp_path, "header.csv", "query,db\n")
    with pytest.raises(ValueError, match=re.escape(f"{header}: no pairs after the header on line 1")):
        load_pairs_csv(header, 2, 2)
    with pytest.raises(FileNotFoundError, match="missing.csv"):
        load_pairs_csv(tmp_path / "missing.csv", 2, 2)


def test_pairs_argument_checks(tmp_path):
    p = _file(tmp_path, "p.csv", "0,0\n")
    with pytest.raises(ValueError, match="n_db"):
        load_pairs_csv(p, 0, 2)
    with pytest.raises(ValueError, match="db_names: 1 names for 2 frames"):
        load_pairs_csv(p, 2, 1, db_names=["a"])
    with pytest.raises(ValueError, match="not unique"):
        load_pairs_csv(p, 2, 1, db_indices=[3, 3])


# ---------------------------------------------------------------- positions

def test_load_positions_indices_and_names(tmp_path):
    p = _file(tmp_path, "pos.csv", "frame,x,y\n0,1.5,2\n2, -3e2 ,4\n1,0,0\n")
    frames, xy = load_positions_csv(p)
    assert frames.dtype == np.int64 and frames.tolist() == [0, 2, 1]
    assert np.array_equal(xy, [[1.5, 2.0], [-300.0, 4.0], [0.0, 0.0]])
    n = _file(tmp_path, "named.csv", "a.png,1,2\nb.png,3,4\n")
    frames, xy = load_positions_csv(n)
    assert frames == ["a.png", "b.png"]
    assert xy.shape == (2, 2)


@pytest.mark.parametrize("text, line, reason", [
    ("0,1,2\n1,2\n", 2, "expected 3 columns"),
    ("0,1,2\n1,2,3,4\n", 2, "expected 3 columns"),
    ("0,1,2\n1,east,3\n", 2, "x 'east' is not a number"),
    ("frame,x,y\n0,1,2\n1,2,\n", 3, "y '' is not a number"),
    ("0,1,2\n1,nan,3\n", 2, "expected a finite number"),
    ("0,1,2\n1,2,3\n0,5,5\n", 3, r"duplicate frame 0 \(first on line 1\)"),
    ("a.png,1,2\n\nb.png,2,3\na.png,5,5\n", 4, r"duplicate frame 'a.png' \(first on line 1\)"),
    ("0,1,2\n-1,2,3\n", 2, "frame number -1 is negative"),
    (" ,1,2\n", 1, "empty frame field"),
])
def test_positions_errors_name_the_line(tmp_path, text, line, reason):
    p = _file(tmp_path, "bad.csv", text)
    with pytest.raises(ValueError, match=_line_error(p, line) + ".*" + reason):
        load_positions_csv(p)
    # the GT builder reports the same error for either traverse
    good = _file(tmp_path, "good.csv", "0,0,0\n")
    with pytest.raises(ValueError, match=_line_error(p, line)):
        gt_from_position_files(good, p, 1.0)
    with pytest.raises(ValueError, match=_line_error(p, line)):
        gt_from_position_files(p, good, 1.0)


def test_positions_empty_file(tmp_path):
    p = _file(tmp_path, "empty.csv", "\n\n")
    with pytest.raises(ValueError, match=re.escape(f"{p}: empty file")):
        load_positions_csv(p)
    h = _file(tmp_path, "h.csv", "frame,x,y\n")
    with pytest.raises(ValueError, match="no positions after the header"):
        load_positions_csv(h)


def test_gt_from_positions_by_index(tmp_path):
    db = _file(tmp_path, "db.csv", "frame,x,y\n0,0,0\n1,10,0\n2,20,0\n3,30,0\n")
    q = _file(tmp_path, "q.csv", "1,11,0\n0,0,4\n2,50,0\n")
    gt = gt_from_position_files(db, q, radius=4.0)
    expected = np.zeros((4, 3), dtype=bool)
    expected[0, 0] = True   # q0 at (0, 4): distance 4, radius inclusive
    expected[1, 1] = True   # q1 at (11, 0)
    assert np.array_equal(gt, expected)
    assert gt_from_position_files(db, q, radius=10.0)[:, 1].tolist() == [False, True, True, False]


def test_gt_from_positions_matches_frames_actually_read(tmp_path):
    db = _file(tmp_path, "db.csv", "0,0,0\n1,10,0\n2,20,0\n3,30,0\n4,40,0\n")
    q = _file(tmp_path, "q.csv", "name,x,y\nq_a.png,21,0\nq_b.png,0,0\nq_c.png,39,0\n")
    # db read frames 0, 2, 4 (subsampled); query frame q_b skipped
    gt = gt_from_position_files(db, q, 2.0, db_indices=[0, 2, 4], q_names=["q_a.png", "q_c.png"])
    assert gt.tolist() == [[False, False], [True, False], [False, True]]


def test_gt_from_positions_numeric_names_match_file_stems(tmp_path):
    db = _file(tmp_path, "db.csv", "0001,0,0\n0002,5,0\n")
    q = _file(tmp_path, "q.csv", "0,5,0\n")
    gt = gt_from_position_files(db, q, 1.0, db_names=["0001.png", "0002.png"])
    assert gt.tolist() == [[False], [True]]


def test_gt_from_positions_missing_frame_is_an_error(tmp_path):
    db = _file(tmp_path, "db.csv", "0,0,0\n2,20,0\n")
    q = _file(tmp_path, "q.csv", "a.png,0,0\n")
    with pytest.raises(ValueError, match=re.escape(f"{db}: no position for 1 of the 3 database frames") + ".*1"):
        gt_from_position_files(db, q, 1.0, db_names=["0.png", "1.png", "2.png"], q_names=["a.png"])
    with pytest.raises(ValueError, match=re.escape(f"{q}: no position") + ".*'b.png'"):
        gt_from_position_files(db, q, 1.0, db_indices=[0, 2], q_names=["a.png", "b.png"])
    with pytest.raises(ValueError, match="no position for 1 of the 3 database frames"):
        gt_from_position_files(db, q, 1.0)


def test_gt_from_positions_bad_radius(tmp_path):
    p = _file(tmp_path, "p.csv", "0,0,0\n")
    for bad in (-1, float("nan"), float("inf"), "x", True):
        with pytest.raises(ValueError, match="radius"):
            gt_from_position_files(p, p, bad)


# ---------------------------------------------------------------- tolerance

def test_gt_from_tolerance():
    gt = gt_from_tolerance(5, 4, 1)
    i, j = np.meshgrid(np.arange(5), np.arange(4), indexing="ij")
    assert gt.dtype == bool and gt.shape == (5, 4)
    assert np.array_equal(gt, np.abs(i - j) <= 1)
    assert np.array_equal(gt_from_tolerance(3, 3, 0), np.eye(3, dtype=bool))
    with pytest.raises(ValueError, match="tol"):
        gt_from_tolerance(3, 3, -1)


# ------------------------------------------------- traverse,frame,x,y files and build_gt

_COMBINED = "traverse,frame,x,y,yaw\nsummer,0,0,0,0\nsummer,1,5,0,0\nsummer,2,10,0,0\nwinter,0,1,0,0\nwinter,1,9,0,0\n"


def test_load_traverse_positions_reads_one_traverse(tmp_path):
    p = _file(tmp_path, "gt.csv", _COMBINED)
    assert load_traverse_positions(p, "winter") == {0: (1.0, 0.0), 1: (9.0, 0.0)}
    # the video `vpr render --video` writes beside the folder: winter.mp4 -> the rows of winter
    assert load_traverse_positions(p, "winter.mp4") == {0: (1.0, 0.0), 1: (9.0, 0.0)}
    with_video = _file(tmp_path, "v.csv", _COMBINED + "winter.mp4,0,7,0,0\n")
    assert load_traverse_positions(with_video, "winter.mp4") == {0: (7.0, 0.0)}
    with pytest.raises(ValueError, match="no rows for traverse 'autumn.mp4'"):
        load_traverse_positions(p, "autumn.mp4")
    with pytest.raises(ValueError, match="no rows for traverse 'autumn'"):
        load_traverse_positions(p, "autumn")
    with pytest.raises(ValueError, match=_line_error(p.parent / "bad.csv", 3)):
        load_traverse_positions(_file(tmp_path, "bad.csv", "traverse,frame,x,y\nsummer,0,0,0\nsummer,x,0,0\n"),
                                "summer")
    with pytest.raises(ValueError, match=_line_error(p.parent / "head.csv", 1)):
        load_traverse_positions(_file(tmp_path, "head.csv", "frame,x,y\n0,0,0\n"), "summer")
    with pytest.raises(FileNotFoundError, match="nope.csv"):
        load_traverse_positions(tmp_path / "nope.csv", "summer")


def test_positions_of_frames_reads_both_layouts(tmp_path):
    combined = _file(tmp_path, "gt.csv", _COMBINED)
    assert positions_of_frames(combined, "summer", [2, 0]).tolist() == [[10, 0], [0, 0]]
    plain = _file(tmp_path, "pos.csv", "frame,x,y\n0,0,0\n1,3,4\n")
    assert positions_of_frames(plain, "any", [1]).tolist() == [[3, 4]]
    with pytest.raises(ValueError, match="no position for frame 5 of traverse 'summer'"):
        positions_of_frames(combined, "summer", [0, 5])


def test_build_gt_from_a_combined_file_with_soft_radius(tmp_path):
    p = _file(tmp_path, "gt.csv", _COMBINED)
    spec = GroundTruthSpec(files=(str(p),), radius=2.0, soft=6.0)
    names = ["a", "b", "c"]
    hard, soft = build_gt(spec, names, names[:2], [0, 1, 2], [0, 1], "summer", "winter")
    # winter 0 at x=1 is within 2 of summer 0 (x=0); winter 1 at x=9 within 2 of summer 2 (x=10)
    assert hard.tolist() == [[True, False], [False, False], [False, True]]
    assert soft.tolist() == [[True, False], [True, True], [False, True]]


def test_build_gt_tolerance_and_pairs(tmp_path):
    # tolerances count frames kept: the database keeps every 2nd frame, so --gt-soft 1 reaches 2 input frames
    with pytest.warns(UserWarning, match="--tolerance 0 accepts only the exact frame"):
        hard, soft = build_gt(GroundTruthSpec(tolerance=0, soft=1), ["a", "b"], ["x", "y"], [0, 2], [0, 1])
    assert hard.tolist() == [[True, False], [False, False]] and soft.tolist() == [[True, True], [True, True]]
    hard, soft = build_gt(GroundTruthSpec(tolerance=1), list("abcd"), list("abc"), [0, 1, 2, 3], [0, 1, 2])
    assert hard[:, 1].tolist() == [True, True, True, False]
    pairs = _file(tmp_path, "pairs.csv", "query,db\n1,0\n")
    hard, soft = build_gt(GroundTruthSpec(files=(str(pairs),)), ["a", "b"], ["x", "y"], [0, 1], [0, 1])
    assert hard.tolist() == [[False, True], [False, False]] and soft is None
    assert build_gt(GroundTruthSpec(), ["a"], ["b"], [0], [0]) == (None, None)
    assert GroundTruthSpec(files=("g.csv",), radius=3.0).describe() == {
        "tolerance": None, "gt": ["g.csv"], "radius": 3.0, "gt_soft": None}


@pytest.mark.parametrize("spec,msg", [
    (GroundTruthSpec(tolerance=1, files=("g.csv",)), "either --tolerance or --gt"),
    (GroundTruthSpec(radius=3.0), "--radius needs --gt"),
    (GroundTruthSpec(files=("a", "b", "c"), radius=1.0), "one or two files, got 3"),
    (GroundTruthSpec(files=("a", "b")), "need --radius"),
    (GroundTruthSpec(files=("a",), soft=2.0), "--gt-soft needs"),
])
def test_build_gt_rejects_contradictory_options(spec, msg):
    with pytest.raises(ValueError, match=re.escape(msg)):
        build_gt(spec, ["a"], ["b"], [0], [0])


def test_frames_without_a_position_are_unknown_pairs_not_left_out_of_the_matrix():
    from vpr.groundtruth import GroundTruthSpec, build_gt, build_loop_gt
    from vpr.groundtruth.trajectories import every

    nan = np.nan
    db = np.array([[0.0, 0], [1, 0], [nan, nan], [3, 0]])
    q = np.array([[0.2, 0], [nan, nan], [3.1, 0]])
    hard, soft = build_gt(GroundTruthSpec(radius=0.5, files=("x",)), [], [], [], [], positions=(db, q))
    assert hard.shape == soft.shape == (4, 3)
    np.testing.assert_array_equal(hard, [[1, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 1]])
    # every pair of a frame without a position is in the soft band (ignored), the rest as the radius says
    np.testing.assert_array_equal(soft, [[1, 1, 0], [0, 1, 0], [1, 1, 1], [0, 1, 1]])
    hard, soft = build_gt(GroundTruthSpec(radius=0.5, soft=1.5, files=("x",)), [], [], [], [], positions=(db, q))
    np.testing.assert_array_equal(soft, [[1, 1, 0], [1, 1, 0], [1, 1, 1], [0, 1, 1]])
    loop_hard, loop_soft = build_loop_gt(GroundTruthSpec(radius=0.5, files=("x",)), [], [], positions=db)
    assert loop_hard.shape == (4, 4) and loop_soft[2].all() and loop_soft[:, 2].all() and not loop_hard[2].any()
    # --every samples by travel among the frames with a position only
    np.testing.assert_array_equal(every(np.array([[nan, nan], [0, 0], [1, 0], [nan, nan], [2, 0], [3, 0]]), 2.0),
                                  [1, 4])
