"""No input file runs code; inputs that would give wrong metrics are refused or warned about (issue 24).

Each case here failed before its fix. Tiny renders keep the command-line cases fast.
"""
import os
import pickle

import numpy as np
import pytest

from pipelines.cli import main
from vpr.groundtruth.formats import db_query_matrix
from vpr.io import load_npy

N_FRAMES = 20


class _Payload:
    """Unpickling this runs ``touch MARKER``: what a crafted ground-truth file would do."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return os.system, (f"touch {self.marker}",)


@pytest.fixture(scope="module")
def folders(scene_on_disk):
    s = scene_on_disk("two_seasons", (48, 32), N_FRAMES)
    return s[s["names"][0]], s[s["names"][1]]


def _run(argv, capsys):
    code = main([str(a) for a in argv] + ["--no-progress"])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def _one_error_line(code, err, *expect):
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    for e in expect:
        assert e in lines[0], lines[0]
    return lines[0]


# ------------------------------------------------------------ 1. no file runs code
def test_a_bare_pickle_named_npy_does_not_run(folders, tmp_path, capsys):
    marker = tmp_path / "PWNED"
    evil = tmp_path / "evil.npy"
    evil.write_bytes(pickle.dumps(_Payload(marker)))
    code, _, err = _run(["compare", *folders, "--out", tmp_path / "out", "--gt", evil], capsys)
    _one_error_line(code, err, "evil.npy", "not a readable")
    assert not marker.exists()
    assert not (tmp_path / "out").exists()


def test_a_payload_inside_a_real_npy_does_not_run(folders, tmp_path, capsys):
    marker = tmp_path / "PWNED"
    arr = np.empty((2, 2), dtype=object)
    arr[0] = [0, [0]]
    arr[1] = [1, _Payload(marker)]
    np.save(tmp_path / "ground_truth_new.npy", arr, allow_pickle=True)
    code, _, err = _run(["match", *folders, "--out", tmp_path / "out", "--gt", tmp_path / "ground_truth_new.npy"],
                        capsys)
    _one_error_line(code, err, "ground_truth_new.npy", "posix.system")
    assert not marker.exists()


def test_text_named_npy_is_one_line(folders, tmp_path, capsys):
    (tmp_path / "gt.npy").write_text("query,db\n0,0\n")
    code, _, err = _run(["compare", *folders, "--out", tmp_path / "out", "--gt", tmp_path / "gt.npy"], capsys)
    _one_error_line(code, err, "gt.npy", "no NumPy .npy header")


def test_vpr_bench_rows_with_numpy_scalars_and_arrays_are_still_read(tmp_path):
    rows = np.empty((3, 2), dtype=object)
    rows[0] = [np.int64(0), np.array([0, 1])]
    rows[1] = [1, [2]]
    rows[2] = [np.int32(2), []]
    np.save(tmp_path / "ground_truth_new.npy", rows, allow_pickle=True)
    gt = db_query_matrix(tmp_path / "ground_truth_new.npy", 4, 3)
    assert gt.sum() == 3 and gt[0, 0] and gt[1, 0] and gt[2, 1]


def test_load_npy_reads_numbers_as_numpy_does(tmp_path):
    a = np.arange(12, dtype=np.float32).reshape(3, 4)
    np.save(tmp_path / "a.npy", a)
    np.testing.assert_array_equal(load_npy(tmp_path / "a.npy"), a)
    with pytest.raises(ValueError, match="a.npy: not a readable"):
        (tmp_path / "a.npy").write_bytes((tmp_path / "a.npy").read_bytes()[:60])
        load_npy(tmp_path / "a.npy")


def test_no_product_module_unpickles_with_numpy():
    """``allow_pickle=True`` would let a file run code: the product reads .npy only through ``load_npy``."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    hits = []
    for pkg in ("vpr", "encoders", "pipelines"):
        for dirpath, _, files in os.walk(os.path.join(root, pkg)):
            for f in files:
                if f.endswith(".py"):
                    text = open(os.path.join(dirpath, f), encoding="utf-8").read()
                    if "allow_pickle=True" in text or "pickle.load(" in text:
                        hits.append(os.path.join(dirpath, f))
    assert not hits, hits
