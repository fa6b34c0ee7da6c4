"""Tests of the image encoders in ``encoders/``."""
from __future__ import annotations

import struct

import cv2
import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

import encoders
from encoders.projection import TopKProjection
from vpr.config import coerce_value
from vpr.imageproc import seqslam_preprocess
from vpr.similarity import overlap_count

NAMES = ["cnn", "descriptors", "orb", "pixel", "projection"]
IMAGE_NAMES = [n for n in NAMES if n != "descriptors"]  # descriptors reads descriptor rows (tests/test_descriptors.py)


def textured(seed: int, size=(160, 120)) -> np.ndarray:
    """A BGR image of random blobs and edges: plenty of corners for ORB."""
    rng = np.random.default_rng(seed)
    w, h = size
    img = np.full((h, w, 3), 90, np.uint8)
    for _ in range(40):
        x, y = (int(v) for v in rng.integers(0, (w, h)))
        c = tuple(int(v) for v in rng.integers(0, 256, 3))
        r = int(rng.integers(3, max(4, w // 8)))
        if rng.random() < 0.5:
            cv2.rectangle(img, (x, y), (x + r, y + 2 * r), c, -1)
        else:
            cv2.circle(img, (x, y), r, c, -1)
    return img


@pytest.fixture(scope="module")
def images():
    return [textured(s) for s in range(6)]


@pytest.fixture(scope="module")
def encs():
    """One default-conf instance per registered encoder (the cnn session is costly)."""
    return {n: encoders.get(n) for n in NAMES}


def rows_equal(a: sp.csr_matrix, b: sp.csr_matrix) -> bool:
    return a.shape == b.shape and (a != b).nnz == 0


# -- registry and conf --------------------------------------------------------

def test_registry_lists_and_builds_all():
    assert encoders.available() == NAMES
    for n in NAMES:
        e = encoders.get(n)
        assert isinstance(e, encoders.BaseEncoder) and e.n_bits == 2048


def test_registry_rejects_unknown_name_and_key():
    with pytest.raises(ValueError, match="unknown encoder 'nope'.*pixel"):
        encoders.get("nope")
    with pytest.raises(ValueError, match="unknown pixel encoder option.*'kk'"):
        encoders.get("pixel", kk=3)


def test_cli_strings_are_coerced_to_default_types():
    conf = encoders.parse_conf(["k=20", "two_sided=true", "size=32,16", "seed=7", "standardise=fit"])
    e = encoders.get("pixel", **conf)
    assert e.conf == {**e.conf, "k": 20, "two_sided": True, "size": (32, 16), "seed": 7, "standardise": "fit"}
    p = encoders.get("projection", descriptor="hog", descriptor_conf='{"size": [64, 32], "pixels_per_cell": 8}')
    assert p.descriptor.conf["size"] == (64, 32) and p.descriptor.conf["pixels_per_cell"] == 8
    c = encoders.get("cnn", threads="2", mean="[0.5, 0.5, 0.5]", normalise="0")
    assert c.conf["threads"] == 2 and c.conf["mean"] == (0.5, 0.5, 0.5) and c.conf["normalise"] is False
    assert coerce_value("gem_p", "2", 3.0) == 2.0 and coerce_value("model", "none", None) is None


def test_cli_arguments_build_the_encoder():
    import argparse

    parser = argparse.ArgumentParser()
    encoders.add_arguments(parser)
    args = parser.parse_args(["--encoder", "orb", "--encoder-conf", "k=12", "--encoder-conf", "mode=grid"])
    e = encoders.from_args(args)
    assert type(e).__name__ == "OrbEncoder" and e.conf["k"] == 12 and e.conf["mode"] == "grid"
    with pytest.raises(SystemExit):
        parser.parse_args(["--encoder", "sift"])


@pytest.mark.parametrize("pairs,match", [
    (["k=forty"], "conf 'k'"), (["k=2.5"], "conf 'k'"), (["two_sided=maybe"], "conf 'two_sided'"),
    (["size=a,b"], "size"), (["noequals"], "key=value"),
])
def test_bad_cli_strings_raise(pairs, match):
    with pytest.raises(ValueError, match=match):
        encoders.get("pixel", **encoders.parse_conf(pairs))


@pytest.mark.parametrize("name,conf,match", [
    ("pixel", {"k": 0}, "k must be"), ("pixel", {"k": 3000}, "k must be"),
    ("pixel", {"standardise": "zscore"}, "standardise"), ("pixel", {"two_sided": True, "n_bits": 2047}, "even"),
    ("projection", {"descriptor": "sift"}, "descriptor"), ("orb", {"mode": "dense"}, "mode"),
    ("orb", {"hash_bits": 64}, "hash_bits"), ("cnn", {"pooling": "sum"}, "pooling"),
])
def test_bad_conf_values_raise(name, conf, match):
    with pytest.raises(ValueError, match=match):
        encoders.get(name, **conf)


# -- input handling -----------------------------------------------------------

@pytest.mark.parametrize("name", IMAGE_NAMES)
def test_bad_images_raise_naming_the_frame(name, encs, images):
    e = encs[name]
    with pytest.raises(ValueError, match=r"images\[1\]: empty image"):
        e.encode([images[0], np.zeros((0, 5, 3), np.uint8)])
    with pytest.raises(ValueError, match=r"images\[0\]: expected a 2-D"):
        e.encode([np.zeros(10, np.uint8)])
    with pytest.raises(ValueError, match=r"images\[1\]: NaN"):
        e.encode([images[0], np.full((20, 20), np.nan)])
    with pytest.raises(ValueError, match="empty batch"):
        e.encode([])
    with pytest.raises(ValueError, match="single colour"):
        e.encode(images[0])
    with pytest.raises(ValueError, match="shape"):
        e.encode(np.zeros((2, 3, 20, 20, 3), np.uint8))


@pytest.mark.parametrize("name", IMAGE_NAMES)
def test_grey_16bit_and_rgba_match_uint8_bgr(name, encs, images):
    e = encs[name]
    grey = [cv2.cvtColor(im, cv2.COLOR_BGR2GRAY) for im in images[:3]]
    as_bgr = [cv2.cvtColor(g, cv2.COLOR_GRAY2BGR) for g in grey]
    base = e.encode(as_bgr)
    assert rows_equal(e.encode(grey), base)
    assert rows_equal(e.encode([g.astype(np.uint16) << 8 for g in grey]), base)
    bgra = [cv2.cvtColor(b, cv2.COLOR_BGR2BGRA) for b in as_bgr]
    assert rows_equal(e.encode(bgra), base)
    # a stacked (N, H, W, C) array is a batch too
    assert rows_equal(e.encode(np.stack(as_bgr)), base)


# -- determinism and sparsity ---------------------------------------------------

@pytest.mark.parametrize("name,conf", [
    ("pixel", {}), ("pixel", {"two_sided": True}), ("projection", {"descriptor": "hog"}),
    ("orb", {}), ("orb", {"mode": "grid"}), ("cnn", {"k": 30}),
])
def test_same_seed_same_sdr_other_seed_other_sdr(name, conf, images):
    a = encoders.get(name, seed=3, **conf).encode(images)
    b = encoders.get(name, seed=3, **conf).encode(images)
    c = encoders.get(name, seed=4, **conf).encode(images)
    assert a.dtype == bool and sp.isspmatrix_csr(a) and a.shape == (len(images), 2048)
    assert rows_equal(a, b)
    assert not rows_equal(a, c)


@pytest.mark.parametrize("name,conf", [
    ("pixel", {}), ("pixel", {"k": 7, "n_bits": 500}), ("pixel", {"two_sided": True, "k": 41}),
    ("projection", {"descriptor": "hog", "k": 64}), ("cnn", {"k": 25, "n_bits": 1024}),
    ("orb", {"mode": "grid", "k": 33}),
])
def test_exactly_k_bits_even_for_blank_images(name, conf, images):
    e = encoders.get(name, **conf)
    blank = [np.zeros((120, 160, 3), np.uint8), np.full((40, 40), 255, np.uint8)]
    s = e.encode(images + blank)
    assert s.shape == (len(images) + 2, e.n_bits)
    assert (s.getnnz(axis=1) == e.conf["k"]).all()


def test_two_sided_splits_top_and_bottom_into_halves(images):
    e = encoders.get("pixel", two_sided=True, k=41, n_bits=1000)
    s = e.encode(images)
    first = (s[:, :500].getnnz(axis=1))
    assert (first == 21).all() and (s[:, 500:].getnnz(axis=1) == 20).all()
    p = e.projection.project(e.describe(images))
    top = np.sort(np.argsort(-p, axis=1)[:, :21], axis=1)
    bottom = np.sort(np.argsort(p, axis=1)[:, :20], axis=1) + 500
    for r in range(len(images)):
        assert np.array_equal(s[r].indices, np.concatenate([top[r], bottom[r]]))


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 6), st.integers(1, 50), st.integers(1, 64), st.booleans(), st.integers(0, 2**31))
def test_topk_projection_always_k_bits(n, dim, k, two_sided, seed):
    rng = np.random.default_rng(seed)
    desc = rng.standard_normal((n, dim)).astype(np.float32)
    desc[0] = 0.0  # an all-zero descriptor is all ties
    k = max(k, 2) if two_sided else k
    proj = TopKProjection(n_bits=128, k=k, seed=seed, two_sided=two_sided)
    s = proj(desc)
    assert (s.getnnz(axis=1) == k).all()
    assert rows_equal(s, TopKProjection(n_bits=128, k=k, seed=seed, two_sided=two_sided)(desc))


def test_topk_projection_rejects_bad_descriptors():
    proj = TopKProjection(n_bits=64, k=4)
    with pytest.raises(ValueError, match="frame 1: NaN"):
        proj(np.array([[1.0, 2.0], [np.nan, 0.0]]))
    with pytest.raises(ValueError, match="2-D"):
        proj(np.zeros((2, 3, 4)))


# -- pixel ------------------------------------------------------------------------

def test_pixel_descriptor_is_seqslam_preprocessing(encs, images):
    d = encs["pixel"].describe(images)
    assert d.dtype == np.float32 and d.shape == (len(images), 2048)
    ref = np.stack([seqslam_preprocess(im).ravel() for im in images])
    np.testing.assert_allclose(d, ref, atol=1e-5)
    # a size that does not tile into patches takes the reference path
    e = encoders.get("pixel", size=(60, 30))
    np.testing.assert_allclose(e.describe(images[:2]),
                               np.stack([seqslam_preprocess(im, size=(60, 30)).ravel() for im in images[:2]]),
                               atol=1e-5)


def test_pixel_and_projection_pixel_agree_and_encode_descriptors(encs, images):
    a = encs["pixel"].encode(images)
    assert rows_equal(a, encs["projection"].encode(images))
    assert rows_equal(a, encs["pixel"].encode_descriptors(encs["pixel"].describe(images)))


def test_standardisation_modes(images):
    e = encoders.get("pixel", standardise="fit")
    with pytest.raises(ValueError, match="call fit"):
        e.encode(images)
    assert e.fit(images) is e
    fitted = e.encode(images)
    assert not rows_equal(fitted, encoders.get("pixel").encode(images))
    # fit statistics are those of the fitted frames: per_batch on the same batch agrees
    assert rows_equal(fitted, encoders.get("pixel", standardise="per_batch").encode(images))
    with pytest.raises(ValueError, match="at least 2 frames"):
        encoders.get("pixel", standardise="per_batch").encode(images[:1])
    with pytest.raises(ValueError, match="fitted on 2048 dims"):
        e.encode_descriptors(np.zeros((2, 10)))


# -- orb --------------------------------------------------------------------------

def test_orb_blank_image_gives_empty_row_in_keypoint_mode(encs, images):
    s = encs["orb"].encode([images[0], np.zeros((120, 160, 3), np.uint8), images[1]])
    assert s.getnnz(axis=1).tolist() == [40, 0, 40]


def test_orb_small_images_are_upscaled_and_grid_is_upright(images):
    small = [cv2.resize(im, (64, 32), interpolation=cv2.INTER_AREA) for im in images]
    s = encoders.get("orb").encode(small)
    assert s.getnnz(axis=1).min() > 0
    grid = encoders.get("orb", mode="grid")
    g = grid.encode(small)
    assert (g.getnnz(axis=1) == 40).all()
    # upright descriptors: a 180-degree rotation changes the grid SDR of a textured image
    rot = grid.encode([cv2.rotate(images[0], cv2.ROTATE_180)])
    assert overlap_count(grid.encode(images[:1]), rot)[0, 0] < 20


def test_orb_votes_histogram_matches_sdr(encs, images):
    e = encs["orb"]
    h = e.describe(images[:2])
    s = e.encode(images[:2])
    assert h.shape == (2, 2048) and h.dtype == np.float32
    for r in range(2):
        # every chosen bin has at least as many votes as every unchosen one
        chosen = h[r, s[r].indices]
        rest = np.delete(h[r], s[r].indices)
        assert chosen.min() >= rest.max()


# -- cnn ----------------------------------------------------------------------------

def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        b, n = n & 0x7F, n >> 7
        out.append(b | (0x80 if n else 0))
        if not n:
            return bytes(out)


def _field(num: int, payload) -> bytes:
    """One protobuf field: varint for ints, length-delimited for bytes/str."""
    if isinstance(payload, int):
        return _varint(num << 3) + _varint(payload)
    data = payload.encode() if isinstance(payload, str) else payload
    return _varint(num << 3 | 2) + _varint(len(data)) + data


def identity_onnx(path, shape) -> None:
    """Write an ONNX Identity model whose float input/output have ``shape``
    (ints are fixed dims, strings symbolic), without the onnx package."""
    def value_info(name):
        dims = b"".join(_field(1, _field(1, d) if isinstance(d, int) else _field(2, d)) for d in shape)
        tensor = _field(1, 1) + _field(2, dims)  # elem_type FLOAT, shape
        return _field(1, name) + _field(2, _field(1, tensor))
    node = _field(1, "x") + _field(2, "y") + _field(3, "id") + _field(4, "Identity")
    graph = _field(1, node) + _field(2, "g") + _field(11, value_info("x")) + _field(12, value_info("y"))
    model = _field(1, 8) + _field(8, _field(2, 17)) + _field(7, graph)
    with open(path, "wb") as f:
        f.write(model)


def test_cnn_bad_model_errors(tmp_path):
    with pytest.raises(ValueError, match="model file not found"):
        encoders.get("cnn", model=str(tmp_path / "missing.onnx"))
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(struct.pack("<4I", 1, 2, 3, 4) * 8)
    with pytest.raises(ValueError, match="cannot load ONNX model"):
        encoders.get("cnn", model=str(junk))
    flat = tmp_path / "flat.onnx"
    identity_onnx(flat, ["N", 3])
    with pytest.raises(ValueError, match="must be 4-D"):
        encoders.get("cnn", model=str(flat))
    with pytest.raises(ValueError, match="unknown output 'logits'.*features"):
        encoders.get("cnn", output="logits")
    fixed = tmp_path / "fixed.onnx"
    identity_onnx(fixed, [1, 3, 32, 32])
    with pytest.raises(ValueError, match="fixed to 32x32"):
        encoders.get("cnn", model=str(fixed))


def test_cnn_generic_model_pooling_and_preprocessing(tmp_path, images):
    """An identity 'network' exposes the preprocessing and pooling arithmetic."""
    path = tmp_path / "id.onnx"
    identity_onnx(path, ["N", 3, "H", "W"])
    img = cv2.resize(images[0], (16, 8), interpolation=cv2.INTER_AREA)
    ref = cv2.cvtColor(img, cv2.COLOR_BGR2RGB) / 255.0
    ref = ((ref - (0.485, 0.456, 0.406)) / (0.229, 0.224, 0.225)).reshape(-1, 3)
    for pooling, expect in [("avg", ref.mean(0)), ("max", ref.max(0)),
                            ("gem", (np.maximum(ref, 1e-6) ** 3).mean(0) ** (1 / 3))]:
        e = encoders.get("cnn", model=str(path), input_size=(16, 8), pooling=pooling, normalise=False)
        np.testing.assert_allclose(e.describe([img])[0], expect, rtol=1e-4, atol=1e-5)
    e = encoders.get("cnn", model=str(path), input_size=(16, 8))
    np.testing.assert_allclose(np.linalg.norm(e.describe(images), axis=1), 1.0, rtol=1e-5)
    # the halving shortcut for big shrinks stays close to a one-step area resize
    from encoders.cnn import shrink_image
    big = textured(9, (640, 480))
    diff = shrink_image(big, (224, 224)).astype(float) - cv2.resize(big, (224, 224), interpolation=cv2.INTER_AREA)
    assert np.abs(diff).mean() < 1.0


def test_cnn_default_model_descriptor(encs, images):
    e = encs["cnn"]
    d = e.describe(images)
    assert d.shape == (len(images), 112) and d.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, rtol=1e-5)
    # batching does not change the result
    e2 = encoders.get("cnn", batch_size=4)
    np.testing.assert_allclose(e2.describe(images), d, atol=1e-5)
    assert rows_equal(e.encode(images), e.encode_descriptors(d))


