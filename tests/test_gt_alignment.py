"""A ``--tolerance`` pairs the frames that sit at one place of the recording, whatever the sources' numbering."""
import csv
import io
import json
import shutil
import warnings

import cv2
import numpy as np
import pytest

from pipelines.cli import main
from vpr.groundtruth import GroundTruthSpec, aligned_frames, build_gt
from vpr.shosm import LOCALIZE_LAG


def test_query_frames_are_placed_by_name_then_by_time_then_by_number():
    db_names = [f"{k:04d}.png" for k in range(10)]
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        # every 2nd file of the same run, under the same names: at the database frame of its name
        at = aligned_frames(db_names, db_names[::2], list(range(10)), list(range(5)))
        np.testing.assert_array_equal(at, [0, 2, 4, 6, 8])
        assert len(said) == 1 and "database frame of its name" in str(said[0].message)
        # a video at 10 frames per second against one at 20: by time (the names are the frame numbers of each)
        at = aligned_frames(db_names, db_names[:5], list(range(10)), list(range(5)), rates=(20.0, 10.0))
        np.testing.assert_array_equal(at, [0, 2, 4, 6, 8])
        assert len(said) == 2 and "of its time" in str(said[1].message)
    # names of their own, or the same names at the same places: their own numbers, nothing said
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(aligned_frames(db_names, ["a", "b"], list(range(10)), [3, 4]), [3, 4])
        np.testing.assert_array_equal(aligned_frames(db_names, db_names[:3], list(range(10)), [0, 1, 2]), [0, 1, 2])
        np.testing.assert_array_equal(
            aligned_frames(db_names, db_names[:3], list(range(10)), [0, 1, 2], rates=(10.0, 10.0)), [0, 1, 2])
    hard, _ = build_gt(GroundTruthSpec(tolerance=1), db_names, db_names[::2], list(range(10)), list(range(5)))
    assert hard[:, 2].nonzero()[0].tolist() == [3, 4, 5]


@pytest.fixture(scope="module")
def aligned(scene_on_disk, tmp_path_factory):
    """60 frames of a day (``db``) and a darker, noisy copy of them under the same names (``q``)."""
    s = scene_on_disk("two_seasons", (48, 32), 60)
    day = sorted(s[s["names"][0]].glob("*.png"))[:60]
    root = tmp_path_factory.mktemp("aligned")
    rng = np.random.default_rng(0)
    (root / "db").mkdir()
    (root / "q").mkdir()
    for f in day:
        img = cv2.imread(str(f))
        shutil.copy(f, root / "db" / f.name)
        dark = np.clip(img.astype(np.float32) * 0.6 + rng.normal(0, 12, img.shape), 0, 255).astype(np.uint8)
        cv2.imwrite(str(root / "q" / f.name), dark)
    return root


def _run(argv, capsys, stdin=None, monkeypatch=None):
    if stdin is not None:
        monkeypatch.setattr("sys.stdin", io.StringIO(stdin))
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        code = main([str(a) for a in argv] + ["--no-progress"])
    cap = capsys.readouterr()
    return code, cap.out, cap.err + "".join(f"{w.message}\n" for w in said)


def _metrics(out, method):
    return json.loads((out / "metrics.json").read_text())["methods"][method]


FAST = ["--methods", "pairwise", "--preset", "fast"]


@pytest.mark.slow
def test_a_query_of_every_second_file_is_scored_at_the_frames_of_its_names(aligned, tmp_path, capsys):
    (tmp_path / "q2").mkdir()
    for f in sorted((aligned / "q").glob("*.png"))[::2]:
        shutil.copy(f, tmp_path / "q2" / f.name)
    code, _, err = _run(["compare", aligned / "db", tmp_path / "q2", "--out", tmp_path / "o", "--tolerance", 1,
                         "--query-speed", "as-is", *FAST], capsys)
    assert code == 0, err
    assert "database frame of its name" in err
    assert _metrics(tmp_path / "o", "pairwise")["recall_at_1"] >= 0.9


@pytest.mark.slow
def test_videos_at_different_rates_read_at_one_fps_are_scored_by_time(aligned, tmp_path, capsys):
    def video(path, frames, fps):
        w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (48, 32))
        for f in frames:
            w.write(cv2.imread(str(f)))
        w.release()

    video(tmp_path / "db.mp4", sorted((aligned / "db").glob("*.png")), 20.0)
    video(tmp_path / "q.mp4", sorted((aligned / "q").glob("*.png"))[::2], 10.0)  # the same 3 s at half the rate
    code, _, err = _run(["compare", tmp_path / "db.mp4", tmp_path / "q.mp4", "--fps", 10, "--out", tmp_path / "o",
                         "--tolerance", 1, *FAST], capsys)
    assert code == 0, err
    assert "database frame of its time" in err
    assert _metrics(tmp_path / "o", "pairwise")["recall_at_1"] >= 0.9


@pytest.mark.slow
def test_a_resumed_localize_scores_its_frames_as_the_unstopped_run(aligned, tmp_path, capsys, monkeypatch):
    (tmp_path / "q").mkdir()  # names of their own: placed by their numbers, not by name
    paths = []
    for f in sorted((aligned / "q").glob("*.png")):
        paths.append(str(shutil.copy(f, tmp_path / "q" / f"night-{f.name}")))
    code, _, err = _run(["learn", aligned / "db", "--out", tmp_path / "map.npz", "--preset", "fast"], capsys)
    assert code == 0, err
    tol = ["--tolerance", 1]
    code, _, err = _run(["localize", tmp_path / "map.npz", "-", "--out", tmp_path / "full", *tol], capsys,
                        "\n".join(paths) + "\n", monkeypatch)
    assert code == 0, err
    _run(["localize", tmp_path / "map.npz", "-", "--out", tmp_path / "a", "--state-out", tmp_path / "s.npz", *tol],
         capsys, "\n".join(paths[:25]) + "\n", monkeypatch)
    code, _, err = _run(["localize", tmp_path / "s.npz", "-", "--out", tmp_path / "b", *tol], capsys,
                        "\n".join(paths[25:]) + "\n", monkeypatch)
    assert code == 0, err

    def rows(out):
        with open(out / "rshosm-seq" / "matches.csv", newline="") as fh:
            keys = ("query_name", "best_db", "accepted", "right", "true_db")
            return [tuple(r[k] for k in keys) for r in csv.DictReader(fh)]

    full, rest = rows(tmp_path / "full"), rows(tmp_path / "b")
    # the last frames of the first part wait in its state for later ones: the second run answers them first
    done = 25 - LOCALIZE_LAG
    assert len(rest) == 60 - done and rest == full[done:]
    assert any(r[3] == "1" for r in rest)
