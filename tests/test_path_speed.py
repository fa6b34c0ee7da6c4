"""The query's speed along accepted paths (vpr.evaluate.path_speed), and a run that says it."""
import csv
import io
import json
import warnings

import numpy as np
import pytest

from tests.cli import run
from vpr.evaluate import SpeedReader, path_run_speeds, path_runs, path_speed, session_speeds
from vpr.groundtruth import check_speeds


def test_speed_counts_only_long_consistent_accepted_runs():
    fast = np.arange(0, 40, 2)                 # 20 frames moving 2 map frames a frame
    slow = 100 + np.arange(30) // 2            # 30 frames moving half a frame a frame
    short = np.array([500, 501, 502])          # too short to count
    best = np.r_[fast, slow, short]
    accepted = np.ones(best.size, bool)
    v, n = path_speed(best, accepted)
    assert n == 19 + 29
    assert np.isclose(v, (38 + 14) / 48)
    accepted[20:50] = False                    # only the fast run is left
    assert path_speed(best, accepted) == (2.0, 19)


def test_no_speed_without_a_run_of_min_run_frames():
    best = np.arange(9)
    assert path_speed(best, np.ones(9, bool)) == (None, 0)
    assert path_speed(np.r_[best, -1, best], np.ones(19, bool)) == (None, 0)
    jumpy = np.arange(0, 100, 5)               # 5 frames a frame: not one path
    assert path_speed(jumpy, np.ones(jumpy.size, bool)) == (None, 0)


@pytest.mark.parametrize("speed, said, fix", [(1.9, "faster", "vpr learn DB --step 2"), (3.2, "faster", "--step 3"),
                                             (0.55, "slower", "one query frame in 2"), (1.07, None, None),
                                             (0.9, None, None), (0.0, None, None), (None, None, None)])
def test_a_query_at_another_speed_is_said(speed, said, fix):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_speeds({"rshosm-seq": speed})
    lines = [str(w.message) for w in caught]
    if said is None:
        assert lines == []
    else:
        assert len(lines) == 1 and f"driven {said}" in lines[0] and lines[0].startswith("rshosm-seq:")
        assert fix in lines[0], lines[0]


def test_the_speed_read_as_frames_come_is_path_speed_of_the_frames_so_far():
    rng = np.random.default_rng(0)
    for _ in range(50):
        n = int(rng.integers(1, 120))
        best = np.where(rng.random(n) < 0.05, -1, np.cumsum(rng.integers(-1, 4, n)))
        accepted = rng.random(n) > 0.1
        reader = SpeedReader(int(rng.integers(2, 12)))
        for j in range(n):
            reader.step(best[j], accepted[j])
            assert reader.speed == pytest.approx(path_speed(best[:j + 1], accepted[:j + 1], reader.min_run)[0])
            # the run it is on now: the last run of path_runs over the frames so far, where it reaches this frame
            first, last = path_runs(best[:j + 1], accepted[:j + 1], reader.min_run)
            now = last.size and last[-1] == j
            want = (best[j] - best[first[-1]]) / (j - first[-1]) if now else None
            assert reader.run_speed == (pytest.approx(want) if now else None)
        first, last = path_runs(best, accepted, reader.min_run)
        assert (last - first).sum() == path_speed(best, accepted, reader.min_run)[1]
        a, b, v = path_run_speeds(best, accepted, reader.min_run)
        np.testing.assert_array_equal(a, first)
        np.testing.assert_array_equal(b, last)
        np.testing.assert_allclose(v, [(best[j] - best[i]) / (j - i) for i, j in zip(first, last, strict=True)])


def test_a_later_session_is_read_against_the_earlier_ones_accepted_or_not():
    first = np.r_[-1, -1, np.arange(30) - 40]          # session 1 (frames 0..31): onto itself, never read
    second = np.arange(0, 60, 2)                       # session 2 (32..61): 2 frames of session 1 a frame
    third = np.r_[np.arange(40, 55), 70 + np.arange(15)]  # session 3 (62..91): on session 1, then on itself
    best = np.r_[np.maximum(first, -1), second, third]
    assert session_speeds(best, [0, 32, 62]) == [2.0, 1.0]
    assert session_speeds(best, [0]) == []
    assert session_speeds(np.r_[best[:32], np.full(30, -1)], [0, 32]) == [None]


