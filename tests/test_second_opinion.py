"""The geometric second opinion on loop closures: a decider around the loop rule, where geometry can see."""
from pathlib import Path

import cv2
import numpy as np
import pytest

from vpr import sdr
from vpr.types import Decision
from vpr.verify import OpinionConf, second_opinion


def _textures(n, size=(240, 320), seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        img = cv2.GaussianBlur(rng.integers(0, 255, (*size, 3), dtype=np.uint8), (0, 0), 1.5)
        out.append(cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX))
    return out


def _stream(n=60, back=40):
    """Frames ``back..n-1`` show again what frames ``0..`` showed; the loop rule found them but accepted none."""
    imgs = _textures(back)
    imgs += [np.roll(imgs[j - back], 3, axis=1) for j in range(back, n)]  # seen again, shifted a little
    best = np.r_[np.full(back, -1), np.arange(n - back)]
    return imgs, best, sdr.random_sdrs(n, 256, 20, seed=0)


def _run(images, best, x, conf=None):
    d = Decision(best, np.zeros(best.size), np.zeros(best.size, bool))
    return second_opinion(d, lambda j: images[j], x, back=4, ahead=6, stop_ratio=0.35, conf=conf)


def test_geometry_accepts_consistent_revisits_it_can_see():
    imgs, best, x = _stream()
    d, rep = _run(imgs, best, x)
    # the first two revisit frames have no consistent past yet, the third is the first verified: from the fourth on
    # geometry confirms them
    assert not d.accepted[:43].any() and d.accepted[43:].all()
    assert rep["accepted_by_geometry"] == 17 and rep["frames_verified"] == 18 and rep["frames_blind"] == 0
    assert rep["ms_per_verified_frame"] > 0


def test_geometry_is_blind_on_small_frames_and_leaves_the_path_alone():
    imgs, best, x = _stream()
    small = [cv2.resize(i, (64, 32)) for i in imgs]
    d, rep = _run(small, best, x)
    assert not d.accepted.any() and rep["frames_blind"] == 18 and rep["frames_verified"] == 0


def test_a_stop_is_not_confirmed():
    imgs, best, _ = _stream()
    x = sdr.from_indices([np.arange(20)] * 60, 256)  # every frame the same: the camera never left
    d, rep = _run(imgs, best, x)
    assert not d.accepted.any() and rep["accepted_by_geometry"] == 0


@pytest.mark.slow  # two-view geometry over a rendered drive
def test_a_scene_never_out_of_sight_is_no_loop():
    # a forward drive: every frame shows the same road ahead a little further on; frame j's best earlier frame
    # j - 20 verifies, but so does every frame in between: the camera never lost sight of it
    road = _textures(1)[0]
    imgs = [np.roll(road, k, axis=1) for k in range(30)]
    best = np.r_[np.full(20, -1), np.arange(10)]
    d, rep = _run(imgs, best, sdr.random_sdrs(30, 256, 20, seed=0))
    assert rep["frames_verified"] > 0 and not d.accepted.any()


@pytest.mark.slow
def test_a_path_geometry_accepted_is_tracked_through_blind_and_weaker_frames():
    imgs, best, x = _stream()
    imgs[45] = np.zeros_like(imgs[45])  # blind: no keypoints
    other = _textures(1, seed=7)[0]
    cover = int(imgs[52].shape[1] * 0.85)
    imgs[52] = imgs[52].copy()
    imgs[52][:, :cover] = other[:, :cover]  # most of the view hidden: 18 inliers with frame 12
    run = {"min_inliers": 30, "verified_frames": 2, "verified_within": 2}  # 2 frames of 30 inliers in a row
    found, _ = _run(imgs, best, x, OpinionConf(keep_inliers=0, **run))
    assert found.accepted[43] and not found.accepted[45] and not found.accepted[52] and not found.accepted[53]
    tracked, rep = _run(imgs, best, x, OpinionConf(keep_inliers=10, **run))
    assert not tracked.accepted[:43].any() and tracked.accepted[43:].all()
    assert rep["frames_blind"] == 1 and rep["accepted_by_geometry"] == 17
    # a frame that breaks the path (another place) ends the tracking: the next needs its run again
    imgs[52] = other
    broken, _ = _run(imgs, best, x, OpinionConf(keep_inliers=10, **run))
    assert broken.accepted[51] and not broken.accepted[52] and not broken.accepted[53] and broken.accepted[54]


def test_too_few_inliers_are_not_enough():
    imgs, best, x = _stream()
    other = _textures(60, seed=9)  # the "revisits" show something else
    d, _ = _run(other, best, x, OpinionConf())
    assert not d.accepted.any()


