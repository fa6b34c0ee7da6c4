import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from vpr import sdr
from vpr.similarity import overlap_count


def test_from_indices_roundtrip_and_dedup():
    b = sdr.from_indices([[3, 1, 1], [], np.array([0, 7])], 8)
    assert b.dtype == bool and b.shape == (3, 8)
    assert [list(r) for r in sdr.to_indices(b)] == [[1, 3], [], [0, 7]]


@pytest.mark.parametrize("rows,msg", [
    ([[0, 8]], "row 0: bit index 8"),
    ([[1], [-1]], "row 1: bit index -1"),
    ([[1.5]], "row 0: non-integer"),
    ([[np.nan]], "row 0: NaN"),
    ([["a"]], "row 0: bit indices must be integers"),
])
def test_from_indices_bad_rows_name_the_row(rows, msg):
    with pytest.raises(ValueError, match=msg):
        sdr.from_indices(rows, 8)


def test_from_dense_and_check_batch_errors():
    assert sdr.from_dense(np.array([[0, 1, 1]])).nnz == 2
    with pytest.raises(ValueError, match="row 1: SDR values must be 0 or 1"):
        sdr.from_dense(np.array([[0, 1], [2, 0]]))
    with pytest.raises(ValueError, match="row 0: NaN"):
        sdr.from_dense(np.array([[np.nan, 1.0]]))
    with pytest.raises(ValueError, match="expected 16 bits"):
        sdr.check_batch(sdr.from_indices([[1]], 8), n_bits=16)
    bad = sp.csr_matrix(np.array([[0.0, 1.0], [0.0, 3.0]]))
    with pytest.raises(ValueError, match="row 1"):
        sdr.check_batch(bad)


def test_from_topk_exact_k_and_ties():
    v = np.array([[0.0, 5, 5, 1], [1, 1, 1, 1]])
    b = sdr.from_topk(v, 2)
    assert np.diff(b.indptr).tolist() == [2, 2]
    assert sdr.to_indices(b)[0].tolist() == [1, 2]
    assert sdr.to_indices(b)[1].tolist() == [0, 1]  # ties: lower index first
    with pytest.raises(ValueError, match="k must be"):
        sdr.from_topk(v, 5)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 30), st.floats(0, 1), st.integers(0, 1000))
def test_add_noise_moves_the_right_number_of_bits(n_active, fraction, seed):
    b = sdr.random_sdrs(5, n_bits=128, n_active=n_active, seed=seed)
    noisy = sdr.add_noise(b, fraction, seed=seed)
    assert np.array_equal(np.diff(noisy.indptr), np.diff(b.indptr))  # same number of 1-bits
    kept = overlap_count(b, noisy).diagonal()
    assert np.all(kept == n_active - int(round(fraction * n_active)))


def test_add_noise_is_seeded():
    b = sdr.random_sdrs(4, seed=0)
    assert (sdr.add_noise(b, 0.5, seed=1) != sdr.add_noise(b, 0.5, seed=1)).nnz == 0
    assert (sdr.add_noise(b, 0.5, seed=1) != sdr.add_noise(b, 0.5, seed=2)).nnz > 0
    with pytest.raises(ValueError, match="fraction"):
        sdr.add_noise(b, 1.5)


def test_overlap_count_density_union():
    b = sdr.from_indices([[0, 1, 2], [2, 3]], 10)
    assert overlap_count(b).tolist() == [[3, 1], [1, 2]]
    assert np.allclose(sdr.density(b), [0.3, 0.2])
    assert sdr.union(b).tolist() == [0, 1, 2, 3]


def test_from_topk_by_blocks_of_rows_equals_one_block(monkeypatch):
    rng = np.random.default_rng(3)
    x = rng.standard_normal((500, 64)).astype(np.float32)
    x[7, :10] = 0.0  # ties go to the lower index in every block
    x[8] = 0.0
    whole = sdr.from_topk(x, 12)
    monkeypatch.setattr(sdr, "_SORT_BLOCK", 64 * 7)  # 7 rows a block
    assert (sdr.from_topk(x, 12) != whole).nnz == 0
    x[433, 5] = np.nan
    with pytest.raises(ValueError, match="row 433"):
        sdr.from_topk(x, 12)


def test_row_log_holds_the_rows_appended_as_a_batch_would():
    rng = np.random.default_rng(0)
    rows = [np.sort(rng.choice(256, int(rng.integers(0, 30)), replace=False)) for _ in range(300)]
    batch = sdr.from_indices(rows, 256)
    log = sdr.RowLog()
    for r in rows:
        log.append(r)
    assert log.rows == 300
    np.testing.assert_array_equal(log.ptr, batch.indptr)
    np.testing.assert_array_equal(log.ind, batch.indices)
    # from the first rows of a batch, then on
    half = sdr.RowLog(batch[:100].indptr, batch[:100].indices)
    for r in rows[100:]:
        half.append(r)
    np.testing.assert_array_equal(half.ptr, batch.indptr)
    np.testing.assert_array_equal(half.ind, batch.indices)
    with pytest.raises(ValueError, match="RowLog"):
        sdr.RowLog([0, 3, 2], [1, 2])
