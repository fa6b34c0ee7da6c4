import numpy as np
import pytest
import scipy.sparse as sp

from vpr import methods, similarity, simulate
from vpr.shosm import SequenceMemory
from vpr.similarity import best_matches
from vpr.types import EncodedTraverse


def _features(n=30, seed=0):
    world = simulate.make_world(1, n, seed=seed)
    traj = np.arange(n)
    db = simulate.observe(world, traj, 0.1, seed=1)
    q = simulate.observe(world, traj, 0.1, seed=2)
    rng = np.random.default_rng(seed)
    pix = rng.random((n, 64)).astype(np.float32)
    mk = lambda s, p: EncodedTraverse(names=[str(i) for i in range(n)], sdr=s, desc=p, pixels=p)  # noqa: E731
    return mk(db, pix), mk(q, pix + 0.01 * rng.random((n, 64)).astype(np.float32))


def test_registry_builds_methods_and_rejects_unknown_names_and_keys():
    assert methods.available() == ["rshosm", "rshosm-seq", "seqslam", "seqslam-desc", "pairwise", "delta"]
    for name in methods.available():
        m = methods.get(name)
        assert isinstance(m, methods.Method) and m.name == name and m.conf == type(m).default_conf
    # strings (from --method-conf) are read as the default's type
    assert methods.get("seqslam", ds="4", causal="true").conf["ds"] == 4
    assert methods.get("seqslam", causal="true").conf["causal"] is True
    with pytest.raises(ValueError, match="unknown method 'nope'; available: rshosm"):
        methods.get("nope")
    with pytest.raises(ValueError, match=r"unknown seqslam option\(s\) \['dx'\]; valid: \['R', 'causal'"):
        methods.get("seqslam", dx=1)
    with pytest.raises(ValueError, match="seqslam: conf 'ds': cannot read 'many' as int"):
        methods.get("seqslam", ds="many")
    # the rshosm conf is the memory's parameters plus its own
    assert set(methods.get_class("rshosm").default_conf) == {"top_k", *SequenceMemory.default_params()}


def test_methods_refuse_loop_closure_they_cannot_do():
    seq = EncodedTraverse(names=list(range(5)), sdr=sp.csr_matrix((5, 64), dtype=bool))

    class NoLoops(methods.Method):
        name = "noloops"

    with pytest.raises(ValueError, match="noloops does not support loop closure"):
        NoLoops().loops(seq, exclude=1)


@pytest.mark.parametrize("method", methods.available())
def test_every_method_finds_an_aligned_route(method):
    db, q = _features()
    conf = {"ds": 4} if method.startswith("seqslam") else None
    res = methods.match(method, db, q, conf)
    assert res.similarity.shape == (30, 30)
    assert np.mean(res.best == np.arange(30)) > 0.8


@pytest.mark.parametrize("method", methods.available())
def test_a_method_learned_for_one_query_answers_as_one_learned_once(method):
    db, q = _features()
    m = methods.get(method, **({"ds": 4} if method.startswith("seqslam") else {}))
    kept, once = m.fit(db), m.fit(db, once=True)
    assert once.state is None  # nothing is learned before the match, nor kept after it
    a, b = kept.match(q), once.match(q)
    assert once.state is None and np.array_equal(a.best, b.best) and np.array_equal(a.accepted, b.accepted)
    same = (a.similarity != b.similarity).nnz == 0 if sp.issparse(a.similarity) else \
        np.array_equal(a.similarity, b.similarity)
    assert same and np.allclose(a.score, b.score, equal_nan=True)
    if m.block_margin is not None:
        with pytest.raises(ValueError, match="learned for one match"):
            once.match_block(q, 0, 10)


def test_best_matches_sparse_marks_empty_queries():
    S = sp.csr_matrix(np.array([[0.0, 0.5, 0], [0.7, 0, 0]]))
    S.eliminate_zeros()
    best, score = best_matches(S)
    assert best.tolist() == [1, 0, -1] and score[2] == -np.inf


def test_large_inputs_go_sparse_or_are_refused(monkeypatch):
    db, q = _features()
    monkeypatch.setattr(similarity, "DENSE_PAIRS_LIMIT", 100)
    res = methods.match("rshosm", db, q, {"top_k": 3})
    assert sp.issparse(res.similarity) and res.similarity.nnz <= 3 * 30
    res = methods.match("pairwise", db, q, {"top_k": 2})
    assert sp.issparse(res.similarity)
    with pytest.raises(ValueError, match="dense descriptors"):
        methods.match("pairwise", db, q, {"on": "descriptor"})
    # rshosm-seq goes sparse above the limit: tests/test_scale.py


def test_loops_only_look_back_far_enough():
    obs, places = simulate.simulate_loops(n_loops=3, seed=0)
    feats = EncodedTraverse(names=list(range(len(places))), sdr=obs)
    res = methods.loops("rshosm", feats, exclude=5)
    ok = res.best >= 0
    assert np.all(res.best[ok] <= np.flatnonzero(ok) - 5)
    # the second and third laps close the loop with the right places
    later = np.arange(20, 60)
    assert np.mean(places[res.best[later]] == places[later]) > 0.9
    with pytest.raises(ValueError, match="exclude"):
        methods.loops("rshosm", feats, exclude=0)


def test_missing_features_are_named():
    db, q = _features()
    db = db.only(["desc", "pixels"])
    with pytest.raises(ValueError, match="rshosm needs SDRs of the database traverse"):
        methods.match("rshosm", db, q)