def test_rising_inliers_is_the_bar_where_the_path_score_is_above_0():
    imgs, best, x = _stream()
    score = np.r_[np.zeros(50), np.full(10, 5.0)]  # the rule's path stands out from frame 50 on, not accepted
    path = Decision(best, score, np.zeros(best.size, bool))
    conf = OpinionConf(min_inliers=100_000, rising_inliers=30)  # no pair reaches the first bar
    d, rep = second_opinion(path, lambda j: imgs[j], x, back=4, ahead=6, stop_ratio=0.35, conf=conf)
    # 2 verified frames where the score is above 0 (at min_inliers alone, none would be)
    assert not d.accepted[:51].any() and d.accepted[51:].all() and rep["accepted_by_geometry"] == 9


def test_with_refuse_after_a_path_the_rule_accepted_is_refused_where_geometry_sees_it_and_never_confirms_it():
    imgs, best, x = _stream()
    score = np.r_[np.zeros(40), np.arange(1.0, 21.0)]  # the rule's path from frame 40, accepted from frame 49 on
    path = Decision(best, score, score >= 10)

    refuse = OpinionConf(refuse_after=3)

    def run(images, conf=refuse):
        return second_opinion(path, lambda j: images[j], x, back=4, ahead=6, stop_ratio=0.35, conf=conf)

    d, rep = run(imgs)  # the right place: confirmed before the rule accepts, and by geometry from frame 43
    assert d.accepted[43:].all() and not d.accepted[:43].any() and rep["refused_by_geometry"] == 0
    other = imgs[:40] + _textures(60, seed=9)[40:]  # another place, in plain sight: 0 inliers on every frame
    d, rep = run(other)
    assert not d.accepted.any() and rep["refused_by_geometry"] == 11
    d, rep = run(other, OpinionConf())  # the default: the rule's path is never refused
    assert np.array_equal(d.accepted, path.accepted) and rep["refused_by_geometry"] == 0
    d, rep = run([cv2.resize(i, (64, 32)) for i in other])  # blind: the path decides alone
    assert np.array_equal(d.accepted, path.accepted) and rep["refused_by_geometry"] == 0
    # a path that starts again (its score at 0, frame 55) is judged afresh: the path decides until geometry saw 3 of
    # its frames (55-57)
    again = Decision(best, np.r_[score[:55], 0.0, 10.0, 11.0, 12.0, 13.0], np.r_[score[:55] >= 10, False, True,
                                                                                 True, True, True])
    d, rep = second_opinion(again, lambda j: other[j], x, back=4, ahead=6, stop_ratio=0.35, conf=refuse)
    assert np.flatnonzero(d.accepted).tolist() == [56] and rep["refused_by_geometry"] == 6 + 3


