import numpy as np
import pytest
import scipy.sparse as sp

from vpr import sdr, similarity
from vpr.frame_pairs import pairwise


def test_overlap_is_normalised_db_by_query():
    db = sdr.from_indices([[0, 1, 2, 3], [4, 5]], 8)
    q = sdr.from_indices([[0, 1], [4, 5], []], 8)
    S = similarity.overlap_similarity(db, q)
    assert S.shape == (2, 3)
    assert np.allclose(S, [[2 / np.sqrt(8), 0, 0], [0, 1, 0]])


def test_overlap_top_k_keeps_the_best_per_query():
    rng = np.random.default_rng(0)
    db = sdr.random_sdrs(60, n_bits=256, n_active=20, seed=1)
    q = sdr.add_noise(db[rng.permutation(60)[:25]], 0.3, seed=2)
    dense = similarity.overlap_similarity(db, q)
    top = similarity.overlap_similarity(db, q, top_k=3, chunk=7)
    assert sp.issparse(top) and top.shape == dense.shape
    assert np.all(np.diff(top.tocsc().indptr) == 3)
    for j in range(25):
        kept = top[:, j].toarray().ravel()
        idx = np.flatnonzero(top[:, j].toarray().ravel() != 0) if kept.any() else []
        assert np.isclose(kept.max(), dense[:, j].max())
        assert len(idx) <= 3


def test_dense_refused_above_the_pair_limit_only(monkeypatch):
    monkeypatch.setattr(similarity, "DENSE_PAIRS_LIMIT", 100)
    a = sdr.random_sdrs(11, n_bits=64, n_active=4, seed=0)
    with pytest.raises(ValueError, match="top_k"):
        similarity.overlap_similarity(a)  # 121 pairs
    assert similarity.overlap_similarity(a, top_k=2).nnz == 22
    # the limit counts pairs, not rows: a long side with a short one stays dense
    long = sdr.random_sdrs(50, n_bits=64, n_active=4, seed=1)
    assert similarity.overlap_similarity(long, a[:2]).shape == (50, 2)


def test_large_database_with_top_k_or_few_queries():
    # one side above 20,000 rows is fine with top_k
    db = sdr.random_sdrs(25_000, n_bits=64, n_active=4, seed=0)
    q = db[[3, 24_999] * 25]
    top = similarity.overlap_similarity(db, q, top_k=5)
    assert top.shape == (25_000, 50) and np.all(np.diff(top.tocsc().indptr) == 5)
    dense = similarity.overlap_similarity(db, q)  # 1.25 M pairs: far below the dense pair limit
    assert dense.shape == (25_000, 50)
    np.testing.assert_allclose(top.max(axis=0).toarray().ravel(), dense.max(axis=0))
    assert np.all(dense[3, 0::2] == 1) and np.all(dense[24_999, 1::2] == 1)


def test_topk_sparse_keeps_only_the_kept_entries_in_memory():
    # Before the fix each block's kept indices were a view of the whole n_db x block
    # argpartition output, so memory grew with n_db x n_q x 8 bytes (40 MB here).
    import tracemalloc

    n_db, n_q, chunk = 5_000, 1_000, 100
    block = np.random.default_rng(0).random((n_db, chunk)).astype(np.float32)
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        m = similarity.topk_sparse(lambda q0, q1: block[:, : q1 - q0], n_db, n_q, top_k=2, chunk=chunk)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert m.nnz == 2 * n_q
    per_block = block.nbytes * 4  # the block's negation and int64 argpartition indices, with margin
    assert peak < per_block + 2_000_000, f"peak {peak / 1e6:.1f} MB"
    best = np.sort(np.argsort(-block, axis=0)[:2], axis=0)
    np.testing.assert_array_equal(m.tocsc()[:, :chunk].indices.reshape(chunk, 2).T, best)


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
    assert np.allclose(pairwise(a), similarity.overlap_similarity(a))
    X = np.random.default_rng(0).random((4, 6))
    assert np.allclose(pairwise(X, X[:2]), similarity.cosine(X, X[:2]))
    assert np.allclose(pairwise(X, metric="sad"), similarity.neg_sad(X))
    with pytest.raises(ValueError, match="metric"):
        pairwise(X, metric="l7")


@pytest.mark.parametrize("n_bits, n_active", [(2048, 200), (100, 7), (64, 3), (130, 30)])
@pytest.mark.parametrize("normalise", [True, False])
def test_top_k_by_bit_sets_equals_the_sparse_product(monkeypatch, n_bits, n_active, normalise):
    rng = np.random.default_rng(n_bits)
    db = sp.csr_matrix(rng.random((90, n_bits)) < n_active / n_bits)
    q = sp.vstack([sp.csr_matrix(rng.random((40, n_bits)) < n_active / n_bits), db[:5], sp.csr_matrix((1, n_bits),
                                                                                                     dtype=bool)]).tocsr()
    for a, b, k in [(db, q, 6), (db, None, 4), (db[:3], q, 10), (db[:0], q, 3)]:
        assert similarity.bitsets_pay(a, a if b is None else b)
        got = similarity.overlap_similarity(a, b, top_k=k, normalise=normalise)
        with monkeypatch.context() as m:
            m.setattr(similarity, "bitsets_pay", lambda A, B: False)
            ref = similarity.overlap_similarity(a, b, top_k=k, normalise=normalise)
        assert got.shape == ref.shape and got.nnz == ref.nnz == got.shape[1] * min(k, a.shape[0])
        G, R = got.tocsc(), ref.tocsc()
        for j in range(got.shape[1]):
            np.testing.assert_array_equal(np.sort(G[:, j].data), np.sort(R[:, j].data))


def test_bit_sets_spread_the_kept_frames_of_a_tie_and_long_codes_stay_sparse():
    def key(d):  # the documented tie order: Fibonacci hashing of the frame number
        return (d * 0x9E3779B97F4A7C15) % 2**64

    db = sdr.from_indices([[0, 1]] * 8 + [[0, 1, 2, 3]], 70)
    q = sdr.from_indices([[0, 1, 2, 3], [5]], 70)
    S = similarity.overlap_similarity(db, q, top_k=3, normalise=False).tocsc()
    # query 0: frame 8 (4 bits shared), then the two of the eight frames tied at 2 with the largest keys
    tied = sorted(range(8), key=key)[-2:]
    np.testing.assert_array_equal(np.sort(S[:, 0].indices), sorted([*tied, 8]))
    # query 1 shares nothing: three frames kept with score 0, the same way
    np.testing.assert_array_equal(np.sort(S[:, 1].indices), sorted(sorted(range(9), key=key)[-3:]))
    assert S[:, 1].nnz == 3 and not S[:, 1].data.any()
    # one appearance at 1,000 places: the 10 kept spread over the database, not its first frames
    same = sdr.from_indices([[1, 2, 3]] * 1000, 64)
    kept = similarity.overlap_similarity(same, same[:1], top_k=10).tocsc().indices
    assert kept.min() < 200 and kept.max() > 800
    # winner codes: millions of cells, ten active; the sparse product is the cheaper one
    codes = sdr.from_indices([[i * 10 + j for j in range(10)] for i in range(20)], 3_000_000)
    assert not similarity.bitsets_pay(codes, codes)
    assert not similarity.bitsets_pay(codes, codes, against="index")
    with pytest.raises(ValueError, match="against"):
        similarity.bitsets_pay(codes, codes, against="dense")
