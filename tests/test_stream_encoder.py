"""Running query statistics online: a camera that stands does not fill them."""
import numpy as np
import pytest

import encoders
from pipelines.stream import StreamEncoder
from vpr.standardise import RunningStandardiser


@pytest.mark.parametrize("window", [None, 3])
def test_withdraw_takes_the_last_frame_back_out(window):
    rng = np.random.default_rng(0)
    r = RunningStandardiser(np.zeros(4), np.ones(4), prior_frames=2.0, window=window)
    for x in rng.normal(size=(5, 4)):  # the window is full: the next frame pushes one out
        r.update(x)
    before = (r.n, r.sum.copy(), r.sq.copy(), [v.copy() for v in r.recent])
    r.update(rng.normal(size=4))
    r.withdraw()
    assert r.n == before[0] and len(r.recent) == len(before[3])
    np.testing.assert_allclose(r.sum, before[1], atol=1e-12)
    np.testing.assert_allclose(r.sq, before[2], atol=1e-12)
    for a, b in zip(r.recent, before[3], strict=True):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="withdraw"):
        r.withdraw()  # once per update


def _images(rng, n):
    return [rng.integers(0, 255, size=(24, 32), dtype=np.uint8) for _ in range(n)]


def test_a_standing_camera_leaves_the_running_statistics_as_they_were():
    rng = np.random.default_rng(1)
    conf = {"standardise": "fit", "n_bits": 512, "k": 20}
    db = _images(rng, 40)
    moving, after = _images(rng, 12), _images(rng, 8)
    enc = encoders.get("pixel", **conf).fit(db)

    def run(frames):
        s = StreamEncoder(encoders.get("pixel", **conf).set_statistics(enc.statistics()), window=5)
        rows = [s.encode(f) for f in frames]
        return s, rows

    plain, rows = run(moving + after)
    stood, rows_stood = run(moving + [moving[-1]] * 30 + after)  # the camera stands 30 frames, then moves on
    # the stand's frames are the same image: each keeps the frame before's bits, and none joins the statistics (were
    # they to, the window of 5 would hold the stand alone and the frames after it would be encoded otherwise)
    for a, b in zip(rows[-len(after):], rows_stood[-len(after):], strict=True):
        np.testing.assert_array_equal(a.indices, b.indices)
    np.testing.assert_allclose(plain._running[0].sum, stood._running[0].sum, rtol=1e-9)