def test_a_speed_is_said_with_the_fix_given():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_speeds({"a": 2.0, "b": 0.5, "c": 3.1}, paths="best paths", fix=None)
        check_speeds({"d": 1.9}, paths="best paths", fix="do this")
    lines = [str(w.message) for w in caught]
    assert len(lines) == 4 and all("along its best paths" in x for x in lines)
    assert "--step 2" in lines[0] and "one query frame in 2" in lines[1] and "--step 3" in lines[2]
    assert lines[3].endswith("do this (research/docs/localize.md)")


def _twice_as_fast(scene_on_disk, tmp_path):
    """(the day traverse, the night traverse, the day's every 2nd frame: the day driven twice as fast)."""
    s = scene_on_disk("two_seasons", (64, 48), 120)
    db, other = s[s["names"][0]], s[s["names"][1]]
    q2 = tmp_path / "every_2nd"
    q2.mkdir()
    for f in sorted(db.iterdir())[::2]:
        (q2 / f.name).symlink_to(f)
    return db, other, q2


@pytest.mark.slow
def test_compare_follows_a_query_driven_twice_as_fast(scene_on_disk, tmp_path, capsys):
    db, other, q2 = _twice_as_fast(scene_on_disk, tmp_path)
    for query, out, how, said in ((q2, "follow", [], "learned again as 2 maps of one frame in 2"),
                                  (q2, "as_is", ["--query-speed", "as-is"], "driven faster"),
                                  (other, "same", [], None)):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            code, _, err = run(["compare", db, query, "--methods", "rshosm-seq", "--out", tmp_path / out, *how],
                               capsys)
        assert code == 0, err
        m = json.loads((tmp_path / out / "metrics.json").read_text())["methods"]["rshosm-seq"]
        lines = [str(w.message) for w in caught if "the same frame rate" in str(w.message)]
        assert (lines != []) == (said is not None) and all(said in x for x in lines), lines
        assert (m["path_speed"] > 1.5) == (said is not None), m["path_speed"]
        assert (m.get("sampling") or {}).get("db_step") == (2 if out == "follow" else None), m
        cfg = json.loads((tmp_path / out / "rshosm-seq" / "config.json").read_text())
        assert cfg["follow_speed"] == (out != "as_is")
        page = (tmp_path / out / "report.html").read_text()
        assert ("matched again against the database&#x27;s 2 maps" in page) == (out == "follow"), out