def test_geometry_is_refused_for_a_method_it_does_not_apply_to(tmp_path, capsys):
    from pipelines.cli import main

    seq = tmp_path / "seq"
    seq.mkdir()
    for j, img in enumerate(_textures(3)):
        cv2.imwrite(str(seq / f"{j:03d}.png"), img)
    out = tmp_path / "out"
    code = main(["loops", str(seq), "--out", str(out), "--method", "seqslam", "--geometry", "on"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--geometry on" in err[0] and not out.exists()


def crossing_at(img):
    """``img`` with a crossing painted over its lower part (one stripe repeated across the frame)."""
    out = img.copy()
    out[150:230] = 90
    for x in range(5, out.shape[1] - 20, 26):
        cv2.rectangle(out, (x, 160), (x + 13, 220), (235, 235, 235), -1)
    return out


def test_a_crossing_seen_at_another_place_is_not_confirmed():
    # the "revisits" are other places with the same crossing as the first 20 frames (none between): its repeated
    # stripes verify them when every match counts, not when a match must be distinct within its own frame (default)
    imgs, best, x = _stream()
    other = _textures(60, seed=9)
    crossed = [crossing_at(im) for im in imgs[:20]] + imgs[20:40] + [crossing_at(im) for im in other[40:]]
    d, _ = _run(crossed, best, x, OpinionConf(min_inliers=12, distinct=False))
    assert d.accepted.any()  # the crossing alone verifies them
    d, _ = _run(crossed, best, x, OpinionConf(min_inliers=12))
    assert not d.accepted.any()


@pytest.mark.slow  # the command line three times over a short loop
def test_vpr_loops_decides_short_loops_with_geometry_by_default_and_online_alike(tmp_path, capsys, monkeypatch):
    import csv
    import io
    import json

    from pipelines.cli import main
    from vpr.shosm import LoopDetector, MemoryFileError

    imgs, _, _ = _stream()
    seq = tmp_path / "seq"
    seq.mkdir()
    for j, img in enumerate(imgs):
        cv2.imwrite(str(seq / f"{j:03d}.png"), img)
    paths = sorted(str(p) for p in seq.glob("*.png"))
    loose = ["--preset", "fast", "--exclude", "12", "--no-progress"]

    def batch(*extra):
        out = tmp_path / f"batch{len(extra)}"
        assert main(["loops", str(seq), "--out", str(out), *loose, *extra]) == 0
        capsys.readouterr()
        with open(out / "rshosm-seq" / "matches.csv") as fh:
            rows = [(int(r["best_db"]), r["accepted"] == "1") for r in csv.DictReader(fh)]
        return rows, json.loads((out / "metrics.json").read_text())["methods"]["rshosm-seq"]

    runs = iter(range(100))

    def online(lines, *extra):  # each run into a folder of its own
        monkeypatch.setattr("sys.stdin", io.StringIO("\n".join(lines) + "\n"))
        code = main(["loops", "-", "--out", str(tmp_path / f"online{next(runs)}"), *extra])
        out, err = capsys.readouterr()
        assert code == 0, err
        return [(r["best_db"] if r["best_db"] is not None else -1, r["accepted"])
                for r in map(json.loads, out.splitlines())]

    rows, m = batch()
    path_only, m_off = batch("--geometry", "off")
    # the path alone accepts none of this short revisit; geometry confirms most of it (the first frames are its run)
    assert not any(a for _, a in path_only) and "geometry" not in m_off
    by_geometry = m["geometry"]["accepted_by_geometry"]
    # (with the frames that led up to its closures on their paths, accepted with them)
    assert by_geometry >= 12 and sum(a for _, a in rows) >= by_geometry
    assert all(b == j - 40 for j, (b, a) in enumerate(rows) if a)
    # online, one frame at a time: the same answers; stopped after 45 frames and resumed: the same again
    assert online(paths, *loose[:-1]) == rows
    state = tmp_path / "state.npz"
    first = online(paths[:45], *loose[:-1], "--state-out", str(state))
    assert first + online(paths[45:], "--resume", str(state)) == rows
    assert LoopDetector.saved_meta(state)["opinion"]
    # the earlier frames gone when the run resumes (a log rotated away): geometry is blind on them, every frame
    # is answered
    for p in paths[:45]:
        Path(p).rename(p + ".gone")
    resumed = online(paths[45:], "--resume", str(state))
    assert len(resumed) == 60 - len(first) and not any(a for _, a in resumed)  # what waited in the state, then 15
    for p in paths[:45]:
        Path(p + ".gone").rename(p)
    with pytest.raises(MemoryFileError, match="saved with a second opinion"):
        LoopDetector.load(state)
    # the opinion is the saved detector's: --geometry cannot change it
    monkeypatch.setattr("sys.stdin", io.StringIO(""))
    assert main(["loops", "-", "--out", str(tmp_path / "x"), "--resume", str(state), "--geometry", "off"]) == 2
    assert "--geometry" in capsys.readouterr().err


@pytest.mark.slow  # a forward drive rendered at 320 x 240, verified frame by frame
def test_a_forward_drive_past_identical_crossings_closes_no_loop(tmp_path, capsys):
    import csv
    import json

    from pipelines.cli import main
    from vpr.render import write_scene

    # speed_change's world paints the same crossing every 66 m and never comes back: every closure is false
    res = write_scene("speed_change", tmp_path / "scene", size=(320, 240), traverses=["fast"], progress=False)
    drive = Path(res["traverses"]["fast"]["folder"])
    out = tmp_path / "out"
    assert main(["loops", str(drive), "--out", str(out), "--no-progress"]) == 0
    capsys.readouterr()
    m = json.loads((out / "metrics.json").read_text())["methods"]["rshosm-seq"]
    assert m["n_accepted"] == 0 and m["geometry"]["frames_verified"] > 150
    # what the default keeps out: with every match counting, 20 inliers twice in a row, the crossings verify (the
    # path accepted nothing, so the answers are the path's)
    with open(out / "rshosm-seq" / "matches.csv") as fh:
        rows = list(csv.DictReader(fh))
    path = Decision(np.array([int(r["best_db"]) for r in rows]), np.array([float(r["score"]) for r in rows]),
                    np.array([r["accepted"] == "1" for r in rows]))
    files = sorted(drive.glob("*.png"))
    every = OpinionConf(min_inliers=20, distinct=False, verified_within=2, keep_inliers=0)
    d, rep = second_opinion(path, lambda j: cv2.imread(str(files[j])), sdr.random_sdrs(len(rows), 256, 20, seed=0),
                            back=4, ahead=6, stop_ratio=0.35, conf=every)
    assert rep["accepted_by_geometry"] >= 3 and not path.accepted.any()
