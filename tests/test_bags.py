"""Robot logs in: ROS bags as sources, positions from their topics, trajectories, names, EXIF, --every.

Bags are written here with rosbags (ROS 1 and ROS 2, raw and compressed images,
NavSatFix and Odometry) from rendered traverses; the same frames from a folder
with a positions file must give the same metrics.
"""
import csv
import json
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipelines.args import parse_every
from pipelines.cli import main
from tests.bags import T0, metres_to_latlon, read_folder, write_bag
from vpr.groundtruth import trajectories as tr
from vpr.sources import BagSource, open_source

N = 40


def _positions(gt_csv, traverse) -> np.ndarray:
    with open(gt_csv) as fh:
        rows = [r for r in csv.DictReader(fh) if r["traverse"] == traverse]
    return np.array([(float(r["x"]), float(r["y"])) for r in sorted(rows, key=lambda r: int(r["frame"]))])


@pytest.fixture(scope="module")
def seasons(scene_on_disk, tmp_path_factory):
    s = scene_on_disk("two_seasons", (48, 32), N)
    out = tmp_path_factory.mktemp("bags")
    day, night = s["summer_day"], s["winter_night"]
    xy_d, xy_n = _positions(s["gt"], "summer_day"), _positions(s["gt"], "winter_night")
    return {"scene": s, "day": day, "night": night, "xy_day": xy_d, "xy_night": xy_n,
            "day_bag": write_bag(out / "day.bag", read_folder(day), xy_d),
            "night_bag": write_bag(out / "night", read_folder(night), xy_n, ros=2, compressed=True),
            "out": out}


def _run(argv, capsys):
    code = main([str(a) for a in argv] + ["--no-progress"])
    out, err = capsys.readouterr()
    return code, out, err


def _metrics(out: Path, method: str) -> dict:
    m = json.loads((out / "metrics.json").read_text())["methods"][method]
    return {k: m[k] for k in ("ap", "recall_at_1", "recall_at_100p", "n_accepted", "precision_accepted")}


# ------------------------------------------------------------------ the bag as a source
@pytest.mark.parametrize("kind", ["ros1-rgb8", "ros1-mono8", "ros2-sqlite-bgr8", "ros2-mcap-compressed",
                                  "mcap-file"])
def test_a_bag_reads_the_frames_a_folder_holds(seasons, tmp_path, kind):
    images = read_folder(seasons["day"])[:8]
    if kind == "ros1-rgb8":
        path = write_bag(tmp_path / "a.bag", images)
    elif kind == "ros1-mono8":
        path = write_bag(tmp_path / "a.bag", images, encoding="mono8")
    elif kind == "ros2-sqlite-bgr8":
        path = write_bag(tmp_path / "a", images, ros=2, encoding="bgr8")
    else:
        path = write_bag(tmp_path / "a", images, ros=2, storage="mcap", compressed=True)
        if kind == "mcap-file":
            path = next(path.glob("*.mcap"))
    src = open_source(path)
    assert isinstance(src, BagSource) and src.topic == "/camera/image_raw"
    frames = list(src)
    assert [f.index for f in frames] == list(range(8))
    assert frames[1].name == f"/camera/image_raw@{int(T0)}.100000000"
    for f, img in zip(frames, images, strict=True):
        want = cv2.cvtColor(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), cv2.COLOR_GRAY2BGR) if "mono" in kind else img
        np.testing.assert_array_equal(f.image, want)
    np.testing.assert_allclose(src.stamps(), T0 + 0.1 * np.arange(8), atol=1e-6)


@pytest.mark.parametrize("ros", [1, 2])
def test_frames_of_a_bag_are_read_again_on_from_the_last(seasons, tmp_path, monkeypatch, ros):
    from vpr.sources import frame_reader

    images = read_folder(seasons["day"])[:30]
    src = open_source(write_bag(tmp_path / ("a.bag" if ros == 1 else "a"), images, ros=ros), step=2)
    starts = []
    real = src.iter_range
    monkeypatch.setattr(src, "iter_range", lambda a, b: starts.append(a) or real(a, b))
    image = frame_reader([src], [src.indices()])
    for j in (3, 4, 5, 9, 1, 2, 14):  # on, on, on, on; behind: a second read, on from it
        np.testing.assert_array_equal(image(j), images[2 * j])
    assert starts == [3, 1]


