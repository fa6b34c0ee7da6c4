"""Tests for vpr.seqslam.

The brute-force reference below (``ref_*``) is a deliberately plain per-query,
per-row loop written from the documented semantics; the vectorised module is
checked against it, against a literal reading of OpenSeqSLAM's matching step
(interior queries), and against a convolution of D with an identity kernel.
``research/benchmarks/bench_seqslam.py`` imports the reference to time it.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.signal import convolve2d

from vpr.seqslam import (
    SeqSLAMResult,
    difference_matrix,
    enhance_contrast,
    match_images,
    seqslam,
    trajectory_offsets,
)


# --------------------------------------------------------------------------- #
# brute-force reference
# --------------------------------------------------------------------------- #
def ref_enhance(D, R=10):
    """Row-by-row contrast enhancement (OpenSeqSLAM's loop, z = 0 for flat windows)."""
    D = np.asarray(D, dtype=np.float64)
    n = D.shape[0]
    h = R // 2
    Z = np.zeros_like(D)
    for i in range(n):
        w = D[max(0, i - h):min(n, i + h + 1)]
        if len(w) < 2:
            continue
        mu = w.mean(axis=0)
        sd = w.std(axis=0, ddof=1)
        for q in range(D.shape[1]):
            if sd[q] > 0 and sd[q] > 1e-10 * abs(mu[q]):
                Z[i, q] = (D[i, q] - mu[q]) / sd[q]
    return Z - Z.min()


def ref_offsets(ds, v_min, v_max, v_step):
    """Offset rows floor(k * v), one per velocity (duplicates kept)."""
    out = []
    j = 0
    while v_min + j * v_step <= v_max + 1e-9:
        v = v_min + j * v_step
        out.append([math.floor(k * v + 1e-9) for k in range(ds + 1)])
        j += 1
    return np.array(out, dtype=np.int64)


def ref_score_column(DD, q, offsets, ds, causal):
    """Complete (S) and partial (P) trajectory scores of query column q."""
    n_db, n_q = DD.shape
    a = ds if causal else ds // 2
    ks = np.array([k for k in range(ds + 1) if 0 <= q - a + k < n_q])
    cols = q - a + ks
    S = np.full(n_db, np.inf)
    P = np.full(n_db, np.inf)
    for i in range(n_db):
        for off in offsets:
            start = i - (off[ds] if causal else ds // 2)
            rows = start + off[ks]
            inside = (rows >= 0) & (rows < n_db)
            if not inside.any():
                continue
            val = DD[rows[inside], cols[inside]].astype(np.float64).sum() * (ds + 1) / inside.sum()
            P[i] = min(P[i], val)
            if inside.all():
                S[i] = min(S[i], val)
    return S, P


def ref_uniqueness(T, rwindow):
    """Best row, best value, OpenSeqSLAM's ratio and the second best, for one column."""
    b = int(np.argmin(T))
    best = T[b]
    rest = [T[j] for j in range(len(T)) if abs(j - b) > rwindow // 2]
    second = min(rest) if rest else np.inf
    if not np.isfinite(best) or second == 0:
        ratio = 1.0
    elif np.isinf(second):
        ratio = 0.0
    else:
        ratio = best / second
    return b, best, ratio, second


def ref_seqslam(D, ds=10, v_min=0.8, v_max=1.2, v_step=0.1, R=10, rwindow=10,
                ratio_threshold=0.9, causal=False, enhance=True):
    """Per-query loop reference: S, P, best_db, best_score, ratio, second, accepted, complete."""
    DD = ref_enhance(D, R) if enhance else np.asarray(D, dtype=np.float64)
    offsets = ref_offsets(ds, v_min, v_max, v_step)
    n_db, n_q = DD.shape
    S = np.empty((n_db, n_q))
    P = np.empty((n_db, n_q))
    best_db = np.empty(n_q, dtype=np.int64)
    best_score = np.empty(n_q)
    ratio = np.empty(n_q)
    second = np.empty(n_q)
    complete = np.empty(n_q, dtype=bool)
    for q in range(n_q):
        S[:, q], P[:, q] = ref_score_column(DD, q, offsets, ds, causal)
        complete[q] = np.isfinite(S[:, q]).any()
        T = S[:, q] if complete[q] else P[:, q]
        best_db[q], best_score[q], ratio[q], second[q] = ref_uniqueness(T, rwindow)
    accepted = np.isfinite(best_score) & (ratio <= ratio_threshold)
    return dict(S=S, P=P, best_db=best_db, best_score=best_score, ratio=ratio, second=second,
                accepted=accepted, complete=complete, DD=DD)


def openseqslam_interior(DD, ds=10, vmin=0.8, vmax=1.2, rwindow=10):
    """OpenSeqSLAM's matching step, read literally (0-based), for interior queries only.

    Scores are indexed by the trajectory's first database row, a row of inf is
    appended below the matrix, indices past it are clamped onto it, and the
    reported match is ``start + ds/2``. Velocities are ``move / ds`` for integer
    moves from ``vmin * ds`` to ``vmax * ds``.
    """
    n_db, n_q = DD.shape
    padded = np.vstack([DD, np.full((1, n_q), np.inf)])
    moves = np.arange(round(vmin * ds), round(vmax * ds) + 1)
    add = np.floor(np.arange(ds + 1)[None, :] * (moves[:, None] / ds)).astype(int)
    out = {}
    for N in range(ds // 2, n_q - ds // 2):
        x = np.arange(N - ds // 2, N + ds // 2 + 1)
        score = np.empty(n_db + 1)
        for s in range(n_db + 1):
            y = np.minimum(add + s, n_db)
            score[s] = padded[y, x[None, :]].sum(axis=1).min()
        m = int(np.argmin(score))
        lo, hi = max(0, m - rwindow // 2), min(n_db, m + rwindow // 2)
        rest = np.concatenate([score[:lo], score[hi + 1:]])
        out[N] = (m + ds // 2, score[m] / rest.min())
    return out


# --------------------------------------------------------------------------- #
# helpers
# --------------------------------------------------------------------------- #
def _check_against_reference(D, **kw):
    res = seqslam(D, **kw)
    ref = ref_seqslam(D, **kw)
    assert isinstance(res, SeqSLAMResult)
    n_db, n_q = np.shape(D)
    assert res.similarity.shape == res.score.shape == (n_db, n_q)
    assert res.similarity.dtype == np.float32
    assert np.isfinite(res.similarity).all()
    for a in (res.score, res.best_score, res.ratio):
        assert not np.isnan(a).any()
    # scores: same infeasible entries, same finite values
    assert np.array_equal(np.isinf(res.score), np.isinf(ref["S"]))
    fin = np.isfinite(ref["S"])
    scale = max(1.0, float(np.abs(ref["S"][fin]).max())) if fin.any() else 1.0
    np.testing.assert_allclose(res.score[fin], ref["S"][fin], rtol=1e-5, atol=1e-5 * scale)
    assert np.array_equal(res.complete, ref["complete"])
    # best row: optimal under the reference (float32 sums may break near-ties differently)
    cols = np.arange(n_q)
    T = np.where(ref["complete"][None, :], ref["S"], ref["P"])
    got = T[res.best_db, cols]
    want = T.min(axis=0)
    both_inf = np.isinf(got) & np.isinf(want)
    assert np.all(both_inf | (got <= want + 1e-4 * scale))
    same = res.best_db == ref["best_db"]
    np.testing.assert_allclose(res.best_score[same], ref["best_score"][same], rtol=1e-5, atol=1e-5 * scale)
    # ratio = best / second carries float32 rounding of both, relative to the matrix
    # scale; a second best at rounding level from 0 leaves it undetermined (0/0 vs 0/eps)
    second = ref["second"]
    sure = same & ~((second > 0) & (second < 1e-4 * scale))
    tol = 1e-4 * ref["ratio"] + 1e-5 * scale / np.where(np.isfinite(second) & (second > 0), second, 1.0)
    assert np.all(np.abs(res.ratio - ref["ratio"])[sure] <= tol[sure] + 1e-6)
    clear = sure & (np.abs(ref["ratio"] - kw.get("ratio_threshold", 0.9)) > 2 * tol)
    assert np.array_equal(res.accepted[clear], ref["accepted"][clear])
    # similarity: -score where feasible, everything else strictly below, ordered by partial score
    feas = np.isfinite(res.score)
    np.testing.assert_array_equal(res.similarity[feas], -res.score[feas])
    if feas.any() and (~feas).any():
        assert res.similarity[~feas].max() < res.similarity[feas].min()
    part = ~feas & np.isfinite(ref["P"])
    if part.sum() > 1:
        order = np.argsort(ref["P"][part], kind="stable")
        assert np.all(np.diff(res.similarity[part][order]) <= 1e-4 * scale)
    none = ~feas & ~np.isfinite(ref["P"])
    if none.any() and (~none).any():
        assert res.similarity[none].max() < res.similarity[~none].min()
    return res, ref


# --------------------------------------------------------------------------- #
# trajectory search vs the reference
# --------------------------------------------------------------------------- #
@settings(max_examples=80, deadline=None)
@given(
    n_db=st.integers(1, 30),
    n_q=st.integers(1, 30),
    half_ds=st.integers(0, 6),
    odd=st.booleans(),
    causal=st.booleans(),
    enhance=st.booleans(),
    vel=st.sampled_from([(0.8, 1.2, 0.1), (1.0, 1.0, 0.1), (0.5, 1.5, 0.25), (0.0, 2.0, 0.5), (0.9, 1.3, 0.2)]),
    R=st.sampled_from([2, 4, 10]),
    rwindow=st.sampled_from([0, 4, 10]),
    chunk=st.sampled_from([1, 7, 256]),
    seed=st.integers(0, 2**32 - 1),
)
def test_matches_reference_random(n_db, n_q, half_ds, odd, causal, enhance, vel, R, rwindow, chunk, seed):
    ds = 2 * half_ds + (1 if (odd and causal) else 0)
    D = np.random.default_rng(seed).random((n_db, n_q), dtype=np.float32)
    kw = dict(ds=ds, v_min=vel[0], v_max=vel[1], v_step=vel[2], R=R, rwindow=rwindow,
              causal=causal, enhance=enhance)
    res, _ = _check_against_reference(D, **kw)
    again = seqslam(D, chunk=chunk, **kw)
    np.testing.assert_array_equal(again.score, res.score)
    np.testing.assert_array_equal(again.best_db, res.best_db)


@pytest.mark.parametrize("causal", [False, True])
def test_defaults_match_reference(causal):
    D = np.random.default_rng(1).random((45, 52), dtype=np.float32)
    _check_against_reference(D, causal=causal)


def test_interior_matches_literal_openseqslam():
    rng = np.random.default_rng(2)
    n = 60
    D = rng.random((n, n), dtype=np.float32)
    D[np.arange(n), np.arange(n)] *= 0.2
    res = seqslam(D)
    lit = openseqslam_interior(enhance_contrast(D).astype(np.float64))
    assert len(lit) == n - 10
    for q, (row, ratio) in lit.items():
        assert res.best_db[q] == row
        assert res.ratio[q] == pytest.approx(ratio, rel=1e-4)
    # OpenSeqSLAM has no match here; we do, and it is complete
    assert res.complete.all()


def test_default_trajectories_are_openseqslams():
    vel, off = trajectory_offsets()
    np.testing.assert_allclose(vel, [0.8, 0.9, 1.0, 1.1, 1.2])
    k = np.arange(11)
    want = np.array([(k * m) // 10 for m in range(8, 13)])    # exact integer floor(k * m / 10)
    np.testing.assert_array_equal(off, want)
    assert want[4].tolist() == [0, 1, 2, 3, 4, 6, 7, 8, 9, 10, 12]


def test_duplicate_velocity_trajectories_searched_once():
    # with ds = 2, v = 0.8, 0.9 give floor offsets (0, 0, 1) and v = 1.0 .. 1.2 give (0, 1, 2)
    _, off = trajectory_offsets(ds=2)
    assert sorted(map(tuple, off.tolist())) == [(0, 0, 1), (0, 1, 2)]


# --------------------------------------------------------------------------- #
# v = 1 against a convolution with an identity kernel
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("causal", [False, True])
@pytest.mark.parametrize("ds", [0, 4, 10])
def test_v1_is_identity_convolution(ds, causal):
    rng = np.random.default_rng(3)
    D = rng.random((40, 33)) * 3.0
    res = seqslam(D, ds=ds, v_min=1.0, v_max=1.0, enhance=False, causal=causal)
    conv = convolve2d(D, np.eye(ds + 1), mode="valid")   # conv[m, n] = sum_k D[m+k, n+k]
    lag = ds if causal else ds // 2
    n_db, n_q = D.shape
    inner = res.score[lag:lag + conv.shape[0], lag:lag + conv.shape[1]]
    np.testing.assert_allclose(inner, conv, rtol=1e-5)
    # rows whose diagonal leaves the database are infeasible for interior queries
    q_in = slice(lag, n_q - (ds - lag))
    assert np.isinf(res.score[:lag, q_in]).all()
    assert np.isinf(res.score[n_db - (ds - lag):, q_in]).all()


# --------------------------------------------------------------------------- #
# edges
# --------------------------------------------------------------------------- #
def _band(n_db, n_q, shift=0):
    """Difference matrix with a clean diagonal: D[i, q] = |i - (q - shift)|, capped."""
    i = np.arange(n_db)[:, None]
    q = np.arange(n_q)[None, :]
    return np.minimum(np.abs(i - (q - shift)), 8).astype(np.float32) / 8.0


@pytest.mark.parametrize("enhance", [False, True])
@pytest.mark.parametrize("causal", [False, True])
def test_edge_queries_find_the_diagonal(causal, enhance):
    D = _band(50, 50)
    res = seqslam(D, causal=causal, enhance=enhance)
    np.testing.assert_array_equal(res.best_db, np.arange(50))
    assert res.complete.all()
    assert np.isfinite(res.best_score).all()


def test_edge_columns_are_rescaled_truncated_sums():
    rng = np.random.default_rng(4)
    D = rng.random((30, 20))
    ds = 10
    res = seqslam(D, ds=ds, v_min=1.0, v_max=1.0, enhance=False)
    # first query: frames 0..5 only, rows i .. i+5
    for i in range(0, 30 - 5):
        want = D[i + np.arange(6), np.arange(6)].sum() * 11 / 6
        assert res.score[i, 0] == pytest.approx(want, rel=1e-5)
    # last query (19): frames 14..19, rows i-5 .. i
    for i in range(5, 30):
        want = D[i - 5 + np.arange(6), 14 + np.arange(6)].sum() * 11 / 6
        assert res.score[i, 19] == pytest.approx(want, rel=1e-5)
    # and the column-2 window (frames 0..7) is scaled by 11/8
    assert res.score[10, 2] == pytest.approx(D[10 - 2 + np.arange(8), np.arange(8)].sum() * 11 / 8, rel=1e-5)


@pytest.mark.parametrize("causal", [False, True])
def test_database_shorter_than_ds(causal):
    # 5 database places seen at queries 10..14 of a 30-frame query run
    D = _band(5, 30, shift=10)
    res, ref = _check_against_reference(D, causal=causal)
    # every 11-frame trajectory spans >= 9 database rows: only query-edge columns,
    # whose windows are cut short, can hold a complete one
    assert not res.complete[10:25].any()
    assert np.isinf(res.score[:, 10:25]).all()
    # partial trajectories are reported at their v = 1 anchor row, so a faster
    # one that leaves the database early may win by one row
    assert np.abs(res.best_db[10:15] - np.arange(5)).max() <= 1
    assert ((res.best_db >= 0) & (res.best_db < 5)).all()


def test_single_database_row_and_single_query():
    for shape in [(1, 12), (12, 1), (1, 1)]:
        D = np.random.default_rng(5).random(shape)
        for causal in (False, True):
            _check_against_reference(D, causal=causal)


def test_no_competitor_outside_window_gives_ratio_zero():
    # OpenSeqSLAM's appended inf row makes best / inf = 0: accepted
    D = _band(12, 30, shift=8)
    res = seqslam(D, rwindow=30)
    assert (res.ratio == 0).all() and res.accepted.all()


@pytest.mark.parametrize("enhance", [False, True])
def test_constant_matrix_is_nan_free_and_rejected(enhance):
    D = np.zeros((25, 25), dtype=np.float32)
    res = seqslam(D, enhance=enhance)
    for a in (res.similarity, res.best_score, res.ratio):
        assert np.isfinite(a).all()
    assert not np.isnan(res.score).any()
    assert (res.ratio == 1).all() and not res.accepted.any()


# --------------------------------------------------------------------------- #
# contrast enhancement
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("shape,R", [((40, 17), 10), ((7, 5), 10), ((1, 4), 10), ((2, 3), 2), ((30, 9), 5)])
def test_enhance_matches_reference(shape, R):
    D = np.random.default_rng(6).random(shape) * 5
    E = enhance_contrast(D, R=R)
    assert E.dtype == np.float32 and E.min() == 0
    np.testing.assert_allclose(E, ref_enhance(D, R), rtol=1e-5, atol=1e-5)


def test_enhance_flat_windows_are_zero_not_nan():
    D = np.random.default_rng(7).random((30, 6)) + 1.0
    D[:, 2] = 0.1                     # constant column (inexact in binary)
    D[10:25, 4] = 3.0                 # constant run
    E = enhance_contrast(D)
    assert np.isfinite(E).all()
    Z = E - E[:, 2:3]                 # the constant column sits at the shift, z = 0
    assert np.all(Z[:, 2] == 0)
    np.testing.assert_allclose(E, ref_enhance(D), rtol=1e-5, atol=1e-5)
    assert np.allclose(E[15:20, 4], E[0, 2])


def test_enhance_is_scale_and_shift_invariant():
    D = np.random.default_rng(8).random((20, 20))
    np.testing.assert_allclose(enhance_contrast(D), enhance_contrast(3.5 * D + 2.0), rtol=1e-4, atol=1e-5)


# --------------------------------------------------------------------------- #
# difference matrix and images
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("chunk", [1, 3, 512])
def test_difference_matrix_sad_and_cosine(chunk):
    rng = np.random.default_rng(9)
    a = rng.standard_normal((11, 4, 5)).astype(np.float32)
    b = rng.standard_normal((7, 20)).astype(np.float32)
    b[3] = 0
    af = a.reshape(11, -1).astype(np.float64)
    sad = np.abs(af[:, None, :] - b[None, :, :]).mean(axis=2)
    D = difference_matrix(a, b, chunk=chunk)
    assert D.dtype == np.float32 and D.shape == (11, 7)
    np.testing.assert_allclose(D, sad, rtol=1e-5)
    C = difference_matrix(a, b, metric="cosine", chunk=chunk)
    nb = np.linalg.norm(b, axis=1)
    cos = (af @ b.T) / np.linalg.norm(af, axis=1)[:, None] / np.where(nb > 0, nb, 1)[None, :]
    np.testing.assert_allclose(C, np.clip(1 - cos, 0, 2), atol=1e-6)
    np.testing.assert_allclose(C[:, 3], 1.0)
    assert np.allclose(np.diag(difference_matrix(b, b, metric="cosine"))[[0, 1, 2, 4, 5, 6]], 0, atol=1e-6)


def _scene(rng, n, h=48, w=96):
    """A route of n views: a long smooth random panorama seen through a sliding window."""
    pano = rng.random((h, w + 4 * n)).astype(np.float32)
    pano = (pano + np.roll(pano, 1, axis=1) + np.roll(pano, 1, axis=0)) / 3
    return [pano[:, 4 * k:4 * k + w] for k in range(n)]


def test_match_images_end_to_end():
    rng = np.random.default_rng(10)
    db = _scene(rng, 40)
    q = [np.clip(0.6 * im + 0.2 + rng.normal(0, 0.05, im.shape), 0, 1).astype(np.float32) for im in db]
    res = match_images(db, q)
    np.testing.assert_array_equal(res.best_db, np.arange(40))
    assert res.accepted[5:35].all()
    cos = match_images(db, q, metric="cosine", causal=True)
    assert (np.abs(cos.best_db - np.arange(40)) <= 1).all()


# --------------------------------------------------------------------------- #
# bad input
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("D,kw,arg", [
    (np.ones(5), {}, "D"),
    (np.zeros((0, 3)), {}, "D"),
    (np.array([[0.0, np.nan]]), {}, "D"),
    (np.array([[0.0, np.inf]]), {}, "D"),
    (np.array([[0.0, -1.0]]), {"enhance": False}, "D"),
    (np.ones((4, 4)), {"ds": 3}, "ds"),
    (np.ones((4, 4)), {"ds": -2}, "ds"),
    (np.ones((4, 4)), {"ds": 2.0}, "ds"),
    (np.ones((4, 4)), {"v_min": 1.3}, "v_max"),
    (np.ones((4, 4)), {"v_min": -0.5}, "v_min"),
    (np.ones((4, 4)), {"v_step": 0}, "v_step"),
    (np.ones((4, 4)), {"v_max": np.nan}, "v_max"),
    (np.ones((4, 4)), {"R": 1}, "R"),
    (np.ones((4, 4)), {"rwindow": -1}, "rwindow"),
    (np.ones((4, 4)), {"ratio_threshold": "x"}, "ratio_threshold"),
    (np.ones((4, 4)), {"chunk": 0}, "chunk"),
])
def test_seqslam_bad_input(D, kw, arg):
    with pytest.raises(ValueError, match=f"^{arg}:"):
        seqslam(D, **kw)


def test_odd_ds_is_fine_when_causal():
    D = np.random.default_rng(11).random((20, 20))
    _check_against_reference(D, ds=5, causal=True)


@pytest.mark.parametrize("a,b,kw,arg", [
    (np.ones((3, 4)), np.ones((2, 5)), {}, "q_desc"),
    (np.ones(3), np.ones((2, 3)), {}, "db_desc"),
    (np.ones((3, 4)), np.ones((0, 4)), {}, "q_desc"),
    (np.ones((3, 4)), np.full((2, 4), np.nan), {}, "q_desc"),
    (np.ones((3, 4)), np.ones((2, 4)), {"metric": "l2"}, "metric"),
])
def test_difference_matrix_bad_input(a, b, kw, arg):
    with pytest.raises(ValueError, match=f"^{arg}:"):
        difference_matrix(a, b, **kw)


def test_match_images_bad_input():
    with pytest.raises(ValueError, match="^q_images"):
        match_images([np.zeros((32, 64))], [])
    with pytest.raises(ValueError, match=r"^db_images\[1\]"):
        match_images([np.zeros((32, 64)), np.full((32, 64), np.nan)], [np.zeros((32, 64))])


def test_too_many_velocities_is_an_error():
    with pytest.raises(ValueError, match="^v_step:"):
        trajectory_offsets(v_step=1e-8)


# --------------------------------------------------------------------------- #
# seqslam_topk: blocked, from descriptors, top-K output
# --------------------------------------------------------------------------- #
from vpr import sdr as _sdr  # noqa: E402
from vpr.seqslam import seqslam_topk  # noqa: E402


def _dense_topk_values(sim, k):
    """Per column, the k highest values of a dense similarity, descending."""
    return [np.sort(sim[:, q])[::-1][:k] for q in range(sim.shape[1])]


def _check_topk_against_dense(res, ref, top_k, exact=True):
    """seqslam_topk vs the dense seqslam: fields within float32 rounding, top-K content equal."""
    assert isinstance(res, SeqSLAMResult) and res.score is None
    n_db, n_q = ref.score.shape
    assert res.similarity.shape == (n_db, n_q) and res.similarity.dtype == np.float32
    assert res.exact is exact
    k = min(top_k, n_db)
    C = res.similarity.tocsc()
    assert np.all(np.diff(C.indptr) == k)
    fin = np.isfinite(ref.score)
    scale = max(1.0, float(np.abs(ref.score[fin]).max())) if fin.any() else 1.0
    tol = 1e-5 * scale
    want = _dense_topk_values(ref.similarity, k)
    for q in range(n_q):
        rows = C.indices[C.indptr[q]:C.indptr[q + 1]]
        vals = C.data[C.indptr[q]:C.indptr[q + 1]]
        # each kept entry carries the dense value of its cell, and the kept values are the dense top-K
        np.testing.assert_allclose(vals, ref.similarity[rows, q], rtol=1e-5, atol=tol)
        np.testing.assert_allclose(np.sort(vals)[::-1], want[q], rtol=1e-5, atol=tol)
    np.testing.assert_array_equal(res.complete, ref.complete)
    # best row: the dense one, unless the dense column has a float32 near-tie at its best
    T = np.where(ref.complete[None, :], ref.score, -ref.similarity)
    Ts = np.sort(T, axis=0)
    tie = (Ts[1] - Ts[0] <= 4 * tol) if n_db > 1 else np.zeros(n_q, bool)
    np.testing.assert_array_equal(res.best_db[~tie], ref.best_db[~tie])
    same = res.best_db == ref.best_db
    np.testing.assert_allclose(res.best_score[same], ref.best_score[same], rtol=1e-5, atol=tol)
    close = same & (np.abs(res.ratio - ref.ratio) <= 1e-3)
    assert close[~tie].mean() >= 0.95 if (~tie).any() else True
    np.testing.assert_array_equal(res.accepted[close & (np.abs(ref.ratio - 0.9) > 1e-3)],
                                  ref.accepted[close & (np.abs(ref.ratio - 0.9) > 1e-3)])


@settings(max_examples=60, deadline=None)
@given(
    n_db=st.integers(1, 40),
    n_q=st.integers(1, 40),
    half_ds=st.integers(0, 5),
    causal=st.booleans(),
    enhance=st.booleans(),
    vel=st.sampled_from([(0.8, 1.2, 0.1), (1.0, 1.0, 0.1), (0.5, 1.5, 0.25), (0.9, 1.3, 0.2)]),
    metric=st.sampled_from(["sad", "cosine"]),
    block=st.integers(1, 45),
    top_k=st.integers(1, 12),
    seed=st.integers(0, 2**32 - 1),
)
def test_topk_equals_dense_random(n_db, n_q, half_ds, causal, enhance, vel, metric, block, top_k, seed):
    rng = np.random.default_rng(seed)
    a = rng.random((n_db, 6), dtype=np.float32)
    b = rng.random((n_q, 6), dtype=np.float32)
    kw = dict(ds=2 * half_ds, v_min=vel[0], v_max=vel[1], v_step=vel[2], causal=causal, enhance=enhance)
    ref = seqslam(difference_matrix(a, b, metric=metric), **kw)
    res = seqslam_topk(a, b, top_k=top_k, metric=metric, block=block, **kw)
    _check_topk_against_dense(res, ref, top_k)
    assert res.cells == n_db * n_q


@pytest.mark.parametrize("metric", ["sad", "cosine"])
@pytest.mark.parametrize("causal", [False, True])
def test_topk_sdr_equals_dense_on_01_rows(metric, causal):
    # SDRs go through overlaps, never densified; the dense reference sees the 0/1 rows
    rng = np.random.default_rng(3)
    db = _sdr.add_noise(_sdr.random_sdrs(60, 256, 24, seed=rng), 0.2, seed=rng)
    q = _sdr.add_noise(db[5:55], 0.4, seed=rng)
    ref = seqslam(difference_matrix(db.toarray().astype(np.float32), q.toarray().astype(np.float32),
                                    metric=metric), causal=causal)
    res = seqslam_topk(db, q, top_k=15, metric=metric, block=16, causal=causal)
    _check_topk_against_dense(res, ref, 15)
    assert np.mean(np.abs(res.best_db[5:-5] - np.arange(5, 55)[5:-5]) <= 1) > 0.9


@pytest.mark.parametrize("causal", [False, True])
@pytest.mark.parametrize("n_db", [1, 3, 8])
def test_topk_database_shorter_than_ds(n_db, causal):
    rng = np.random.default_rng(n_db)
    a, b = rng.random((n_db, 5), dtype=np.float32), rng.random((17, 5), dtype=np.float32)
    ref = seqslam(difference_matrix(a, b), causal=causal)
    res = seqslam_topk(a, b, top_k=4, block=5, causal=causal)
    assert not res.complete[10:12].any()     # interior: 11 frames at v >= 0.8 need 9 database rows
    _check_topk_against_dense(res, ref, 4)


def test_topk_border_queries_and_single_query():
    rng = np.random.default_rng(5)
    a = rng.random((30, 8), dtype=np.float32)
    for b in (a[:1] + 0.01, a[:4], a[-3:]):
        ref = seqslam(difference_matrix(a, b))
        _check_topk_against_dense(seqslam_topk(a, b, top_k=30, block=2), ref, 30)


def test_topk_candidates_covering_everything_is_exact():
    rng = np.random.default_rng(7)
    a, b = rng.random((50, 8), dtype=np.float32), rng.random((35, 8), dtype=np.float32)
    ref = seqslam(difference_matrix(a, b))
    every = sp.csr_matrix(np.ones((50, 35)))
    # every alignment a candidate, enough windows to hold them all: every row searched
    res = seqslam_topk(a, b, top_k=10, candidates=every, block=8, n_windows=50)
    _check_topk_against_dense(res, ref, 10, exact=True)
    dense_pattern = seqslam_topk(a, b, top_k=10, candidates=np.ones((50, 35), bool), block=8, n_windows=50)
    assert dense_pattern.similarity.nnz == res.similarity.nnz
    np.testing.assert_array_equal(dense_pattern.best_db, res.best_db)


def _aliased(n, seed, active=40):
    """Aliased SDR traverses: n places, n // 10 appearances, query at a varying speed, 35 % bits moved."""
    rng = np.random.default_rng(seed)
    app = _sdr.random_sdrs(max(1, n // 10), 2048, active, seed=rng)
    db = app[rng.integers(0, app.shape[0], n)]
    pos = np.cumsum(1.0 + 0.2 * np.sin(np.arange(n) / 60.0))
    gt = np.round(pos[pos <= n - 1]).astype(int)
    return _sdr.check_batch(db), _sdr.add_noise(db[gt], 0.35, seed=rng), gt


@pytest.mark.parametrize("stride", [1, 3])
def test_sdr_candidates_by_bit_sets_or_inverted_index_have_the_same_overlaps(monkeypatch, stride):
    from vpr.seqslam import topk

    db, q, _ = _aliased(400, 5, active=200)
    q = sp.vstack([q, sp.csr_matrix((1, q.shape[1]), dtype=bool)]).tocsr()  # one query sharing no bit
    d = topk._Descriptors(db, q, "sad")
    assert topk.bitsets_pay(db, q, against="index")
    assert not topk.bitsets_pay(*_aliased(400, 5)[:2], against="index")  # 40 of 2,048 bits: the index
    got = d.candidates(30, stride)
    monkeypatch.setattr(topk, "bitsets_pay", lambda a, b, against: False)
    ref = d.candidates(30, stride)
    np.testing.assert_array_equal(got[0], ref[0])  # as many candidates per query, none for skipped ones
    ov = (db.astype(np.int32) @ q.T.astype(np.int32)).toarray()
    for j in range(q.shape[0]):
        g, r = got[1][got[0][j]:got[0][j + 1]], ref[1][ref[0][j]:ref[0][j + 1]]
        np.testing.assert_array_equal(np.sort(ov[g, j]), np.sort(ov[r, j]))  # ties may pick other rows
        assert (ov[g, j] > 0).all()
    if (q.shape[0] - 1) % stride == 0:  # the query sharing no bit was sampled: it has no candidate
        assert got[0][-1] == got[0][-2]


def test_topk_candidate_windows_match_exact_on_aliased_traverses():
    db, q, gt = _aliased(1500, 11)
    ex = seqslam_topk(db, q, top_k=20)
    ca = seqslam_topk(db, q, top_k=20, candidates="pairwise")
    assert ex.exact and not ca.exact
    assert ca.cells < 0.5 * ex.cells
    # single frames are aliased ~10 times, so this is the sequence search at work
    assert np.mean(np.abs(ex.best_db - gt) <= 1) > 0.85
    assert np.mean(ca.best_db == ex.best_db) > 0.98
    # where both found the same best row, its score is the same exact trajectory score
    same = ca.best_db == ex.best_db
    shift = np.median(ca.best_score[same] - ex.best_score[same])    # global-minimum shift over searched cells only
    np.testing.assert_allclose(ca.best_score[same] - shift, ex.best_score[same], atol=1e-3)
    # kept entries are exact-mode entries up to that shift (the top-K itself differs: the
    # exact one also holds far-away rows the windows never search)
    E, Cc = ex.similarity.tocsc(), ca.similarity.tocsc()
    for q in np.flatnonzero(same)[::50]:
        er, ev = E.indices[E.indptr[q]:E.indptr[q + 1]], E.data[E.indptr[q]:E.indptr[q + 1]]
        cr, cv = Cc.indices[Cc.indptr[q]:Cc.indptr[q + 1]], Cc.data[Cc.indptr[q]:Cc.indptr[q + 1]]
        common, ie, ic = np.intersect1d(er, cr, return_indices=True)
        assert ex.best_db[q] in common
        np.testing.assert_allclose(cv[ic] + shift, ev[ie], atol=1e-3)


def test_topk_candidate_matrix_from_caller():
    db, q, gt = _aliased(800, 12)
    from vpr.similarity import overlap_similarity

    cand = overlap_similarity(db, q, top_k=30)
    res = seqslam_topk(db, q, top_k=10, candidates=cand, n_windows=2)
    assert np.mean(np.abs(res.best_db - gt) <= 1) > 0.85
    # a query block without any candidate searches nothing
    empty = sp.csr_matrix(cand.shape)
    none = seqslam_topk(db, q, candidates=empty)
    assert none.cells == 0 and (none.best_db == -1).all() and not none.accepted.any()
    assert none.similarity.nnz == 0


@pytest.mark.parametrize("kw, arg", [
    (dict(candidates="nearby"), "candidates"),
    (dict(candidates=np.ones((3, 3))), "candidates"),
    (dict(top_k=0), "top_k"),
    (dict(block=0), "block"),
    (dict(n_windows=0), "n_windows"),
    (dict(candidates="pairwise", candidate_stride=0), "candidate_stride"),
    (dict(metric="l2"), "metric"),
    (dict(ds=3), "ds"),
])
def test_topk_bad_input(kw, arg):
    a = np.random.default_rng(0).random((12, 4))
    with pytest.raises(ValueError, match=arg):
        seqslam_topk(a, a[:10], **kw)


def test_topk_mixed_descriptor_kinds_refused():
    db = _sdr.random_sdrs(5, 64, 4, seed=0)
    with pytest.raises(ValueError, match="q_desc"):
        seqslam_topk(db, db.toarray())
    with pytest.raises(ValueError, match="q_desc"):
        seqslam_topk(db, _sdr.random_sdrs(5, 32, 4, seed=0))


@pytest.mark.parametrize("metric", ["sad", "cosine"])
def test_topk_pairwise_candidates_on_dense_descriptors(metric):
    # a route of 600 smooth dense descriptors, revisited at speed 0.8-1.2 with noise
    rng = np.random.default_rng(21)
    db = np.cumsum(rng.standard_normal((600, 32)), axis=0).astype(np.float32)
    pos = np.cumsum(1.0 + 0.2 * np.sin(np.arange(600) / 40.0))
    gt = np.round(pos[pos <= 599]).astype(int)
    q = db[gt] + 2.0 * rng.standard_normal((len(gt), 32)).astype(np.float32)
    ex = seqslam_topk(db, q, metric=metric, top_k=5)
    ca = seqslam_topk(db, q, metric=metric, top_k=5, candidates="pairwise", n_candidates=10)
    assert ca.cells < 0.6 * ex.cells
    assert np.mean(ca.best_db == ex.best_db) > 0.97
    assert np.mean(np.abs(ca.best_db - gt) <= 2) > 0.9
