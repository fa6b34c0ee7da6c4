"""Ground truth in the formats the common benchmarks ship: GThard/GTsoft, VPR-Bench, loop matrices."""
import cv2
import numpy as np
import pytest
import scipy.io

from vpr.groundtruth import GroundTruthSpec, build_gt, build_loop_gt
from vpr.groundtruth.files import load_tolerance_csv
from vpr.groundtruth.formats import db_query_matrix, loop_matrix, read_matrix, split_variable


def test_split_variable_only_for_mat_files():
    assert split_variable("truth.mat:GT") == (split_variable("truth.mat")[0], "GT")
    assert split_variable("C:/data/truth.npy")[1] is None
    assert split_variable("truth.mat")[1] is None


def test_gthard_gtsoft_npy_select_the_frames_read(tmp_path):
    hard = np.zeros((6, 5), bool)
    hard[[0, 2, 4], [0, 2, 4]] = True
    soft = hard.copy()
    soft[1, 0] = True
    np.save(tmp_path / "GThard.npy", hard)
    np.save(tmp_path / "GTsoft.npy", soft.astype(np.uint8))
    spec = GroundTruthSpec(files=(str(tmp_path / "GThard.npy"), str(tmp_path / "GTsoft.npy")))
    h, s = build_gt(spec, ["a", "b", "c"], ["x", "y"], [0, 1, 2], [0, 2])
    np.testing.assert_array_equal(h, hard[np.ix_([0, 1, 2], [0, 2])])
    np.testing.assert_array_equal(s, soft[np.ix_([0, 1, 2], [0, 2])])
    assert s[1, 0] and not h[1, 0]


def test_transposed_matrix_is_refused_with_a_hint(tmp_path):
    np.save(tmp_path / "gt.npy", np.eye(3, 8, dtype=bool))
    with pytest.raises(ValueError, match="transposed"):
        db_query_matrix(tmp_path / "gt.npy", 8, 3)


def test_vpr_bench_ground_truth_rows(tmp_path):
    rows = np.empty((3, 2), dtype=object)
    rows[0] = [0, [0, 1]]
    rows[1] = [1, [2]]
    rows[2] = [2, []]
    np.save(tmp_path / "ground_truth_new.npy", rows, allow_pickle=True)
    gt = db_query_matrix(tmp_path / "ground_truth_new.npy", 4, 3)
    expected = np.zeros((4, 3), bool)
    expected[[0, 1], 0] = True
    expected[2, 1] = True
    np.testing.assert_array_equal(gt, expected)
    # an entry beyond the traverses' frames (VPR-Bench's Gardens Point lists database frames 200 and 201 of 200):
    # left out and said, the rest as the file without it
    rows[1] = [1, [2, 9]]
    np.save(tmp_path / "beyond.npy", rows, allow_pickle=True)
    with pytest.warns(UserWarning, match=r"beyond.npy: 1 entry name frames beyond .* row 1 \(database frame 9\)"):
        np.testing.assert_array_equal(db_query_matrix(tmp_path / "beyond.npy", 4, 3), expected)
    rows[0], rows[1], rows[2] = [0, [7, 8]], [1, [9]], [5, [0]]  # most of it beyond: another dataset's file
    np.save(tmp_path / "other.npy", rows, allow_pickle=True)
    with pytest.raises(ValueError, match=r"other.npy: 4 of its 4 entries name frames beyond"):
        db_query_matrix(tmp_path / "other.npy", 4, 3)
    rows[2] = [2, [-1]]
    np.save(tmp_path / "negative.npy", rows, allow_pickle=True)
    with pytest.raises(ValueError, match=r"negative.npy: row 2: a negative frame number"):
        db_query_matrix(tmp_path / "negative.npy", 4, 3)


def test_loop_matrix_png_is_symmetrised_and_subset(tmp_path):
    img = np.zeros((6, 6), np.uint8)
    img[5, 1] = 255  # frame 5 closes onto earlier frame 1 (row = frame)
    cv2.imwrite(str(tmp_path / "gt.png"), img)
    m = loop_matrix(tmp_path / "gt.png", [1, 3, 5])
    assert m.shape == (3, 3)
    assert m[0, 2] and m[2, 0] and m.sum() == 2
    with pytest.raises(ValueError, match="does not cover frame 7"):
        loop_matrix(tmp_path / "gt.png", [0, 7])


def test_mat_variables(tmp_path):
    gt = np.zeros((4, 4))
    gt[3, 0] = 1
    scipy.io.savemat(tmp_path / "one.mat", {"truth": gt})
    np.testing.assert_array_equal(read_matrix(tmp_path / "one.mat"), gt)
    scipy.io.savemat(tmp_path / "two.mat", {"GT": gt, "other": np.ones((2, 2))})
    with pytest.raises(ValueError, match="2 matrices .*name one as"):
        read_matrix(tmp_path / "two.mat")
    assert read_matrix(f"{tmp_path / 'two.mat'}:GT")[3, 0] == 1
    with pytest.raises(ValueError, match="no variable 'nope'; variables: GT, other"):
        read_matrix(f"{tmp_path / 'two.mat'}:nope")
    with pytest.raises(ValueError, match="only a .mat file has named variables"):
        np.save(tmp_path / "x.npy", gt)
        read_matrix(f"{tmp_path / 'x.npy'}:GT")