@pytest.mark.slow
def test_loops_follow_a_later_session_driven_twice_as_fast(scene_on_disk, tmp_path, capsys, monkeypatch):
    s = scene_on_disk("two_seasons", (64, 48), 120)
    db = s[s["names"][0]]
    q2 = tmp_path / "every_2nd"
    q2.mkdir()
    for f in sorted(db.iterdir())[::2]:
        (q2 / f.name).symlink_to(f)
    near = {}
    for how, said in (("follow", "learned again as 2 maps of one frame in 2"), ("as-is", "vpr learn EARLIER")):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            code, _, err = run(["loops", db, q2, "--out", tmp_path / how, "--query-speed", how], capsys)
        assert code == 0, err
        lines = [str(w.message) for w in caught if "session 2" in str(w.message)]
        assert len(lines) == 1 and said in lines[0], lines
        m = json.loads((tmp_path / how / "metrics.json").read_text())["methods"]["rshosm-seq"]
        assert m["session_speeds"][0] > 1.5
        assert (m.get("sampling") or {}).get("sessions", [{}])[0].get("db_step") == (2 if how == "follow" else None)
        page = (tmp_path / how / "report.html").read_text()
        assert ("session 2 moved" in page) == (how == "follow"), how
        with open(tmp_path / how / "rshosm-seq" / "matches.csv", newline="") as f:
            rows = list(csv.DictReader(f))[len(list(db.iterdir())):]
        near[how] = np.mean([r["accepted"] == "1" and abs(int(r["best_db"]) - 2 * j) <= 1 for j, r in enumerate(rows)])
    assert near["follow"] >= 0.9, near  # what following gains is measured in tests/test_query_speed.py
    code, _, err = run(["loops", "-", "--query-speed", "follow", "--out", tmp_path / "online"], capsys)
    assert code == 2 and "--query-speed" in err
    # online, the later session (after a line #session) is said with what follows it, not followed
    lines = [str(f) for f in sorted(db.iterdir())] + ["#session"] + [str(f) for f in sorted(q2.iterdir())]
    monkeypatch.setattr("sys.stdin", io.StringIO("\n".join(lines) + "\n"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code, _, err = run(["loops", "-", "--out", tmp_path / "online"], capsys)
    assert code == 0, err
    said = [line for line in err.splitlines() if "session 2's best frames" in line]
    assert len(said) == 1 and "from frame" in said[0] and "vpr localize map.npz SESSION" in said[0], err
    assert not [w for w in caught if "session 2" in str(w.message)]  # said once, as it was read
    m = json.loads((tmp_path / "online" / "metrics.json").read_text())["methods"]["rshosm-seq"]
    assert m["session_speeds"][0] > 1.5 and "sampling" not in m


@pytest.mark.slow
def test_localize_follows_a_query_driven_twice_as_fast_and_resumes(scene_on_disk, tmp_path, capsys):
    s = scene_on_disk("two_seasons", (64, 48), 120)
    db = s[s["names"][0]]
    frames = sorted(db.iterdir())[::2]
    for name, part in (("q2", frames), ("first", frames[:30]), ("rest", frames[30:])):
        (tmp_path / name).mkdir()
        for f in part:
            (tmp_path / name / f.name).symlink_to(f)
    code, _, err = run(["learn", db, "--out", tmp_path / "map.npz"], capsys)
    assert code == 0, err
    answers = {}
    for how in ("follow", "as-is"):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            code, out, err = run(["localize", tmp_path / "map.npz", tmp_path / "q2", "--out", tmp_path / how,
                                  "--query-speed", how], capsys)
        assert code == 0, err
        m = json.loads((tmp_path / how / "metrics.json").read_text())["methods"]["rshosm-seq"]
        assert ("answered by the map's 2 maps of one frame in 2" in err) == (how == "follow"), err
        assert any("driven faster" in str(w.message) for w in caught) == (how == "as-is")
        assert (m.get("sampling") or {}).get("db_step") == (2 if how == "follow" else None), m
        page = (tmp_path / how / "report.html").read_text()
        assert ("frames answered by the map&#x27;s 2 maps of one frame in 2" in page) == (how == "follow"), how
        answers[how] = [json.loads(x) for x in out.splitlines()]
    near = {h: np.mean([r["accepted"] and abs(r["best_db"] - 2 * r["query"]) <= 1 for r in a if r["query"] >= 9])
            for h, a in answers.items()}  # (no answer is accepted before the query's direction is read)
    assert near["follow"] >= 0.9, near  # what following gains is measured in tests/test_query_speed.py
    # stopped and continued from --state-out: the same answers as one run
    code, first, err = run(["localize", tmp_path / "map.npz", tmp_path / "first", "--out", tmp_path / "a",
                            "--state-out", tmp_path / "state.npz"], capsys)
    assert code == 0, err
    code, rest, err = run(["localize", tmp_path / "state.npz", tmp_path / "rest", "--out", tmp_path / "b"], capsys)
    assert code == 0, err
    key = lambda r: (r["best_db"], r["score"], r["accepted"])  # noqa: E731
    assert [key(json.loads(x)) for x in (first + rest).splitlines()] == [key(r) for r in answers["follow"]]


@pytest.mark.slow
def test_a_single_frame_method_says_nothing_of_a_speed(scene_on_disk, tmp_path, capsys):
    # its best frames form no path: no speed is said of it, no --step advised, at any speed of the query
    db, other, q2 = _twice_as_fast(scene_on_disk, tmp_path)
    for query, out in ((q2, "twice"), (other, "same")):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            code, _, err = run(["compare", db, query, "--methods", "pairwise", "--out", tmp_path / out], capsys)
        assert code == 0, err
        said = [str(w.message) for w in caught if "frame rate" in str(w.message) or "--step" in str(w.message)]
        assert said == [] and "--step" not in err, said
