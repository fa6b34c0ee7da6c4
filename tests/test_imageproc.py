"""Tests for vpr.imageproc: the one SeqSLAM pixel descriptor, single image and batch."""
import numpy as np
import pytest

from vpr.imageproc import patch_normalise, seqslam_descriptors, seqslam_preprocess


def _images(n, seed=0):
    rng = np.random.default_rng(seed)
    # different sizes and layouts: grey uint8, BGR uint8, BGRA float
    return [rng.integers(0, 256, (48 + 3 * i, 90 + 5 * i), dtype=np.uint8) if i % 3 == 0 else
            rng.integers(0, 256, (50, 70, 3), dtype=np.uint8) if i % 3 == 1 else
            rng.random((40, 64, 4)) for i in range(n)]


@pytest.mark.parametrize("size,patch", [((64, 32), 8), ((60, 30), 8), ((32, 16), 4), ((7, 5), 3)])
def test_batch_descriptor_equals_single_image_preprocessing(size, patch):
    imgs = _images(7)
    d = seqslam_descriptors(imgs, size, patch)
    assert d.dtype == np.float32 and d.shape == (7, size[0] * size[1])
    ref = np.stack([seqslam_preprocess(im, size, patch).ravel() for im in imgs])
    np.testing.assert_array_equal(d, ref)  # bit for bit: one implementation


def test_patch_normalise_definition_and_flat_blocks():
    rng = np.random.default_rng(1)
    g = rng.integers(0, 256, (3, 10, 13)).astype(np.float32)
    g[1, :4, :4] = 7  # a flat block becomes 0
    out = patch_normalise(g, 4)
    for i in range(3):
        np.testing.assert_array_equal(out[i], patch_normalise(g[i], 4))
        for y0 in range(0, 10, 4):
            for x0 in range(0, 13, 4):
                b = g[i, y0:y0 + 4, x0:x0 + 4]
                ref = (b - b.mean()) / b.std() if b.std() > 1e-6 else np.zeros_like(b)
                np.testing.assert_allclose(out[i, y0:y0 + 4, x0:x0 + 4], ref, atol=1e-5)
    assert np.all(out[1, :4, :4] == 0)


def test_errors_name_the_image():
    with pytest.raises(ValueError, match="no images"):
        seqslam_descriptors([])
    with pytest.raises(ValueError, match=r"images\[1\]: NaN"):
        seqslam_descriptors([np.zeros((8, 8)), np.full((8, 8), np.nan)])
    with pytest.raises(ValueError, match="expected"):
        patch_normalise(np.zeros((2, 2, 2, 2)))
