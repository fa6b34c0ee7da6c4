"""Tests of the joined encoders (``encoders/joined.py``): ``pixel+cnn`` and friends."""
from __future__ import annotations

import argparse

import numpy as np
import pytest
import scipy.sparse as sp

import encoders
from encoders.joined import DescribedJoinedEncoder, JoinedEncoder, split_name
from vpr.methods import match
from vpr.types import EncodedTraverse

# a small CNN input keeps the ONNX runs in milliseconds; the tests are about joining, not the CNN
SMALL_CNN = {"cnn.input_size": (64, 64)}


@pytest.fixture(scope="module")
def scene(rendered):
    return rendered("two_seasons", (64, 48), 24)


@pytest.fixture(scope="module")
def frames(scene):
    return scene.traverses[0].images, scene.traverses[1].images


def same(a: sp.csr_matrix, b: sp.csr_matrix) -> bool:
    return a.shape == b.shape and (a != b).nnz == 0


def test_split_name_and_duplicate_parts():
    assert split_name("pixel+cnn") == (["pixel", "cnn"], ["pixel", "cnn"])
    assert split_name("pixel + pixel") == (["pixel", "pixel"], ["pixel", "pixel#2"])
    for bad in ("pixel", "pixel+", "+cnn"):
        with pytest.raises(ValueError, match="joined by"):
            split_name(bad)


