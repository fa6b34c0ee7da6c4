import numpy as np
import pytest
import scipy.sparse as sp

from vpr import sdr, similarity
from vpr.baselines.pairwise import pairwise


def test_overlap_is_normalised_db_by_query():
    db = sdr.from_indices([[0, 1, 2, 3], [4, 5]], 8)
    q = sdr.from_indices([[0, 1], [4, 5], []], 8)
    S = similarity.overlap(db, q)
    assert S.shape == (2, 3)
    assert np.allclose(S, [[2 / np.sqrt(8), 0, 0], [0, 1, 0]])


def test_overlap_top_k_keeps_the_best_per_query():
    rng = np.random.default_rng(0)
    db = sdr.random_sdrs(60, n_bits=256, n_active=20, seed=1)
    q = sdr.add_noise(db[rng.permutation(60)[:25]], 0.3, seed=2)
    dense = similarity.overlap(db, q)
    top = similarity.overlap(db, q, top_k=3, chunk=7)
    assert sp.issparse(top) and top.shape == dense.shape
    assert np.all(np.diff(top.tocsc().indptr) == 3)
    for j in range(25):
        kept = top[:, j].toarray().ravel()
        idx = np.flatnonzero(top[:, j].toarray().ravel() != 0) if kept.any() else []
        assert np.isclose(kept.max(), dense[:, j].max())
        assert len(idx) <= 3


def test_dense_refused_for_huge_inputs(monkeypatch):
    monkeypatch.setattr(similarity, "DENSE_LIMIT", 10)
    a = sdr.random_sdrs(11, n_bits=64, n_active=4, seed=0)
    with pytest.raises(ValueError, match="top_k"):
        similarity.overlap(a)
    assert similarity.overlap(a, top_k=2).nnz == 22


def test_cosine_and_sad():
    X = np.array([[1.0, 0], [0, 2], [0, 0]])
    C = similarity.cosine(X)
    assert np.allclose(C, [[1, 0, 0], [0, 1, 0], [0, 0, 0]])
    D = similarity.neg_sad(X, X[:2])
    assert np.allclose(D, -np.abs(X[:, None] - X[None, :2]).mean(2))
    with pytest.raises(ValueError, match="NaN"):
        similarity.cosine([[np.nan, 1.0]])
    with pytest.raises(ValueError, match="sizes differ"):
        similarity.cosine(X, np.ones((1, 3)))


def test_pairwise_dispatch():
    a = sdr.random_sdrs(5, n_bits=64, n_active=8, seed=3)
    assert np.allclose(pairwise(a), similarity.overlap(a))
    X = np.random.default_rng(0).random((4, 6))
    assert np.allclose(pairwise(X, X[:2]), similarity.cosine(X, X[:2]))
    assert np.allclose(pairwise(X, metric="sad"), similarity.neg_sad(X))
    with pytest.raises(ValueError, match="metric"):
        pairwise(X, metric="l7")
