"""Robot logs as they come off real robots: outages, other encodings, killed recordings, two robots, sessions.

Every faulty log is written here (rosbags for the bags, ``vpr render`` for the
frames); each case checks what is said and what is written.
"""
import csv
import json
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipelines.cli import main
from tests.bags import positions_of, read_folder, write_bag
from vpr.sources import open_source, open_sources


def _run(argv, capsys):
    code = main([str(a) for a in argv] + ["--no-progress"])
    out, err = capsys.readouterr()
    return code, out, err


def _metrics(out: Path) -> dict:
    return json.loads((out / "metrics.json").read_text())


@pytest.fixture(scope="module")
def laps(scene_on_disk):
    s = scene_on_disk("loop_revisits", (48, 36), 240)
    return {"scene": s, "images": read_folder(s["laps"]), "xy": positions_of(s["gt"], "laps")}


@pytest.fixture(scope="module")
def seasons(scene_on_disk):
    s = scene_on_disk("two_seasons", (48, 32), 40)
    return {"scene": s, "day": read_folder(s["summer_day"]), "xy": positions_of(s["gt"], "summer_day")}


LOOSE = ["--preset", "fast", "--exclude", "12", "--method-conf", "rshosm-seq.min_score=10"]


# ------------------------------------------------------------------ outages
@pytest.mark.slow
def test_a_gps_outage_is_said_and_only_leaves_its_frames_out_of_the_metrics(laps, tmp_path, capsys):
    # 1 frame a second; the receiver loses its fix for frames 100..159 (a minute in a tunnel)
    bag = write_bag(tmp_path / "outage.bag", laps["images"], laps["xy"], dt=1.0, odom=False,
                    no_fix=set(range(100, 160)))
    with pytest.warns(UserWarning, match=r"60 of 240 frames have no position \(60 in 1 outage of /gps/fix \(no "
                                         r"position for over 10 s; longest 61\.0 s, from 99\.0 s after its first "
                                         r"sample\), not interpolated across\); not extrapolated: the method sees "
                                         r"them as every frame, and their pairs are left out of the metrics"):
        code, _, err = _run(["loops", bag, "--out", tmp_path / "o", "--gt-topic", "/gps/fix", "--radius", 4,
                             *LOOSE], capsys)
    assert code == 0, err
    code, _, err = _run(["loops", bag, "--out", tmp_path / "plain", *LOOSE], capsys)
    assert code == 0, err
    with_gt, without = (list(csv.DictReader(open(tmp_path / d / "rshosm-seq" / "matches.csv")))
                        for d in ("o", "plain"))
    assert len(with_gt) == len(without) == 240  # the frames of the outage are in the run
    for a, b in zip(with_gt, without, strict=True):  # ground truth only scores
        assert (a["query"], a["best_db"], a["accepted"], a["score"]) == (b["query"], b["best_db"], b["accepted"],
                                                                         b["score"])
    assert any(r["accepted"] == "1" for r in with_gt[100:160])  # the tunnel is a revisit the method still closes
    for r in with_gt:  # a frame without a position, or onto one, is neither right nor wrong
        if r["accepted"] == "1" and (100 <= int(r["query"]) < 160 or 100 <= int(r["best_db"]) < 160):
            assert r["right"] == "", r
    m = _metrics(tmp_path / "o")["methods"]["rshosm-seq"]
    accepted_scored = sum(r["accepted"] == "1" and r["right"] != "" for r in with_gt)
    assert m["n_false"] == sum(r["accepted"] == "1" and r["right"] == "0" for r in with_gt)
    assert accepted_scored > 0


def test_short_gaps_in_the_fixes_are_said_and_an_outage_is_named_by_its_own_start(laps, tmp_path):
    from vpr.groundtruth import GroundTruthSpec, prepare_positions

    # 1 frame and 1 fix a second: 3 fixes with status -1 (a 4 s gap, interpolated across), a 13 s outage from 9 s
    # and a 61 s one from 149 s (the longest, named by its start); an outage is a gap of over 10 intervals here
    no_fix = {50, 51, 52, *range(10, 22), *range(150, 210)}
    bag = write_bag(tmp_path / "gaps.bag", laps["images"], laps["xy"], dt=1.0, odom=False, no_fix=no_fix)
    src = open_source(bag)
    spec = GroundTruthSpec(radius=4.0, topic="/gps/fix")
    with pytest.warns(UserWarning) as said:
        (xy,) = prepare_positions([src], ["sequence"], spec, loops=True)
    text = [str(w.message) for w in said]
    short = [t for t in text if "short gap" in t]
    assert len(short) == 1 and "/gps/fix: 3 frames fall in 1 short gap of its positions (longest 4.0 s, from " \
        "49.0 s after its first sample" in short[0] and "interpolated across" in short[0], text
    outage = [t for t in text if "outage" in t and "short gap" not in t]
    assert len(outage) == 1 and "in 2 outages of /gps/fix" in outage[0] and "longest 61.0 s, from 149.0 s" in \
        outage[0], text
    assert len(xy) == 240 and np.isnan(xy[:, 0]).sum() == 12 + 60 and not np.isnan(xy[50:53]).any()