def test_defaults_share_one_encoders_width_and_density():
    e = encoders.get("pixel+cnn", **SMALL_CNN)
    assert isinstance(e, DescribedJoinedEncoder) and e.name == "pixel+cnn"
    assert [p.n_bits for p in e.encoders] == [1024, 1024] and e.n_bits == 2048
    default_k = encoders.get_class("pixel").default_conf.get("k", encoders.get("pixel").conf["k"])
    assert [p.conf["k"] for p in e.encoders] == [-(-default_k // 2)] * 2
    three = encoders.get("pixel+pixel+pixel")
    assert [p.n_bits for p in three.encoders] == [682, 682, 684] and three.n_bits == 2048


def test_per_part_and_shared_keys(frames):
    e = encoders.get("pixel+cnn", **{"pixel.k": "100", "cnn.k": 30, "pixel.n_bits": 1536, "cnn.n_bits": "512",
                                     "standardise": "fit", **SMALL_CNN})
    px, cnn = e.encoders
    assert (px.conf["k"], cnn.conf["k"], px.n_bits, cnn.n_bits) == (100, 30, 1536, 512)
    assert px.conf["standardise"] == cnn.conf["standardise"] == "fit"
    # the flat conf names every part's key, so caches keyed on conf tell two splits apart
    assert e.conf["pixel.k"] == 100 and e.conf["cnn.n_bits"] == 512 and e.conf["describe"] == "balanced"
    db, _ = frames
    s = e.fit(db).encode(db)
    assert s.shape == (len(db), 2048) and s.dtype == bool
    assert (np.diff(s.indptr) == 130).all()
    assert (s[:, :1536].sum(axis=1) == 100).all() and (s[:, 1536:].sum(axis=1) == 30).all()


def test_bad_conf_is_named():
    with pytest.raises(ValueError, match="names no part.*pixel"):
        encoders.get("pixel+cnn", **{"hog.k": 3})
    with pytest.raises(ValueError, match="unknown pixel encoder option.*'kk'"):
        encoders.get("pixel+cnn", **{"pixel.kk": 3})
    with pytest.raises(ValueError, match="without a part prefix.*'orb'"):
        encoders.get("pixel+orb", patch=4)
    with pytest.raises(ValueError, match="unknown encoder 'sift'"):
        encoders.get("pixel+sift")
    with pytest.raises(ValueError, match="describe must be"):
        encoders.get("pixel+pixel", describe="mean")


@pytest.mark.parametrize("standardise", ["none", "fit"])
def test_raw_joined_sdr_is_the_parts_sdrs_side_by_side(frames, standardise):
    db, q = frames
    conf = {"pixel.k": 50, "cnn.k": 20, "standardise": standardise, **SMALL_CNN}
    e = encoders.get("pixel+cnn", describe="raw", **conf)
    px = encoders.get("pixel", k=50, n_bits=1024, standardise=standardise)
    cnn = encoders.get("cnn", k=20, n_bits=1024, standardise=standardise, input_size=(64, 64))
    for images in (db, q):  # per-traverse standardisation: each traverse fitted on itself
        if standardise == "fit":
            e.fit(images), px.fit(images), cnn.fit(images)
        joined = e.encode(images)
        assert same(joined, sp.hstack([px.encode(images), cnn.encode(images)], format="csr"))
        desc = e.describe(images)
        assert np.array_equal(desc, np.hstack([px.describe(images), cnn.describe(images)]))
    # the overlap of joined SDRs is the sum of the parts' overlaps
    a, b = e.encode(db), e.encode(q)
    o = (a.astype(np.int32) @ b.T.astype(np.int32)).toarray()
    o_px = (a[:, :1024].astype(np.int32) @ b[:, :1024].T.astype(np.int32)).toarray()
    o_cnn = (a[:, 1024:].astype(np.int32) @ b[:, 1024:].T.astype(np.int32)).toarray()
    assert np.array_equal(o, o_px + o_cnn)


def test_balanced_descriptor_gives_each_part_equal_weight(frames):
    db, _ = frames
    e = encoders.get("pixel+cnn", **SMALL_CNN)
    d = e.describe(db)
    assert d.shape == (len(db), e.dim) and e.dims[0] == 2048 and d.dtype == np.float32
    blocks = e.split_descriptors(d)
    for b in blocks:
        np.testing.assert_allclose(np.linalg.norm(b, axis=1), 1 / np.sqrt(2), rtol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, rtol=1e-5)
    # a per-frame scale does not move a top-k: without standardisation the SDRs equal the raw ones
    raw = encoders.get("pixel+cnn", describe="raw", **SMALL_CNN)
    assert same(e.encode(db), raw.encode(db))
    # join_descriptors builds the same joined descriptor from cached per-part descriptors
    parts = [p.describe(db) for p in e.encoders]
    np.testing.assert_allclose(e.join_descriptors(parts), d, rtol=1e-6)
    with pytest.raises(ValueError, match="expects?|expected 2"):
        e.join_descriptors(parts[:1])
    with pytest.raises(ValueError, match="expected .* dims"):
        e.split_descriptors(d[:, :100])


def test_fit_then_encode_equals_descriptor_path(frames):
    db, q = frames
    e1 = encoders.get("pixel+cnn", standardise="fit", **SMALL_CNN)
    e2 = encoders.get("pixel+cnn", standardise="fit", **SMALL_CNN)
    d = e2.describe(q)
    assert same(e1.fit(q).encode(q), e2.fit_descriptors(d).encode_descriptors(d))
    # fitted on another traverse, the SDRs differ: fit really standardises
    assert not same(e1.fit(db).encode(q), e2.encode_descriptors(d))
    with pytest.raises(ValueError, match="not fitted"):
        encoders.get("pixel+cnn", standardise="fit", **SMALL_CNN).encode(q)


def test_parts_without_descriptor(frames):
    db, _ = frames
    e = encoders.get("pixel+orb", **{"orb.mode": "grid"})
    assert type(e).__mro__[1] is JoinedEncoder and not hasattr(e, "encode_descriptors")
    s = e.fit(db).encode(db)
    assert s.shape == (len(db), 2048) and same(s[:, :1024], encoders.get("pixel", n_bits=1024, k=20).encode(db))
    with pytest.raises(NotImplementedError, match="orb"):
        e.describe(db)


def test_rshosm_seq_runs_on_joined_sdrs(frames):
    db, q = frames
    feats = []
    for images in (db, q):
        e = encoders.get("pixel+cnn", standardise="fit", **{"pixel.k": 100, "cnn.k": 100, **SMALL_CNN})
        d = e.describe(images)
        sdr = e.fit_descriptors(d).encode_descriptors(d)
        feats.append(EncodedTraverse(names=list(range(len(images))), sdr=sdr, desc=d))
    res = match("rshosm-seq", *feats)
    assert res.similarity.shape == (len(db), len(q)) and np.isfinite(res.similarity).all()
    pw = match("pairwise", *feats, conf={"on": "descriptor", "metric": "cosine"})
    assert pw.similarity.shape == (len(db), len(q))


def test_cli_accepts_joined_names():
    ap = argparse.ArgumentParser()
    encoders.add_arguments(ap)
    args = ap.parse_args(["--encoder", "pixel+cnn", "--encoder-conf", "pixel.k=100", "--encoder-conf", "cnn.k=100"])
    e = encoders.from_args(args)
    assert [p.conf["k"] for p in e.encoders] == [100, 100]
    with pytest.raises(SystemExit):
        ap.parse_args(["--encoder", "pixel+sift"])


def test_conf_round_trips_and_tells_pipelines_to_fit():
    e = encoders.get("pixel+cnn", **{"pixel.standardise": "fit", "pixel.k": 150, "pixel.n_bits": 1536,
                                     "cnn.k": 50, "cnn.n_bits": 512, **SMALL_CNN})
    # encoders/extract.py fits when conf["standardise"] == "fit"; one fitting part is enough
    assert e.conf["standardise"] == "fit" and e.encoders[1].conf["standardise"] == "none"
    again = encoders.get("pixel+cnn", **e.conf)
    assert again.conf == e.conf and [p.conf for p in again.encoders] == [p.conf for p in e.encoders]
    assert encoders.get("pixel+orb").conf["standardise"] == "none"


def test_compare_pipeline_extracts_joined_features(frames, tmp_path):
    import cv2

    from pipelines.extract import extract
    from vpr.sources import open_source

    db, _ = frames
    for i, im in enumerate(db):
        cv2.imwrite(str(tmp_path / f"{i:03d}.png"), im)
    e = encoders.get("pixel+cnn", standardise="fit", **SMALL_CNN)
    ex = extract(open_source(str(tmp_path)), e, inputs=("sdr", "desc"), progress=False)
    ref = encoders.get("pixel+cnn", standardise="fit", **SMALL_CNN)
    d = ref.describe(list(db))
    assert ex.features.desc.shape == d.shape
    np.testing.assert_allclose(ex.features.desc, d, atol=1e-5)
    # fitted on the traverse itself, as with a single encoder
    assert same(ex.features.sdr, ref.fit_descriptors(d).encode_descriptors(d))