def test_loop_ground_truth_from_matrix_and_pairs(tmp_path):
    gt = np.zeros((5, 5), bool)
    gt[4, 1] = True
    np.save(tmp_path / "loops.npy", gt)
    names = [f"f{i}.png" for i in range(5)]
    hard, soft = build_loop_gt(GroundTruthSpec(files=(str(tmp_path / "loops.npy"),)), names, range(5))
    assert hard[1, 4] and hard[4, 1] and hard.sum() == 2 and soft is None
    (tmp_path / "pairs.csv").write_text("earlier,frame\nf1.png,f4.png\n")
    hard2, _ = build_loop_gt(GroundTruthSpec(files=(str(tmp_path / "pairs.csv"),)), names, range(5))
    np.testing.assert_array_equal(hard2, hard)
    (tmp_path / "bad.csv").write_text("frame,earlier\nf4.png,nope\n")
    with pytest.raises(ValueError, match="earlier 'nope' is not a known frame name"):
        build_loop_gt(GroundTruthSpec(files=(str(tmp_path / "bad.csv"),)), names, range(5))


@pytest.mark.parametrize("kwargs, message", [
    ({"files": ("a.npy", "b.csv")}, "cannot be mixed"),
    ({"files": ("a.npy",), "radius": 2.0}, "--radius applies to positions CSV files"),
    ({"files": ("a.npy", "b.npy", "c.npy")}, "one or two files"),
    ({"files": ("a.npy",), "soft": 3.0}, "second --gt file"),
])
def test_matrix_option_refusals(kwargs, message):
    with pytest.raises(ValueError, match=message):
        GroundTruthSpec(**kwargs).check()


def test_loops_refuse_tolerance_and_two_csvs(tmp_path):
    with pytest.raises(ValueError, match="not --tolerance"):
        GroundTruthSpec(tolerance=2).check(loops=True)
    with pytest.raises(ValueError, match="one CSV file"):
        GroundTruthSpec(files=("a.csv", "b.csv"), radius=1.0).check(loops=True)


def _openseqslam_rows(path, n, tolerance=15, header=False):
    path.write_text(("query,db,tolerance\n" if header else "") + "".join(f"{i},{i},{tolerance}\n"
                                                                          for i in range(1, n + 1)))
    return path


@pytest.mark.parametrize("header", [False, True])
def test_openseqslam_rows_at_their_unit_are_the_frame_tolerance(tmp_path, header):
    """OpenSeqSLAM's Nordland sample (i,i,15 over every 10th frame, 15 at the full rate) is |i - j| <= 1."""
    f = _openseqslam_rows(tmp_path / "truth.csv", 12, header=header)
    names = [f"{i:03d}" for i in range(12)]
    hard, soft = build_gt(GroundTruthSpec(files=(str(f),), file_unit=10), names, names, range(12), range(12))
    i, j = np.indices((12, 12))
    np.testing.assert_array_equal(hard, np.abs(i - j) <= 1)
    assert soft is None
    # counted in the file's own frames: within 15
    np.testing.assert_array_equal(load_tolerance_csv(f, 12, 12, 1), np.abs(i - j) <= 15)


def test_openseqslam_rows_of_frames_not_read_are_left_out(tmp_path):
    f = _openseqslam_rows(tmp_path / "truth.csv", 10, tolerance=0)
    with pytest.warns(UserWarning, match="6 rows name frames that were not read"):
        gt = load_tolerance_csv(f, 4, 7, 1, db_indices=[0, 2, 4, 6], q_indices=range(7))
    assert gt.sum() == 4 and gt[1, 2] and gt[3, 6]  # query frame 2 (row 3) onto database frame 2


@pytest.mark.parametrize("text, message", [
    ("0,1,15\n", "count from 1"),
    ("1,1,-2\n", "negative"),
    ("1,x,3\n", "db 'x' is not an integer"),
    ("a,b,c\n1,1,1\n", "unknown header"),
    ("9,1,1\n", "query frame 9 out of range 1..4"),
    ("1,9,1\n", "database frame 9 out of range 1..4"),
    ("1,1\n", "expected 3 columns"),
])
def test_openseqslam_rows_malformed(tmp_path, text, message):
    (tmp_path / "t.csv").write_text(text)
    with pytest.raises(ValueError, match=message):
        load_tolerance_csv(tmp_path / "t.csv", 4, 4, 10)


@pytest.mark.parametrize("kwargs, message", [
    ({}, "--gt-tolerance-unit N"),                                   # the unit is not in the file
    ({"file_unit": 0}, "integer >= 1"),
    ({"file_unit": 10, "radius": 2.0}, "alone"),
    ({"file_unit": 10, "soft": 3}, "needs position ground truth"),
])
def test_openseqslam_unit_refusals(tmp_path, kwargs, message):
    f = _openseqslam_rows(tmp_path / "truth.csv", 3)
    with pytest.raises(ValueError, match=message):
        GroundTruthSpec(files=(str(f),), **kwargs).check()


def test_unit_on_a_two_column_file_is_refused(tmp_path):
    (tmp_path / "pairs.csv").write_text("0,0\n1,1\n")
    with pytest.raises(ValueError, match="has 2 columns"):
        GroundTruthSpec(files=(str(tmp_path / "pairs.csv"),), file_unit=10).check()
