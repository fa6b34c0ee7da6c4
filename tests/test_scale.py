"""Above the dense limit every SDR method goes top-K sparse; rshosm-seq's sparse result agrees with the dense one."""
import numpy as np
import scipy.sparse as sp

from vpr import methods, similarity, simulate
from vpr.similarity import best_matches
from vpr.types import EncodedTraverse


def _aliased(n, seed=0):
    db, q, dp, qp = simulate.aliased_traverses(n, n // 10, seed=seed)
    return (EncodedTraverse(names=list(range(db.shape[0])), sdr=db),
            EncodedTraverse(names=list(range(q.shape[0])), sdr=q), dp, qp)


def test_rshosm_seq_goes_sparse_above_the_limit_with_the_dense_best_matches(monkeypatch):
    db, q, dp, qp = _aliased(600)
    dense = methods.match("rshosm-seq", db, q, {"seed": 0})
    assert isinstance(dense.similarity, np.ndarray)
    monkeypatch.setattr(similarity, "DENSE_PAIRS_LIMIT", 100)
    res = methods.match("rshosm-seq", db, q, {"seed": 0, "top_k": 7})
    S = res.similarity
    assert sp.issparse(S) and S.shape == (len(db), len(q))
    per_query = np.diff(sp.csc_matrix(S).indptr)
    assert per_query.max() == 7
    # the best match is the largest stored entry of its column (up to float32 ties), and the dense computation's
    # (the result's score is the decision's path score; the z-scores are the matrix's)
    z = np.asarray(S.tocsc()[res.best, np.arange(len(q))]).ravel()
    assert np.allclose(z, best_matches(S)[1], rtol=1e-6)
    assert np.mean(res.best == dense.best) >= 0.97
    # aliasing: single frames are ambiguous, the sequence is not
    assert np.mean(np.abs(dp[res.best] - qp) <= 1) >= 0.9
    # the kept entries are the z-scores of the dense column (absent cells carry no evidence, so nearly equal)
    cols = np.flatnonzero(res.best == dense.best)
    z_dense = dense.similarity[dense.best, np.arange(len(q))]
    assert np.allclose(z[cols], z_dense[cols], atol=0.05 * np.abs(z_dense[cols]).max())


def test_rshosm_seq_switches_to_the_sparse_evidence_at_its_own_lower_size(monkeypatch):
    # the sparse evidence becomes the faster one well below the memory limit (research/docs/benchmarks.md):
    # rshosm-seq switches there, the single-frame methods keep their dense matrix up to the limit
    from vpr.methods import rshosm_seq

    db, q, _, _ = _aliased(200, seed=2)
    pairs = len(db) * len(q)
    monkeypatch.setattr(rshosm_seq, "DENSE_EVIDENCE_PAIRS", pairs)
    assert isinstance(methods.match("rshosm-seq", db, q, {"top_k": 5}).similarity, np.ndarray)
    monkeypatch.setattr(rshosm_seq, "DENSE_EVIDENCE_PAIRS", pairs - 1)
    S = methods.match("rshosm-seq", db, q, {"top_k": 5}).similarity
    assert sp.issparse(S) and np.diff(sp.csc_matrix(S).indptr).max() <= 5
    assert isinstance(methods.match("pairwise", db, q, {"top_k": 5}).similarity, np.ndarray)
    assert similarity.top_k_or_dense(10, 10, 5, 99) == 5 and similarity.top_k_or_dense(10, 10, 5, 100) is None
    monkeypatch.setattr(similarity, "DENSE_PAIRS_LIMIT", 50)  # the memory limit still holds below a method's own
    assert similarity.top_k_or_dense(10, 10, 5, 100) == 5


def test_every_sdr_method_keeps_top_k_above_the_limit(monkeypatch):
    db, q, _, _ = _aliased(300, seed=1)
    monkeypatch.setattr(similarity, "DENSE_PAIRS_LIMIT", 100)
    for name in ("rshosm", "pairwise", "rshosm-seq"):
        S = methods.match(name, db, q, {"top_k": 5}).similarity
        assert sp.issparse(S), name
        assert np.diff(sp.csc_matrix(S).indptr).max() <= 5, name


def test_tolerance_ground_truth_is_a_sparse_band_above_the_limit(monkeypatch):
    from vpr import groundtruth

    rng = np.random.default_rng(3)
    db_i, q_i = np.sort(rng.choice(200, 60, replace=False)), rng.integers(0, 210, 50)  # e.g. --step, unsorted query
    spec = groundtruth.GroundTruthSpec(tolerance=2, soft=4)
    names_db, names_q = [str(i) for i in db_i], [str(i) for i in q_i]
    dense = groundtruth.build_gt(spec, names_db, names_q, db_i, q_i)
    monkeypatch.setattr(similarity, "DENSE_PAIRS_LIMIT", 100)
    band = groundtruth.build_gt(spec, names_db, names_q, db_i, q_i)
    for d, b in zip(dense, band, strict=True):
        assert sp.issparse(b) and b.dtype == bool
        assert np.array_equal(b.toarray(), d)


def test_position_ground_truth_is_sparse_above_the_limit(tmp_path, monkeypatch):
    from vpr import groundtruth

    rng = np.random.default_rng(4)
    files = []
    for name, n in (("db", 40), ("q", 30)):
        xy = rng.uniform(0, 10, (n, 2))
        (tmp_path / f"{name}.csv").write_text("frame,x,y\n" + "".join(f"{i},{x},{y}\n" for i, (x, y) in enumerate(xy)))
        files.append(str(tmp_path / f"{name}.csv"))
    spec = groundtruth.GroundTruthSpec(files=tuple(files), radius=1.5, soft=3.0)
    args = ([str(i) for i in range(40)], [str(i) for i in range(30)], list(range(40)), list(range(30)))
    dense = groundtruth.build_gt(spec, *args)
    monkeypatch.setattr(similarity, "DENSE_PAIRS_LIMIT", 100)
    for d, b in zip(dense, groundtruth.build_gt(spec, *args), strict=True):
        assert sp.issparse(b) and np.array_equal(b.toarray(), d) and d.any()
