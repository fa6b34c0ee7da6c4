import numpy as np
import pytest
import scipy.sparse as sp

from vpr import methods, simulate
from vpr.memory import SequenceMemory
from vpr.methods import base


def _features(n=30, seed=0):
    world = simulate.make_world(1, n, seed=seed)
    traj = np.arange(n)
    db = simulate.observe(world, traj, 0.1, seed=1)
    q = simulate.observe(world, traj, 0.1, seed=2)
    rng = np.random.default_rng(seed)
    pix = rng.random((n, 64)).astype(np.float32)
    mk = lambda s, p: methods.EncodedTraverse(names=[str(i) for i in range(n)], sdr=s, desc=p, pixels=p)  # noqa: E731
    return mk(db, pix), mk(q, pix + 0.01 * rng.random((n, 64)).astype(np.float32))


def test_registry_builds_methods_and_rejects_unknown_names_and_keys():
    assert methods.available() == ["rshosm", "rshosm-seq", "seqslam", "pairwise"]
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
    seq = methods.EncodedTraverse(names=list(range(5)), sdr=sp.csr_matrix((5, 64), dtype=bool))

    class NoLoops(methods.Method):
        name = "noloops"

    with pytest.raises(ValueError, match="noloops does not support loop closure"):
        NoLoops().loops(seq, exclude=1)


@pytest.mark.parametrize("method", methods.available())
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
    monkeypatch.setattr(base, "DENSE_PAIRS_LIMIT", 100)
    res = methods.match("rshosm", db, q, {"top_k": 3})
    assert sp.issparse(res.similarity) and res.similarity.nnz <= 3 * 30
    res = methods.match("pairwise", db, q, {"top_k": 2})
    assert sp.issparse(res.similarity)
    with pytest.raises(ValueError, match="seqslam needs a dense 30 x 30 matrix"):
        methods.match("seqslam", db, q)
    with pytest.raises(ValueError, match="dense descriptors"):
        methods.match("pairwise", db, q, {"on": "descriptor"})
    # rshosm-seq goes sparse above the limit: tests/test_scale.py


def test_loops_only_look_back_far_enough():
    obs, places = simulate.simulate_loops(n_loops=3, seed=0)
    feats = methods.EncodedTraverse(names=list(range(len(places))), sdr=obs)
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
