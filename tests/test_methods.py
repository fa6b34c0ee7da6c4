import numpy as np
import pytest
import scipy.sparse as sp

from vpr import methods, sdr, simulate


def _features(n=30, seed=0):
    world = simulate.make_world(1, n, seed=seed)
    traj = np.arange(n)
    db = simulate.observe(world, traj, 0.1, seed=1)
    q = simulate.observe(world, traj, 0.1, seed=2)
    rng = np.random.default_rng(seed)
    pix = rng.random((n, 64)).astype(np.float32)
    mk = lambda s, p: methods.Features(names=[str(i) for i in range(n)], sdr=s, desc=p, pixels=p)  # noqa: E731
    return mk(db, pix), mk(q, pix + 0.01 * rng.random((n, 64)).astype(np.float32))


def test_merge_conf_rejects_unknown_methods_and_keys():
    assert methods.merge_conf("seqslam", {"ds": 4})["ds"] == 4
    with pytest.raises(ValueError, match="unknown method"):
        methods.merge_conf("nope", {})
    with pytest.raises(ValueError, match="unknown seqslam option"):
        methods.merge_conf("seqslam", {"dx": 1})


@pytest.mark.parametrize("method", methods.METHODS)
def test_every_method_finds_an_aligned_route(method):
    db, q = _features()
    conf = {"ds": 4} if method == "seqslam" else None
    res = methods.match(method, db, q, conf)
    assert res.similarity.shape == (30, 30)
    assert np.mean(res.best_db == np.arange(30)) > 0.8


def test_best_matches_sparse_marks_empty_queries():
    S = sp.csr_matrix(np.array([[0.0, 0.5, 0], [0.7, 0, 0]]))
    S.eliminate_zeros()
    best, score = methods.best_matches(S)
    assert best.tolist() == [1, 0, -1] and score[2] == -np.inf


def test_large_inputs_go_sparse_or_are_refused(monkeypatch):
    db, q = _features()
    monkeypatch.setattr(methods, "DENSE_PAIRS_LIMIT", 100)
    res = methods.match("rshosm", db, q, {"top_k": 3})
    assert sp.issparse(res.similarity) and res.similarity.nnz <= 3 * 30
    res = methods.match("pairwise", db, q, {"top_k": 2})
    assert sp.issparse(res.similarity)
    with pytest.raises(ValueError, match="dense 30 x 30 difference matrix"):
        methods.match("seqslam", db, q)
    with pytest.raises(ValueError, match="dense descriptors"):
        methods.match("pairwise", db, q, {"on": "descriptor"})


def test_loops_only_look_back_far_enough():
    obs, places = simulate.simulate_loops(n_loops=3, seed=0)
    feats = methods.Features(names=list(range(len(places))), sdr=obs)
    res = methods.loops("rshosm", feats, exclude=5)
    ok = res.best_db >= 0
    assert np.all(res.best_db[ok] <= np.flatnonzero(ok) - 5)
    # the second and third laps close the loop with the right places
    later = np.arange(20, 60)
    assert np.mean(places[res.best_db[later]] == places[later]) > 0.9
    with pytest.raises(ValueError, match="exclude"):
        methods.loops("rshosm", feats, exclude=0)


def test_missing_features_are_named():
    db, q = _features()
    db.sdr = None
    with pytest.raises(ValueError, match="rshosm needs SDRs of the database traverse"):
        methods.match("rshosm", db, q)
