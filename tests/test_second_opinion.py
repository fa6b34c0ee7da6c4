"""The geometric second opinion on loop closures: a decider around the loop rule, where geometry can see."""
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
    # j - 40 verifies, but so does every frame in between: the camera never lost sight of it
    road = _textures(1)[0]
    imgs = [np.roll(road, k, axis=1) for k in range(60)]
    best = np.r_[np.full(40, -1), np.arange(20)]
    d, rep = _run(imgs, best, sdr.random_sdrs(60, 256, 20, seed=0))
    assert rep["frames_verified"] > 0 and not d.accepted.any()


def test_too_few_inliers_are_not_enough():
    imgs, best, x = _stream()
    other = _textures(60, seed=9)  # the "revisits" show something else
    d, _ = _run(other, best, x, OpinionConf())
    assert not d.accepted.any()


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