# ------------------------------------------------------------------ encodings
def test_a_12_bit_camera_keeps_its_contrast(seasons, tmp_path):
    grey = [cv2.cvtColor(im, cv2.COLOR_BGR2GRAY) for im in seasons["day"][:6]]
    twelve = [g.astype(np.uint16) << 4 for g in grey]  # a 12-bit sensor's values in 16-bit words
    bag = write_bag(tmp_path / "mono16.bag", [np.ascontiguousarray(t) for t in twelve], encoding="mono16",
                    gps=False, odom=False)
    frames = list(open_source(bag))
    for f, g in zip(frames, grey, strict=True):
        np.testing.assert_array_equal(f.image[:, :, 0], g)  # not shifted by 8 bits into near black


def test_depth_topics_are_not_taken_for_the_camera(seasons, tmp_path, capsys):
    depth = [np.full((32, 48), 1500 + 10 * k, np.uint16) for k in range(6)]
    both = write_bag(tmp_path / "rgbd.bag", seasons["day"][:6], gps=False, odom=False,
                     more={"/camera/depth/image_raw": (depth, "16UC1")})
    assert open_source(both).topic == "/camera/image_raw"  # the depth topic is not a candidate
    only = write_bag(tmp_path / "depth.bag", depth, encoding="16UC1", gps=False, odom=False,
                     topic="/camera/depth/image_raw")
    code, _, err = _run(["loops", only, "--out", tmp_path / "o"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "/camera/depth/image_raw (16UC1)" in err and "not an appearance camera" in err and "--topic" in err
    assert not (tmp_path / "o").exists()
    src = open_source(only, topic="/camera/depth/image_raw")  # asked for: read
    assert len(list(src)) == 6


def test_compressed_depth_is_read_when_named_and_qoi_is_named_in_the_refusal(seasons, tmp_path, capsys):
    depth = [np.full((32, 48), 1000 * (k + 1), np.uint16) for k in range(4)]
    cd = write_bag(tmp_path / "cd.bag", depth, compressed=True, fmt="16UC1; compressedDepth png", gps=False,
                   odom=False, topic="/depth/compressed")
    code, _, err = _run(["loops", cd, "--out", tmp_path / "o"], capsys)
    assert code == 2 and "/depth/compressed (compressedDepth)" in err
    frames = list(open_source(cd, topic="/depth/compressed"))
    assert len(frames) == 4 and frames[0].image.mean() < frames[-1].image.mean()
    qoi = write_bag(tmp_path / "qoi.bag", seasons["day"][:4], compressed=True, fmt="qoi", gps=False, odom=False)
    code, _, err = _run(["loops", qoi, "--out", tmp_path / "q"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "compressed format 'qoi' is not read: QOI has no decoder in OpenCV" in err


def test_a_bag_without_images_lists_its_topics_and_gt_topic_says_what_it_reads(seasons, tmp_path, capsys):
    bag = write_bag(tmp_path / "cam.bag", seasons["day"][:4], seasons["xy"][:4])
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    with Writer(tmp_path / "imu.bag") as w:
        c = w.add_connection("/imu/temperature", "sensor_msgs/msg/Temperature", typestore=ts)
        T = ts.types["sensor_msgs/msg/Temperature"]
        H, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
        w.write(c, 1, ts.serialize_ros1(T(header=H(seq=0, stamp=Time(sec=0, nanosec=1), frame_id="imu"),
                                            temperature=20.0, variance=0.0), T.__msgtype__))
    code, _, err = _run(["loops", tmp_path / "imu.bag", "--out", tmp_path / "o"], capsys)
    assert code == 2 and "no image topic" in err and "/imu/temperature (sensor_msgs/Temperature, 1)" in err
    code, _, err = _run(["loops", bag, "--out", tmp_path / "o", "--gt-topic", "/camera/image_raw", "--radius", 4],
                        capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert ("--gt-topic: topic /camera/image_raw holds sensor_msgs/Image, not positions (read: NavSatFix" in err
            and "position topics here: /gps/fix, /odom" in err)


# ------------------------------------------------------------------ two robots
@pytest.mark.slow
def test_topics_per_input(seasons, scene_on_disk, tmp_path, capsys):
    night = scene_on_disk("two_seasons", (48, 32), 40)
    a = write_bag(tmp_path / "a.bag", seasons["day"], seasons["xy"], topic="/robot_a/camera/image_raw")
    b = write_bag(tmp_path / "b", read_folder(night["winter_night"]), positions_of(night["gt"], "winter_night"), ros=2,
                  compressed=True, topic="/robot_b/camera/image_raw/compressed")
    with pytest.raises(ValueError, match="--topic: 3 values for 2 inputs"):
        open_sources([a, b], topic=("/x", "/y", "/z"))
    code, _, err = _run(["compare", a, b, "--out", tmp_path / "o", "--topic", "/robot_a/camera/image_raw",
                         "/robot_b/camera/image_raw/compressed", "--gt-topic", "/gps/fix", "/odom", "--radius", 4,
                         "--preset", "fast"], capsys)
    assert code == 0, err
    assert _metrics(tmp_path / "o")["params"]["ground_truth"]["gt_topic"] == ["/gps/fix", "/odom"]
    code, _, err = _run(["compare", a, b, "--out", tmp_path / "p", "--topic", "/robot_a/camera/image_raw"], capsys)
    assert code == 2 and "b: no topic '/robot_a/camera/image_raw'" in err


# ------------------------------------------------------------------ sessions
@pytest.fixture
def two_runs(seasons, scene_on_disk, tmp_path):
    """run1/img and run2/img: a robot's two runs under the usual layout, and one traverse,frame,x,y file for both."""
    s = seasons["scene"]
    for run, traverse in (("run1", "summer_day"), ("run2", "winter_night")):
        (tmp_path / run).mkdir()
        shutil.copytree(s[traverse], tmp_path / run / "img")
    with open(s["gt"]) as fh:
        rows = list(csv.DictReader(fh))
    return tmp_path, rows


def _write_positions(path, rows, names):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["traverse", "frame", "x", "y"])
        for r in rows:
            if r["traverse"] in names:
                w.writerow([names[r["traverse"]], r["frame"], r["x"], r["y"]])
    return path


@pytest.mark.slow  # command-line integration
def test_sessions_named_alike_are_told_apart(two_runs, capsys):
    root, rows = two_runs
    runs = [root / "run1" / "img", root / "run2" / "img"]
    alike = _write_positions(root / "alike.csv", rows, {"summer_day": "img", "winter_night": "img"})
    code, _, err = _run(["loops", *runs, "--out", root / "o", "--gt", alike, "--radius", 4, *LOOSE], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert f"{runs[0]} and {runs[1]} share a name ('img')" in err and "'run1/img', 'run2/img'" in err
    assert not (root / "o").exists()
    apart = _write_positions(root / "apart.csv", rows, {"summer_day": "run1/img", "winter_night": "run2/img"})
    code, _, err = _run(["loops", *runs, "--out", root / "o", "--gt", apart, "--radius", 4, *LOOSE], capsys)
    assert code == 0, err
    pairs = _metrics(root / "o")["methods"]["rshosm-seq"]["sessions"]
    assert [(p["session"], p["onto"]) for p in pairs] == [("run1/img", "run1/img"), ("run2/img", "run1/img"),
                                                          ("run2/img", "run2/img")]
    assert pairs[1]["frames"] > 0  # the second run revisits the first: its rows were not overwritten
    page = (root / "o" / "report.html").read_text()  # the page shows the closures per pair of sessions
    table = page[page.index('<table class="sessions" data-method="rshosm-seq">'):]
    rec = "-" if pairs[1]["recall"] is None else f"{pairs[1]['recall']:.3f}"
    assert f"<td>run2/img</td><td>run1/img</td><td>{pairs[1]['frames']}</td><td>{pairs[1]['accepted']}</td>" in \
        table[:table.index("</table>")] and rec in table[:table.index("</table>")]


def test_the_same_recording_twice_is_refused_as_sessions(two_runs, capsys):
    root, _ = two_runs
    run = root / "run1" / "img"
    for argv in (["loops", run, run, "--out", root / "o"], ["learn", run, run, "--out", root / "map.npz"]):
        code, _, err = _run(argv, capsys)
        assert code == 2 and len(err.strip().splitlines()) == 1
        assert f"{run} is given twice (inputs 1 and 2)" in err
    assert not (root / "o").exists() and not (root / "map.npz").exists()


@pytest.mark.slow  # command-line integration
def test_a_byte_identical_copy_of_a_recording_is_refused_as_a_second_session(laps, two_runs, tmp_path, capsys):
    root, _ = two_runs
    copy = tmp_path / "copy" / "img"
    shutil.copytree(root / "run1" / "img", copy)
    bag = write_bag(tmp_path / "run.bag", laps["images"][:30], gps=False, odom=False)
    shutil.copy(bag, tmp_path / "run_copy.bag")
    for first, second in ((root / "run1" / "img", copy), (bag, tmp_path / "run_copy.bag")):
        code, _, err = _run(["loops", first, second, "--out", tmp_path / "o"], capsys)
        assert code == 2 and len(err.strip().splitlines()) == 1, err
        assert f"{first} and {second} (inputs 1 and 2) hold the same recording, byte for byte" in err
    assert not (tmp_path / "o").exists()
    code, _, err = _run(["loops", root / "run1" / "img", root / "run2" / "img", "--out", tmp_path / "o", *LOOSE],
                        capsys)
    assert code == 0, err  # two recordings of one route are two sessions
    # without ground truth the closures per pair of sessions are still counted, and shown
    m = _metrics(tmp_path / "o")["methods"]["rshosm-seq"]
    pairs = m["sessions"]
    assert [(p["session"], p["onto"]) for p in pairs] == [("run1/img", "run1/img"), ("run2/img", "run1/img"),
                                                          ("run2/img", "run2/img")]
    assert all(p["frames"] is None and p["precision"] is None for p in pairs)
    assert sum(p["accepted"] for p in pairs) == m["n_accepted"]
    assert '<table class="sessions" data-method="rshosm-seq">' in (tmp_path / "o" / "report.html").read_text()


def test_nan_in_a_traverse_positions_file_is_refused_with_its_line(two_runs, capsys):
    root, rows = two_runs
    bad = _write_positions(root / "nan.csv", rows, {"summer_day": "img"})
    lines = bad.read_text().splitlines()
    lines[5] = ",".join(lines[5].split(",")[:2] + ["nan", "0"])
    bad.write_text("\n".join(lines) + "\n")
    s = root / "run1" / "img"
    code, _, err = _run(["loops", s, "--out", root / "o", "--gt", bad, "--radius", 4], capsys)
    assert code == 2 and f"{bad}:6: x, y must be finite numbers, got nan, 0" in err


# ------------------------------------------------------------------ killed recordings
@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_killed_ros2_folder_without_metadata_reads(seasons, tmp_path, storage):
    whole = write_bag(tmp_path / "whole", seasons["day"][:12], seasons["xy"][:12], ros=2, storage=storage)
    (whole / "metadata.yaml").unlink()
    with pytest.warns(UserWarning, match=r"no metadata.yaml \(a ROS 2 recording killed before it wrote it\); read "
                                         r"its 1 storage file \(whole\."):
        src = open_source(whole)
    assert len(list(src)) == 12
    t, _, kind = src.trajectory("/gps/fix")
    assert kind == "latlon" and len(t) == 12


def test_a_cut_mcap_and_an_active_ros1_bag_read_up_to_the_damage(seasons, tmp_path, capsys):
    folder = write_bag(tmp_path / "rec", seasons["day"][:20], seasons["xy"][:20], ros=2, storage="mcap")
    data = next(folder.glob("*.mcap")).read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: int(len(data) * 0.6)])
    with pytest.warns(UserWarning, match=r"cut.mcap: damaged or cut short .*read its \d+ complete messages"):
        src = open_source(tmp_path / "cut.mcap")
    frames = list(src)
    assert 5 < len(frames) < 20
    np.testing.assert_array_equal(frames[3].image, seasons["day"][3])  # CDR messages decoded as they were written
    bag = write_bag(tmp_path / "run.bag", seasons["day"][:20], seasons["xy"][:20])
    active = tmp_path / "run.bag.active"
    active.write_bytes(bag.read_bytes()[: int(bag.stat().st_size * 0.7)])
    with pytest.warns(UserWarning, match=r"run.bag.active: damaged or cut short"):
        code, _, err = _run(["loops", active, "--out", tmp_path / "o", "--exclude", 3, "--preset", "fast"], capsys)
    assert code == 0, err
    assert 5 < len((tmp_path / "o" / "rshosm-seq" / "matches.csv").read_text().splitlines()) - 1 < 20
    salvaged = _metrics(tmp_path / "o")["params"]["salvaged"]["run.bag.active"]  # the run says what it read
    assert salvaged["messages_read"] > 5 and salvaged["damage"]
    page = (tmp_path / "o" / "report.html").read_text()  # a bag's frames captioned by their time in the run
    assert re.search(r"frame \d+ · \d+\.\d s<", page)
    assert not [c for c in re.findall(r"<figcaption>([^<]*)<", page) if "@" in c]  # the full name is the tooltip


# ------------------------------------------------------------------ time and sampling
@pytest.mark.slow
def test_time_where_there_are_stamps(seasons, tmp_path, capsys):
    bag = write_bag(tmp_path / "two_hz.bag", seasons["day"], seasons["xy"], dt=0.5)  # a 2 Hz camera
    with pytest.warns(UserWarning, match=r"--fps 10 is above its frame rate \(2 frames/s\): every frame is read"):
        assert len(open_source(bag, fps=10).indices()) == 40
    code, _, err = _run(["loops", bag, "--out", tmp_path / "o", "--exclude", "10s", "--preset", "fast"], capsys)
    assert code == 0, err
    assert _metrics(tmp_path / "o")["params"]["exclude"] == 20  # 10 s at 2 frames a second


@pytest.mark.slow
def test_a_drive_without_revisits_counts_its_false_closures(laps, tmp_path, capsys):
    # a drive along a street that looks the same twice (the frames repeat), 3 m a frame: no revisit
    straight = np.stack([3.0 * np.arange(80), np.zeros(80)], axis=1)
    bag = write_bag(tmp_path / "drive.bag", laps["images"][:40] * 2, straight, dt=0.5)
    with pytest.warns(UserWarning, match=r"no frame is within 2 of a frame at least --exclude 5 frames earlier; "
                                         r"there is no loop closure to find: every closure accepted is false"):
        code, _, err = _run(["loops", bag, "--out", tmp_path / "o", "--gt-topic", "/gps/fix", "--radius", 2,
                             "--every", "2m", "--exclude", 5, "--preset", "fast", "--method-conf",
                             "rshosm-seq.min_score=10"], capsys)
    assert code == 0, err
    m = _metrics(tmp_path / "o")["methods"]["rshosm-seq"]
    n = _metrics(tmp_path / "o")["params"]["n_frames"]
    assert m["revisits"] == 0 and m["n_false"] == m["n_accepted"] > 0 and m["recall_accepted"] is None
    assert m["false_per_1000"] == pytest.approx(1000 * m["n_accepted"] / n)
    assert m["precision_accepted"] == 0.0 and "ap" not in m


# ------------------------------------------------------------------ sessions online
class _Stopped:
    """Lines of stdin, then a Ctrl-C as the next one is awaited (a robot's supervisor stopping the run)."""

    def __init__(self, lines):
        self.lines = lines

    def __iter__(self):
        yield from (line + "\n" for line in self.lines)
        raise KeyboardInterrupt


@pytest.mark.slow
def test_online_sessions_are_said_reported_and_resumed_without_a_gap_or_a_repeat(laps, tmp_path, capsys,
                                                                                 monkeypatch):
    paths = sorted(str(p) for p in laps["scene"]["laps"].glob("*.png"))
    lines = paths[:120] + ["#session"] + paths[120:]
    gt = ["--gt", laps["scene"]["gt"], "--radius", 4]
    monkeypatch.setattr("sys.stdin", _Stopped(lines[:126]))  # 5 frames of the second session read, then a stop
    code = main(["loops", "-", "--out", str(tmp_path / "a"), "--state-out", str(tmp_path / "s.npz"),
                 "--no-progress"])
    _, err = capsys.readouterr()
    assert code == 130
    assert "#session (input line 121): the frames that follow are a new run" in err
    # the first frames of a later session wait in the causal encoder: said, with where to go on
    waiting = json.loads((tmp_path / "a" / "metrics.json").read_text())["methods"]["rshosm-seq"]["waiting"]
    assert [Path(w).name for w in waiting] == [f"{k:06d}.png" for k in range(120, 125)]
    assert f"5 frames read ({waiting[0]} .. {waiting[-1]}) wait in {tmp_path / 's.npz'} for later frames" in err
    assert "feed it from input line 127" in err
    monkeypatch.setattr("sys.stdin", _Lines(lines[126:]))
    assert main(["loops", "-", "--out", str(tmp_path / "b"), "--resume", str(tmp_path / "s.npz"),
                 "--no-progress"]) == 0
    done = [r for f in ("a", "b") for r in csv.DictReader(open(tmp_path / f / "rshosm-seq" / "matches.csv"))]
    assert sorted(int(r["query"]) for r in done) == list(range(240))  # every frame answered once
    monkeypatch.setattr("sys.stdin", _Lines(lines))
    assert main(["loops", "-", "--out", str(tmp_path / "whole"), *LOOSE, *map(str, gt), "--no-progress"]) == 0
    pairs = _metrics(tmp_path / "whole")["methods"]["rshosm-seq"]["sessions"]
    assert [(p["session"], p["onto"]) for p in pairs] == [("1", "1"), ("2", "1"), ("2", "2")]
    assert pairs[1]["frames"] > 0


class _Lines(_Stopped):
    def __iter__(self):
        yield from (line + "\n" for line in self.lines)


# ------------------------------------------------------------------ sampling of the map and the query
@pytest.mark.slow
def test_a_query_every_4m_against_a_full_rate_map_keeps_its_precision(scene_on_disk, tmp_path, capsys):
    s = scene_on_disk("speed_change", (64, 48), 240)  # 400 m: a frame every 1.7 m
    gt = ["--gt", s["gt"], "--radius", 5]
    # pixels alone (--preset fast): the frames kept must pair one to one, the encoder does not rescue a drift
    code, _, err = _run(["learn", s["slow"], "--out", tmp_path / "map.npz", "--gt", s["gt"], "--preset", "fast"],
                        capsys)
    assert code == 0, err
    with pytest.warns(UserWarning, match=r"the map was learned every 1.7 m of travel and the query comes every 4 m: "
                                         r"the map is learned again one frame per 4 m \(\d+ of 240 frames\)"):
        code, _, err = _run(["localize", tmp_path / "map.npz", s["fast"], "--out", tmp_path / "q", *gt,
                             "--every", "4m"], capsys)
    assert code == 0, err
    m = _metrics(tmp_path / "q")["methods"]["rshosm-seq"]
    assert m["frames"] < 120 and m["n_accepted"] > 0.9 * m["frames"] and m["precision_accepted"] >= 0.99
    # a map learned every 4 m and a query with positions: the query is sampled alike
    code, _, err = _run(["learn", s["slow"], "--out", tmp_path / "map4.npz", "--gt", s["gt"], "--every", "4m",
                         "--preset", "fast"], capsys)
    assert code == 0, err
    with pytest.warns(UserWarning, match=r"the map was learned one frame per 4 m of travel: the query is sampled so "
                                         r"too \(--every 4m\)"):
        code, _, err = _run(["localize", tmp_path / "map4.npz", s["fast"], "--out", tmp_path / "r", *gt], capsys)
    assert code == 0, err
    r = _metrics(tmp_path / "r")["methods"]["rshosm-seq"]
    assert r["frames"] == m["frames"] and r["n_accepted"] > 0.9 * r["frames"] and r["precision_accepted"] >= 0.99


@pytest.mark.slow
def test_a_map_and_a_query_at_frame_rates_four_times_apart_keep_their_precision(scene_on_disk, tmp_path, capsys):
    s = scene_on_disk("speed_change", (64, 48), 240)
    img, xy = read_folder(s["slow"]), positions_of(s["gt"], "slow")
    gt = ["--gt-topic", "/gps/fix", "--radius", 5]
    full = write_bag(tmp_path / "full.bag", img, xy, dt=0.2, odom=False)  # 5 frames/s
    sparse = write_bag(tmp_path / "sparse.bag", img[1::4], xy[1::4], dt=0.8, odom=False)  # the same drive, 1.25
    with pytest.warns(UserWarning, match=r"the map's frames came at 5 per second and the query's come at 1.25: the "
                                         r"map is learned again from one frame in 4 \(60 of 240\)"):
        code, _, err = _run(["localize", full, sparse, "--out", tmp_path / "a", *gt], capsys)
    assert code == 0, err
    a = _metrics(tmp_path / "a")["methods"]["rshosm-seq"]
    assert a["frames"] == 60 and a["n_accepted"] > 40 and a["precision_accepted"] >= 0.95  # 0.40 of 5 unchanged
    code, _, err = _run(["learn", write_bag(tmp_path / "slow_map.bag", img[::4], xy[::4], dt=0.8, odom=False),
                         "--out", tmp_path / "map.npz", "--gt-topic", "/gps/fix"], capsys)
    assert code == 0, err
    query = write_bag(tmp_path / "query.bag", img[1:], xy[1:], dt=0.2, odom=False)
    with pytest.warns(UserWarning, match=r"the query is read at the map's rate \(--fps 1.25\)"):
        code, _, err = _run(["localize", tmp_path / "map.npz", query, "--out", tmp_path / "b", *gt], capsys)
    assert code == 0, err
    b = _metrics(tmp_path / "b")["methods"]["rshosm-seq"]
    assert 55 <= b["frames"] <= 60 and b["precision_accepted"] >= 0.95  # 0.72 at every frame unchanged
    with pytest.warns(UserWarning, match=r"full.bag comes at 5 frames per second and .*sparse.bag at 1.25: a "
                                         r"sequence of one moves 4 frames per frame of the other"):
        code, _, err = _run(["compare", full, sparse, "--out", tmp_path / "c", "--methods", "pairwise", *gt], capsys)
    assert code == 0, err


@pytest.mark.slow
def test_a_map_at_4_hz_and_a_query_at_2_hz_are_said_and_made_to_agree(scene_on_disk, tmp_path, capsys):
    s = scene_on_disk("speed_change", (64, 48), 240)
    img, xy = read_folder(s["slow"]), positions_of(s["gt"], "slow")
    gt = ["--gt-topic", "/gps/fix", "--radius", 5]
    fast = write_bag(tmp_path / "map.bag", img, xy, dt=0.25, odom=False)  # 4 frames/s
    slow = write_bag(tmp_path / "query.bag", img[1::2], xy[1::2], dt=0.5, odom=False)  # the same drive at 2
    with pytest.warns(UserWarning, match=r"the map's frames came at 4 per second and the query's come at 2: the "
                                         r"map is learned again from one frame in 2 \(120 of 240\)"):
        code, _, err = _run(["localize", fast, slow, "--out", tmp_path / "a", *gt], capsys)
    assert code == 0, err
    a = _metrics(tmp_path / "a")["methods"]["rshosm-seq"]
    assert a["frames"] == 120 and a["precision_accepted"] >= 0.99 and a["recall_accepted"] >= 0.9
    with pytest.warns(UserWarning, match=r"map.bag comes at 4 frames per second and .*query.bag at 2: a sequence of "
                                         r"one moves 2 frames per frame of the other"):
        code, _, err = _run(["loops", fast, slow, "--out", tmp_path / "s", "--exclude", 12, "--preset", "fast"],
                            capsys)
    assert code == 0, err


def test_frame_numbers_are_not_times(tmp_path):
    from vpr.sources.files import name_time

    assert name_time("000042") is None and name_time("frame1") is None  # numbered frames have no frame rate
    assert name_time("1305031102.175304") == 1305031102.175304  # TUM RGB-D
    assert name_time("1700000000250") == 1700000000.25 and name_time("1700000000250000000") == 1700000000.25
    for name, rate in (("numbered", None), ("timed", 4.0)):
        (tmp_path / name).mkdir()
        for k in range(5):
            stem = f"{k:06d}" if name == "numbered" else f"{1700000000 + 0.25 * k:.6f}"
            cv2.imwrite(str(tmp_path / name / f"{stem}.png"), np.full((8, 8, 3), 40 * k, np.uint8))
        assert open_source(tmp_path / name).rate() == rate


def test_a_negative_distance_is_one_line(two_runs, capsys):
    root, _ = two_runs
    code, _, err = _run(["loops", root / "run1" / "img", "--out", root / "o", "--every", "-1m"], capsys)
    assert code == 2 and err.strip() == "vpr loops: error: --every must be a distance in metres like 2m, got '-1m'"