def test_fps_samples_a_bag_by_time(seasons, tmp_path):
    path = write_bag(tmp_path / "a.bag", read_folder(seasons["day"])[:20])  # 10 frames a second
    assert open_source(path, fps=2).indices() == [0, 5, 10, 15]
    assert open_source(path, step=3, max_frames=3).indices() == [0, 3, 6]


def test_bad_bags_are_one_line(seasons, tmp_path, capsys):
    images = read_folder(seasons["day"])[:6]
    (tmp_path / "text.bag").write_text("not a bag")
    with pytest.raises(ValueError, match="text.bag: not a readable ROS bag"):
        open_source(tmp_path / "text.bag")
    two = write_bag(tmp_path / "two.bag", images, extra_image_topic="/camera/depth")
    with pytest.raises(ValueError, match=r"2 image topics \(/camera/depth \(0 messages\), /camera/image_raw \(6 "
                                         r"messages\)\); name one with --topic"):
        open_source(two)
    with pytest.raises(ValueError, match=r"no topic '/cam'; topics: /camera/depth .*/camera/image_raw"):
        open_source(two, topic="/cam")
    odd = write_bag(tmp_path / "odd.bag", [np.zeros((4, 4), np.float64)] * 2, encoding="64FC1")
    with pytest.raises(ValueError, match="image encoding '64FC1' is not read"):
        open_source(odd)
    code, _, err = _run(["loops", tmp_path / "text.bag", "--out", tmp_path / "o"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "text.bag" in err
    code, _, err = _run(["compare", seasons["day"], seasons["night"], "--out", tmp_path / "o", "--topic", "/x"],
                        capsys)
    assert code == 2 and "--topic applies to ROS bags" in err


def test_a_cut_ros1_bag_reads_what_is_complete(seasons, tmp_path):
    path = write_bag(tmp_path / "a.bag", read_folder(seasons["day"])[:20], seasons["xy_day"][:20])
    data = path.read_bytes()
    (tmp_path / "cut.bag").write_bytes(data[: int(len(data) * 0.6)])
    with pytest.warns(UserWarning, match=r"cut.bag: damaged or cut short .*read its \d+ complete messages"):
        src = open_source(tmp_path / "cut.bag")
    n = len(src.indices())
    assert 5 < n < 20
    assert [f.index for f in src] == list(range(n))


@pytest.mark.slow  # command-line integration
def test_empty_compressed_frames_are_skipped_everywhere(seasons, tmp_path, capsys):
    images = read_folder(seasons["day"])[:16]
    bag = write_bag(tmp_path / "drops.bag", images, compressed=True, gps=False, odom=False, empty={3, 9})
    first = write_bag(tmp_path / "first.bag", images, compressed=True, gps=False, odom=False, empty={0})
    with pytest.warns(UserWarning, match=r"empty compressed image \(png, 0 bytes\)"):
        assert [f.index for f in open_source(bag)] == [i for i in range(16) if i not in (3, 9)]
    code, _, err = _run(["loops", bag, "--out", tmp_path / "loops", "--exclude", 2], capsys)
    assert code == 0, err
    skipped = json.loads((tmp_path / "loops" / "metrics.json").read_text())["params"]["skipped"]
    assert [name for name, _ in skipped] == [f"/camera/image_raw@{int(T0)}.{i}00000000" for i in (3, 9)]
    with pytest.warns(UserWarning, match=r"1 of the frames could not be read and are not in the map \(first: "
                                         r"/camera/image_raw@\d+\.0+: empty compressed image"):
        code, _, err = _run(["learn", first, "--out", tmp_path / "map.npz", "--preset", "fast"], capsys)
    assert code == 0, err
    code, _, err = _run(["localize", tmp_path / "map.npz", bag, "--out", tmp_path / "loc"], capsys)
    assert code == 0, err
    rows = (tmp_path / "loc" / "rshosm-seq" / "matches.csv").read_text().splitlines()
    assert len(rows) == 1 + 14


# ------------------------------------------------------------------ positions
def test_gt_topic_navsatfix_and_odometry_give_the_rendered_positions(seasons):
    src = open_source(seasons["day_bag"])
    for topic in ("/gps/fix", "/odom"):
        t, values, kind = src.trajectory(topic)
        xy = tr.latlon_to_metres(values[:, 0], values[:, 1]) if kind == "latlon" else values
        got, why = tr.positions_at(src.stamps(), t, xy)
        assert (why == 0).all()
        want = seasons["xy_day"] - (seasons["xy_day"][0] if kind == "latlon" else 0)
        np.testing.assert_allclose(got, want, atol=0.01)


def test_positions_are_interpolated_at_frame_times_never_extrapolated():
    xy, why = tr.positions_at([0.5, 1.5, 3.0, -1.0], [0.0, 1.0, 2.0], [[0, 0], [10, 0], [10, 10]])
    np.testing.assert_allclose(xy[:2], [[5, 0], [10, 5]])
    assert why.tolist() == [0, 0, 1, 1] and np.isnan(xy[2:]).all()


def test_positions_are_not_interpolated_across_an_outage():
    t = np.r_[np.arange(0.0, 10.0), np.arange(70.0, 80.0)]  # 1 Hz, then a minute without a fix
    xy, why = tr.positions_at([5.5, 30.0, 69.5, 75.0], t, np.stack([t, 0 * t], axis=1))
    assert why.tolist() == [0, 2, 2, 0] and np.isnan(xy[1:3]).all()
    np.testing.assert_allclose(xy[[0, 3], 0], [5.5, 75.0])
    np.testing.assert_allclose(tr.outages(t), [[9.0, 70.0]])


@pytest.mark.slow
def test_frames_outside_the_gps_span_are_said_and_left_out_of_the_metrics_only(laps, tmp_path, capsys):
    late = write_bag(tmp_path / "late.bag", read_folder(laps["scene"]["laps"]), laps["xy"], odom=False, pos_start=10)
    n = len(laps["xy"])
    with pytest.warns(UserWarning, match=rf"10 of {n} frames have no position \(10 outside the time span of "
                                         r"/gps/fix\); not extrapolated: the method sees them"):
        code, _, err = _run(["loops", late, "--out", tmp_path / "o", "--gt-topic", "/gps/fix", "--radius", 4,
                             "--preset", "fast", "--exclude", 12], capsys)
    assert code == 0, err
    doc = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert doc["params"]["n_frames"] == n  # ground truth only scores: every frame is in the run
    with open(tmp_path / "o" / "rshosm-seq" / "matches.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert rows[0]["query_name"] == f"/camera/image_raw@{int(T0)}.000000000"
    assert all(r["right"] == "" for r in rows[:10])  # no position: neither right nor wrong


def test_tum_kitti_names_and_exif_formats(tmp_path):
    # TUM: images named by their time, a trajectory associated by time
    folder = tmp_path / "tum"
    folder.mkdir()
    for k in range(5):
        cv2.imwrite(str(folder / f"{1305031102.0 + 0.5 * k:.6f}.png"), np.full((8, 8, 3), 40 * k, np.uint8))
    (tmp_path / "traj.txt").write_text("# timestamp tx ty tz qx qy qz qw\n" + "".join(
        f"{1305031102.0 + k} {2.0 * k} 0 0 0 0 0 1\n" for k in range(3)))
    src = open_source(folder)
    assert tr.trajectory_format(tmp_path / "traj.txt") == "tum"
    t, xyz = tr.load_tum(tmp_path / "traj.txt")
    xy, why = tr.positions_at(src.stamps(), t, xyz)
    np.testing.assert_allclose(xy[:, 0], [0, 1, 2, 3, 4])
    assert (why == 0).all()
    # KITTI: one 3x4 pose a line, translation last
    (tmp_path / "poses.txt").write_text("".join(f"1 0 0 {k} 0 1 0 0 0 0 1 {2 * k}\n" for k in range(4)))
    assert tr.trajectory_format(tmp_path / "poses.txt") == "kitti"
    np.testing.assert_allclose(tr.load_kitti(tmp_path / "poses.txt")[2], [2, 0, 4])
    # UTM in names
    names = ["@0543256.96@4178906.85@10@S@037.75468@-122.41543@@@@@@pitch1_yaw1@.jpg", "x/@5.5@6.25@.png"]
    np.testing.assert_allclose(tr.utm_from_names(names), [[543256.96, 4178906.85], [5.5, 6.25]])
    with pytest.raises(ValueError, match="no UTM coordinates"):
        tr.utm_from_names(["plain.png"])
    # EXIF GPS of a phone photo
    from PIL import Image

    img = Image.fromarray(np.zeros((8, 8, 3), np.uint8))
    exif = Image.Exif()
    exif[0x8825] = {1: "N", 2: (48.0, 8.0, 13.2), 3: "E", 4: (11.0, 34.0, 30.0)}
    img.save(tmp_path / "photo.jpg", exif=exif)
    img.save(tmp_path / "bare.jpg")
    latlon, missing = tr.exif_positions([tmp_path / "photo.jpg", tmp_path / "bare.jpg"])
    np.testing.assert_allclose(latlon[0], [48 + 8 / 60 + 13.2 / 3600, 11 + 34 / 60 + 30 / 3600])
    assert missing == [1]


def test_every_keeps_one_frame_per_distance_of_travel():
    # 10 frames standing still at a traffic light, then 1 m a frame
    xy = np.r_[np.zeros((10, 2)), np.c_[np.arange(1, 11), np.zeros(10)]]
    assert tr.every(xy, 2.0).tolist() == [0, 11, 13, 15, 17, 19]
    assert parse_every("2m") == 2.0 and parse_every("0.5") == 0.5
    with pytest.raises(ValueError, match="--every"):
        parse_every("2 miles")


def test_every_keeps_frames_of_two_traverses_that_pair_one_to_one():
    # one 400 m route at 1.7 m a frame, and again at steps of 1 to 3 m: the k-th frames kept stay together
    slow = np.c_[np.arange(0, 400, 1.7), np.zeros(236)]
    x = np.r_[0.0, np.cumsum(np.resize([1.0, 1.3, 2.9, 3.0, 2.2], 200))]
    fast = np.c_[x[x < 400], np.zeros((x < 400).sum())]
    a, b = tr.every(slow, 4.0), tr.every(fast, 4.0)
    n = min(a.size, b.size)
    assert abs(a.size - b.size) <= 1 and n >= 95
    # within half a frame step of k * 4 m each, so within (1.7 + 3.0) / 2 m of each other
    assert np.abs(slow[a[:n], 0] - 4.0 * np.arange(n)).max() <= 1.7 / 2 + 1e-9
    assert np.abs(fast[b[:n], 0] - 4.0 * np.arange(n)).max() <= 3.0 / 2 + 1e-9
    # a frame nearest two marks (steps longer than the distance) is kept once
    assert tr.every(fast, 1.0).tolist() == list(range(len(fast)))


# ------------------------------------------------------------------ through the commands
@pytest.mark.slow
def test_compare_of_two_bags_equals_the_folders_with_a_positions_file(seasons, tmp_path, capsys):
    fast = ["--preset", "fast", "--methods", "rshosm-seq,pairwise"]
    code, _, err = _run(["compare", seasons["day_bag"], seasons["night_bag"], "--out", tmp_path / "bag",
                         "--gt-topic", "/gps/fix", "--radius", 3, "--gt-soft", 10, *fast], capsys)
    assert code == 0, err
    code, _, err = _run(["compare", seasons["day"], seasons["night"], "--out", tmp_path / "folder",
                         "--gt", seasons["scene"]["gt"], "--radius", 3, "--gt-soft", 10, *fast], capsys)
    assert code == 0, err
    for m in ("rshosm-seq", "pairwise"):
        assert _metrics(tmp_path / "bag", m) == pytest.approx(_metrics(tmp_path / "folder", m))
    with open(tmp_path / "bag" / "rshosm-seq" / "matches.csv") as fh:
        first = next(csv.DictReader(fh))
    assert first["query_name"] == f"/camera/image_raw@{int(T0)}.000000000"
    code, _, err = _run(["compare", seasons["day_bag"], seasons["night_bag"], "--out", tmp_path / "odom",
                         "--gt-topic", "/odom", "--radius", 3, "--gt-soft", 10, *fast], capsys)
    assert code == 0, err
    assert _metrics(tmp_path / "odom", "pairwise") == pytest.approx(_metrics(tmp_path / "folder", "pairwise"))


@pytest.fixture(scope="module")
def laps(scene_on_disk, tmp_path_factory):
    s = scene_on_disk("loop_revisits", (48, 36), 240)
    xy = _positions(s["gt"], "laps")
    return {"scene": s, "xy": xy, "bag": write_bag(tmp_path_factory.mktemp("lapbag") / "laps.bag",
                                                  read_folder(s["laps"]), xy)}


@pytest.mark.slow
def test_loops_of_a_bag_equal_the_folder_with_positions(laps, tmp_path, capsys):
    loose = ["--preset", "fast", "--exclude", "12", "--method-conf", "rshosm-seq.min_score=10"]
    code, _, err = _run(["loops", laps["bag"], "--out", tmp_path / "bag", "--gt-topic", "/odom", "--radius", 4,
                         "--gt-soft", 8, *loose], capsys)
    assert code == 0, err
    code, _, err = _run(["loops", laps["scene"]["laps"], "--out", tmp_path / "folder", "--gt", laps["scene"]["gt"],
                         "--radius", 4, "--gt-soft", 8, *loose], capsys)
    assert code == 0, err
    a, b = _metrics(tmp_path / "bag", "rshosm-seq"), _metrics(tmp_path / "folder", "rshosm-seq")
    assert a == pytest.approx(b)
    assert a["n_accepted"] > 20


@pytest.mark.slow
def test_localize_with_positions_from_the_bags_equals_the_folders(seasons, tmp_path, capsys):
    gt_bag = ["--gt-topic", "/gps/fix", "--radius", 3, "--gt-soft", 10]
    code, _, err = _run(["localize", seasons["day_bag"], seasons["night_bag"], "--out", tmp_path / "bag",
                         "--preset", "fast", *gt_bag], capsys)
    assert code == 0, err
    code, _, err = _run(["localize", seasons["day"], seasons["night"], "--out", tmp_path / "folder",
                         "--preset", "fast", "--gt", seasons["scene"]["gt"], "--radius", 3, "--gt-soft", 10], capsys)
    assert code == 0, err
    assert _metrics(tmp_path / "bag", "rshosm-seq") == pytest.approx(_metrics(tmp_path / "folder", "rshosm-seq"))
    # a map learned with its positions, then localised against
    code, _, err = _run(["learn", seasons["day_bag"], "--out", tmp_path / "map.npz", "--preset", "fast",
                         "--gt-topic", "/gps/fix"], capsys)
    assert code == 0, err
    code, _, err = _run(["localize", tmp_path / "map.npz", seasons["night_bag"], "--out", tmp_path / "map", *gt_bag],
                        capsys)
    assert code == 0, err
    assert _metrics(tmp_path / "map", "rshosm-seq") == pytest.approx(_metrics(tmp_path / "bag", "rshosm-seq"))


@pytest.mark.slow
def test_every_two_metres_through_loops(laps, tmp_path, capsys):
    code, _, err = _run(["loops", laps["bag"], "--out", tmp_path / "o", "--gt-topic", "/odom", "--radius", 4,
                         "--every", "3m", "--preset", "fast", "--exclude", 5], capsys)
    assert code == 0, err
    kept = json.loads((tmp_path / "o" / "metrics.json").read_text())["params"]["n_frames"]
    step = np.linalg.norm(np.diff(laps["xy"], axis=0), axis=1).mean()
    assert kept < len(laps["xy"]) * step / 3 * 1.3 and kept < len(laps["xy"])


def test_exif_needs_a_radius_names_default_to_the_fields_and_every_needs_positions(seasons, tmp_path, capsys):
    code, _, err = _run(["compare", seasons["day"], seasons["night"], "--out", tmp_path / "o", "--gt", "exif"],
                        capsys)
    assert code == 2 and "--gt exif needs --radius" in err
    # --gt names without --radius: the field's 25 m; these names hold no UTM, said naming the file
    code, _, err = _run(["compare", seasons["day"], seasons["night"], "--out", tmp_path / "o", "--gt", "names"],
                        capsys)
    assert code == 2 and "no UTM coordinates in the name" in err and not (tmp_path / "o").exists()
    code, _, err = _run(["compare", seasons["day"], seasons["night"], "--out", tmp_path / "o", "--every", "2m"],
                        capsys)
    assert code == 2 and "--every needs the frames' positions" in err
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        code, _, err = _run(["compare", seasons["day"], seasons["night"], "--out", tmp_path / "o", "--gt-topic",
                             "/gps/fix", "--radius", 3], capsys)
    assert code == 2 and "is not a ROS bag" in err
    assert metres_to_latlon(np.zeros((1, 2)))[0, 0] == pytest.approx(48.137)
