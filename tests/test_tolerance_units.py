"""A ground-truth tolerance counts frames kept (after --step / --fps / --every), said wherever it is scored."""
import json
import shutil
import warnings

import cv2
import numpy as np
import pytest

from pipelines.cli import main
from vpr import evaluate
from vpr.groundtruth import GroundTruthSpec, build_gt, gt_from_frames, sampling_step


@pytest.fixture(scope="module")
def aligned(scene_on_disk, tmp_path_factory):
    """Two frame-aligned folders of 200 frames (the same file name is the same place: a day and a darker, noisy
    copy), and the same two holding every 10th file."""
    s = scene_on_disk("two_seasons", (48, 32), 200)
    day = sorted(s[s["names"][0]].glob("*.png"))[:200]
    root = tmp_path_factory.mktemp("aligned")
    rng = np.random.default_rng(0)
    for sub in ("db", "q", "db10", "q10"):
        (root / sub).mkdir()
    for k, f in enumerate(day):
        img = cv2.imread(str(f))
        dark = np.clip(img.astype(np.float32) * 0.6 + rng.normal(0, 12, img.shape), 0, 255).astype(np.uint8)
        cv2.imwrite(str(root / "db" / f.name), img)
        cv2.imwrite(str(root / "q" / f.name), dark)
        if k % 10 == 0:
            shutil.copy(root / "db" / f.name, root / "db10" / f.name)
            shutil.copy(root / "q" / f.name, root / "q10" / f.name)
    return root


def _run(argv, capsys):
    code = main([str(a) for a in argv] + ["--no-progress"])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


METRICS = ("ap", "recall_at_1", "recall_at_100p", "precision_accepted", "n_accepted")


@pytest.mark.slow
def test_a_tolerance_at_a_step_counts_frames_kept_and_is_said_in_both_units(aligned, tmp_path, capsys):
    common = ["--methods", "pairwise", "--preset", "fast"]
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        code, out, err = _run(["compare", aligned / "db", aligned / "q", "--out", tmp_path / "a", "--step", 10,
                               "--tolerance", 1, *common], capsys)
    assert not [w for w in got if "--tolerance" in str(w.message)]  # nothing to say: 1 frame kept, the usual
    assert code == 0, err
    assert "--tolerance 1: 1 frame kept = 10 input frames" in out
    a = json.loads((tmp_path / "a" / "metrics.json").read_text())
    truth = a["params"]["ground_truth"]
    assert truth["tolerance_unit"] == "frames kept" and truth["tolerance_input_frames"] == 10
    # the same folders as holding every 10th file: frames kept and input frames are one unit there
    code, out, err = _run(["compare", aligned / "db10", aligned / "q10", "--out", tmp_path / "b", "--tolerance", 1,
                           *common], capsys)
    assert code == 0, err
    assert "--tolerance 1: 1 frame kept = 1 input frame" in out
    b = json.loads((tmp_path / "b" / "metrics.json").read_text())
    for k in METRICS:
        assert a["methods"]["pairwise"][k] == pytest.approx(b["methods"]["pairwise"][k]), k
    # and in input frames: 10 of them, on the source frame numbers of the frames kept
    S = np.load(tmp_path / "a" / "pairwise" / "similarity.npy")
    idx = np.arange(0, 200, 10)
    assert evaluate.average_precision(S, gt_from_frames(idx, idx, 10)) == pytest.approx(a["methods"]["pairwise"]["ap"])
    # the page carries it in its settings
    page = (tmp_path / "a" / "report.html").read_text()
    assert "1 frame kept = 10 input frames" in page and 'id="settings"' in page


@pytest.mark.slow
@pytest.mark.parametrize("tolerance, said", [
    (0, "--tolerance 0 accepts only the exact frame, where frames kept are 10 input frames apart; --tolerance 1 "
        "(a neighbour kept) was probably meant"),
    (10, "--tolerance 10 counts frames kept and spans more than a tenth of the route (20 frames kept, 1 frame kept = "
         "10 input frames): --tolerance 1 (10 input frames) was probably meant"),
])
def test_a_tolerance_that_probably_means_another_unit_is_said_in_one_line(aligned, tmp_path, capsys, tolerance,
                                                                           said):
    with pytest.warns(UserWarning) as got:
        code, _, err = _run(["compare", aligned / "db", aligned / "q", "--out", tmp_path / "o", "--step", 10,
                             "--tolerance", tolerance, "--methods", "pairwise", "--preset", "fast"], capsys)
    assert code == 0, err
    assert [str(w.message) for w in got if "--tolerance" in str(w.message)] == [said]


def test_sampling_step_and_the_radius_check():
    assert sampling_step(np.arange(0, 200, 10)) == 10 and sampling_step([5]) == 1
    assert sampling_step([0, 10, 20, 31, 40]) == 10  # a frame unread or off by one does not change it
    xy = np.c_[np.arange(0, 40, 2.0), np.zeros(20)]  # a frame every 2 m
    with pytest.warns(UserWarning, match=r"--radius 1 is smaller than the median travel between consecutive "
                                         r"database frames kept \(2\): .*--radius 2 or more was probably meant"):
        build_gt(GroundTruthSpec(radius=1.0, files=("x",)), [], [], [], [], positions=(xy, xy))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        build_gt(GroundTruthSpec(radius=3.0, files=("x",)), [], [], [], [], positions=(xy, xy))
        hard, _ = build_gt(GroundTruthSpec(tolerance=1), [], [], np.arange(0, 200, 10), np.arange(0, 200, 10))
    assert hard[3, 4] and not hard[3, 5]  # neighbours kept, 10 input frames apart