def test_seqslam_desc_is_seqslam_on_the_encoder_descriptors_with_cosine():
    db, q = _features()
    m = methods.get("seqslam-desc", ds=4)
    assert m.required_inputs == ("desc",) and m.conf["metric"] == "cosine" and "descriptor" not in m.conf
    res = m.match(db, q)
    ref = methods.match("seqslam", db, q, {"ds": 4, "descriptor": "encoder", "metric": "cosine"})
    np.testing.assert_array_equal(res.similarity, ref.similarity)
    np.testing.assert_array_equal(res.best, ref.best)
    # "desc" is accepted as an alias of "encoder" (the spelling of EncodedTraverse.desc)
    assert methods.get("seqslam", descriptor="desc").required_inputs == ("desc",)
    assert methods.get("seqslam").required_inputs == ("pixels",)
    # the pixel thumbnails are not read: without the encoder's descriptors it says what is missing
    db = db.only(["sdr", "pixels"])
    with pytest.raises(ValueError, match="seqslam-desc needs dense descriptors of the database traverse"):
        m.match(db, q)


@pytest.mark.parametrize("bad", [{"descriptor": "sdr"}, {"metric": "l2"}, {"large": "refuse"}])
def test_seqslam_rejects_bad_choices(bad):
    with pytest.raises(ValueError, match=f"seqslam: {next(iter(bad))} must be"):
        methods.get("seqslam", **bad)


@pytest.mark.parametrize("name", ["seqslam", "seqslam-desc"])
def test_seqslam_above_the_dense_limit_runs_blocked_top_k(monkeypatch, name):
    db, q = _features(n=60)
    dense = methods.match(name, db, q, {"ds": 4})
    monkeypatch.setattr(similarity, "DENSE_PAIRS_LIMIT", 100)
    exact = methods.match(name, db, q, {"ds": 4, "large": "exact", "top_k": 5})
    assert sp.issparse(exact.similarity) and exact.similarity.shape == (60, 60)
    assert exact.similarity.getnnz(axis=0).max() == 5
    # exact mode keeps the dense matrix's 5 best values of every query
    top = -np.sort(-dense.similarity, axis=0)[:5]
    C = sp.csc_matrix(exact.similarity)
    kept = np.stack([-np.sort(-C.data[C.indptr[j]:C.indptr[j + 1]]) for j in range(60)], axis=1)
    np.testing.assert_allclose(kept, top, rtol=1e-5, atol=1e-4)
    np.testing.assert_array_equal(exact.best, dense.best)
    np.testing.assert_array_equal(exact.accepted, dense.accepted)
    # candidate mode (the default): approximate, but the route is found
    cand = methods.match(name, db, q, {"ds": 4})
    assert sp.issparse(cand.similarity)
    assert np.mean(cand.best == dense.best) > 0.9
    # loop closure has no blocked form: refused before any work
    with pytest.raises(ValueError, match=f"{name} loop closure needs a dense 60 x 60 matrix"):
        methods.loops(name, db, exclude=5)


@pytest.fixture(scope="module")
def image_folders(tmp_path_factory):
    """Two traverses of one textured route (query: noisy), 12 frames of 64 x 48."""
    import cv2

    root = tmp_path_factory.mktemp("route")
    rng = np.random.default_rng(0)
    world = cv2.resize(rng.integers(0, 256, (12, 60), dtype=np.uint8), (600, 48), interpolation=cv2.INTER_LINEAR)
    for name, noise in (("db", 0), ("q", 12)):
        (root / name).mkdir()
        for i in range(12):
            im = world[:, 40 * i:40 * i + 64].astype(float) + rng.normal(0, noise + 1e-9, (48, 64))
            cv2.imwrite(str(root / name / f"{i:03d}.png"), np.clip(im, 0, 255).astype(np.uint8))
    return root / "db", root / "q"


@pytest.mark.parametrize("enc", ["pixel", "projection", "orb", "cnn"])
def test_every_encoder_with_a_dense_descriptor_feeds_seqslam_desc(image_folders, enc, tmp_path):
    import encoders
    from pipelines.extract import extract
    from vpr.sources import open_source

    m = methods.get("seqslam-desc", ds=2, R=2)
    encoder = encoders.get(enc)
    feats = []
    for folder in image_folders:
        kw = dict(inputs=tuple(i for i in m.required_inputs if i == "desc"), cache_dir=tmp_path, progress=False)
        ex = extract(open_source(folder), encoder, **kw)
        again = extract(open_source(folder), encoder, **kw)  # from the cache, with the descriptors
        assert again.cached and again.features.desc is not None
        np.testing.assert_array_equal(again.features.desc, ex.features.desc)
        feats.append(ex.features)
    d = feats[0].desc
    assert d.dtype == np.float32 and d.shape[0] == 12 and d.ndim == 2
    res = m.match(*feats)
    assert res.similarity.shape == (12, 12) and res.best.shape == (12,)


def test_an_encoder_without_a_dense_descriptor_is_named(image_folders):
    import encoders
    from pipelines.extract import extract
    from vpr.sources import open_source

    class NoDesc(encoders.base.BaseEncoder):
        name = "nodesc"

    with pytest.raises(ValueError, match="needs dense descriptors .*encoder 'nodesc' has no dense descriptor"):
        extract(open_source(image_folders[0]), NoDesc(), inputs=("desc",), progress=False)