# -- rendered route -------------------------------------------------------------------

ROUTE = {
    "name": "encoder_test_route",
    "world": {"kind": "street", "seed": 3, "length": 150},
    "camera": {"size": [160, 120]},
    "traverses": [
        {"name": "summer_day", "conditions": {"time": "day", "season": "summer"}},
        {"name": "autumn_overcast", "conditions": {"time": "day", "season": "autumn", "weather": "overcast"}},
    ],
}


@pytest.fixture(scope="module")
def route():
    from vpr.render import gt_matrix, render_scene

    db, q = render_scene(ROUTE, n_frames=30).traverses
    # same place: cameras within 4 m; different place: more than 20 m apart
    return db, q, gt_matrix(db, q, 4.0), ~gt_matrix(db, q, 20.0)


@pytest.mark.parametrize("name,conf", [
    ("pixel", {}), ("pixel", {"two_sided": True}), ("projection", {"descriptor": "hog"}),
    ("projection", {"descriptor": "hog", "standardise": "fit"}), ("orb", {}), ("orb", {"mode": "grid"}),
    ("cnn", {}), ("cnn", {"standardise": "fit"}),
])
def test_same_place_overlap_beats_different_place_on_rendered_route(route, name, conf):
    db, q, same, different = route
    assert same.sum() >= 20 and different.sum() >= 200
    enc = encoders.get(name, **conf)
    fit = conf.get("standardise") == "fit"
    A = enc.fit(db.images).encode(db.images) if fit else enc.encode(db.images)
    B = enc.fit(q.images).encode(q.images) if fit else enc.encode(q.images)
    ov = overlap_count(A, B)
    assert ov[same].mean() > ov[different].mean() + 1.0, (ov[same].mean(), ov[different].mean())
