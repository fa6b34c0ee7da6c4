"""Tests for vpr.evaluate: brute-force cross-checks (hypothesis), hand examples, errors."""
import math

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vpr import evaluate as E
from vpr.evaluate import (
    auc_from_pr,
    auc_pr,
    average_precision,
    evaluate,
    pr_curve,
    recall_at_100p,
    recall_at_k,
    thin_pr,
)
from vpr.groundtruth import gt_from_labels, gt_from_positions, gt_from_tolerance, loop_closure_gt, loop_closure_mask

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# --------------------------------------------------------------------------- #
# brute-force reference definitions: plain loops, written from the spec
# --------------------------------------------------------------------------- #
def _evaluated(S, hard, soft, mask, i, j):
    """May pair (i, j) be predicted / ranked at all?"""
    if mask is not None and not mask[i][j]:
        return False
    if soft is not None and soft[i][j] and not hard[i][j]:
        return False
    return S[i][j] != -math.inf


def _brute_decisions(S, hard, soft, mask, matching):
    n_db, n_q = len(S), len(S[0])
    if matching == "multi":
        dec = [(S[i][j], hard[i][j]) for i in range(n_db) for j in range(n_q)
               if _evaluated(S, hard, soft, mask, i, j)]
        n_pos = sum(1 for i in range(n_db) for j in range(n_q)
                    if hard[i][j] and (mask is None or mask[i][j]))
        return dec, n_pos
    dec = []
    n_pos = 0
    for j in range(n_q):
        if any(hard[i][j] and (mask is None or mask[i][j]) for i in range(n_db)):
            n_pos += 1
        best = None
        for i in range(n_db):
            if _evaluated(S, hard, soft, mask, i, j) and (best is None or S[i][j] > S[best][j]):
                best = i
        if best is not None:
            dec.append((S[best][j], hard[best][j]))
    return dec, n_pos


def _brute_curve(S, hard, soft, mask, matching):
    dec, n_pos = _brute_decisions(S, hard, soft, mask, matching)
    if n_pos == 0:
        return None
    P, R, T, FP = [0.0], [0.0], [math.inf], [0]
    for t in sorted({s for s, _ in dec}, reverse=True):
        tp = sum(1 for s, h in dec if s >= t and h)
        fp = sum(1 for s, h in dec if s >= t and not h)
        P.append(tp / (tp + fp))
        R.append(tp / n_pos)
        T.append(t)
        FP.append(fp)
    if len(P) > 1:
        P[0] = P[1]  # the curve starts at recall 0 with the first threshold's precision
    return P, R, T, FP


def _brute_auc(P, R):
    area = 0.0
    for a in range(1, len(P)):
        area += (R[a] - R[a - 1]) * (P[a] + P[a - 1]) / 2
    return area


def _brute_r100p(R, FP):
    return max(r for r, fp in zip(R, FP, strict=True) if fp == 0)


def _brute_recall_at_k(S, hard, soft, mask, k):
    n_db, n_q = len(S), len(S[0])
    n_pos = hits = 0
    for j in range(n_q):
        if not any(hard[i][j] and (mask is None or mask[i][j]) for i in range(n_db)):
            continue
        n_pos += 1
        ranking = sorted((i for i in range(n_db) if _evaluated(S, hard, soft, mask, i, j)),
                         key=lambda i: (-S[i][j], i))
        if any(hard[i][j] for i in ranking[:k]):
            hits += 1
    return None if n_pos == 0 else hits / n_pos


# --------------------------------------------------------------------------- #
# strategies: small matrices with many ties, -inf entries, soft pairs and masks
# --------------------------------------------------------------------------- #
@st.composite
def problems(draw):
    n_db = draw(st.integers(1, 6))
    n_q = draw(st.integers(1, 6))
    cells = n_db * n_q
    # few distinct values so that ties are the rule, not the exception
    values = draw(st.lists(st.sampled_from([-math.inf, -1.0, 0.0, 0.5, 1.0, 2.0]),
                           min_size=cells, max_size=cells))
    S = np.array(values).reshape(n_db, n_q)
    bools = st.lists(st.booleans(), min_size=cells, max_size=cells)
    hard = np.array(draw(bools)).reshape(n_db, n_q)
    soft = None
    if draw(st.booleans()):
        soft = np.array(draw(bools)).reshape(n_db, n_q)
        if draw(st.booleans()):
            soft |= hard  # the usual case; the other one must work too
    mask = np.array(draw(bools)).reshape(n_db, n_q) if draw(st.booleans()) else None
    return S, hard, soft, mask


def _to_sparse(S, fmt):
    # stored = finite entries (explicit zeros included); -inf = not stored
    r, c = np.nonzero(np.isfinite(S))
    return sp.coo_matrix((S[r, c], (r, c)), shape=S.shape).asformat(fmt)


def _variants(S, hard, soft, mask):
    """Dense input, and sparse S with dense or sparse ground truth."""
    yield S, hard, soft, mask
    yield _to_sparse(S, "csr"), hard, soft, mask
    sp_or_none = lambda a: None if a is None else sp.csc_matrix(a)  # noqa: E731
    yield _to_sparse(S, "csc"), sp.csr_matrix(hard), sp_or_none(soft), sp_or_none(mask)


@SETTINGS
@given(problems(), st.sampled_from(["multi", "single"]))
def test_pr_auc_r100p_match_brute_force(problem, matching):
    S, hard, soft, mask = problem
    ref = _brute_curve(S.tolist(), hard.tolist(), None if soft is None else soft.tolist(),
                       None if mask is None else mask.tolist(), matching)
    for args in _variants(S, hard, soft, mask):
        if ref is None:
            with pytest.raises(ValueError, match="gt_hard"):
                pr_curve(*args[:3], matching=matching, mask=args[3])
            continue
        P, R, T = pr_curve(*args[:3], matching=matching, mask=args[3])
        np.testing.assert_allclose(P, ref[0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(R, ref[1], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(T, ref[2])
        assert auc_pr(*args[:3], matching=matching, mask=args[3]) == pytest.approx(
            _brute_auc(ref[0], ref[1]), abs=1e-12)
        assert recall_at_100p(*args[:3], matching=matching, mask=args[3]) == pytest.approx(
            _brute_r100p(ref[1], ref[3]), abs=1e-12)


@SETTINGS
@given(problems(), st.integers(1, 7))
def test_recall_at_k_matches_brute_force(problem, k):
    S, hard, soft, mask = problem
    ref = _brute_recall_at_k(S.tolist(), hard.tolist(), None if soft is None else soft.tolist(),
                             None if mask is None else mask.tolist(), k)
    for args in _variants(S, hard, soft, mask):
        if ref is None:
            with pytest.raises(ValueError, match="gt_hard"):
                recall_at_k(*args[:3], k=k, mask=args[3])
        else:
            assert recall_at_k(*args[:3], k=k, mask=args[3]) == pytest.approx(ref, abs=1e-12)


def _top_k(S, K):
    """(the K best rows per column as a sparse matrix, the same dense with -inf elsewhere): a retrieval stage."""
    top = np.argpartition(-S, K - 1, axis=0)[:K]
    cols = np.broadcast_to(np.arange(S.shape[1]), top.shape)
    S_topk = sp.csr_matrix((S[top, cols].ravel(), (top.ravel(), cols.ravel())), shape=S.shape)
    S_dense = np.full(S.shape, -np.inf)
    S_dense[top, cols] = S[top, cols]
    return S_topk, S_dense


@SETTINGS
@given(problems(), st.integers(1, 4))
def test_sparse_top_k_equals_dense_with_minus_inf(problem, K):
    S, hard, soft, mask = problem
    S = np.where(np.isinf(S), 0.0, S)
    n_db, n_q = S.shape
    K = min(K, n_db)
    # a real top-K matrix as a retrieval stage would produce it
    S_topk, S_dense = _top_k(S, K)
    if not (hard & (True if mask is None else mask)).any():
        return
    assert evaluate(S_topk, hard, soft, mask=mask) == evaluate(S_dense, hard, soft, mask=mask)
    for matching in ("multi", "single"):
        sparse_curve = pr_curve(S_topk, hard, soft, matching, mask)
        dense_curve = pr_curve(S_dense, hard, soft, matching, mask)
        for a, b in zip(sparse_curve, dense_curve, strict=True):
            np.testing.assert_array_equal(a, b)
    for k in (1, 2, 3):
        assert recall_at_k(S_topk, hard, soft, k, mask) == recall_at_k(S_dense, hard, soft, k, mask)


@SETTINGS
@given(problems())
def test_evaluate_agrees_with_individual_metrics(problem):
    S, hard, soft, mask = problem
    if not (hard & (True if mask is None else mask)).any():
        with pytest.raises(ValueError):
            evaluate(S, hard, soft, mask=mask)
        return
    res = evaluate(S, hard, soft, mask=mask)
    assert list(res) == ["ap", "auc_pr", "recall_at_100p", "recall_at_1", "recall_at_5", "auc_pr_single"]
    assert res["ap"] == average_precision(S, hard, soft, mask=mask)
    assert all(isinstance(v, float) for v in res.values())
    assert res["auc_pr"] == auc_pr(S, hard, soft, mask=mask)
    assert res["auc_pr_single"] == auc_pr(S, hard, soft, matching="single", mask=mask)
    assert res["recall_at_100p"] == recall_at_100p(S, hard, soft, mask=mask)
    assert res["recall_at_1"] == recall_at_k(S, hard, soft, k=1, mask=mask)
    assert res["recall_at_5"] == recall_at_k(S, hard, soft, k=5, mask=mask)


@SETTINGS
@given(problems())
def test_curve_invariants(problem):
    S, hard, soft, mask = problem
    try:
        P, R, T = pr_curve(S, hard, soft, mask=mask)
    except ValueError:
        return
    assert R[0] == 0 and T[0] == np.inf
    assert P[0] == (P[1] if len(P) > 1 else 0)
    assert np.all(np.diff(T) < 0), "one point per distinct threshold, decreasing"
    assert np.all(np.diff(R) >= 0)
    assert np.all((P >= 0) & (P <= 1)) and np.all((R >= 0) & (R <= 1))
    assert 0 <= auc_from_pr(P, R) <= 1
    keep = thin_pr(P, R)  # the thinned curve keeps AP, area and every point it shows
    p, r = P[keep], R[keep]
    assert keep[0] == 0 and keep[-1] == P.size - 1 and np.all(np.diff(keep) > 0)
    assert np.isclose(np.sum(np.diff(r) * p[1:]), np.sum(np.diff(R) * P[1:]))  # AP
    assert np.isclose(auc_from_pr(p, r), auc_from_pr(P, R))
    assert set(zip(R.tolist(), P.tolist(), strict=True)) >= set(zip(r.tolist(), p.tolist(), strict=True))


def test_thinned_curve_of_a_long_run_of_false_pairs_is_short():
    R = np.r_[0.0, 0.5, 0.5 * np.ones(10_000), 1.0]
    P = np.r_[1.0, 1.0, 1 / np.arange(2, 10_002), 0.5]
    keep = thin_pr(P, R)
    assert keep.tolist() == [0, 1, 10_001, 10_002]
    with pytest.raises(ValueError, match="equal length"):
        thin_pr(P[:-1], R)


# --------------------------------------------------------------------------- #
# hand-computed examples
# --------------------------------------------------------------------------- #
def test_hand_example_multi_and_single():
    S = np.array([[0.9, 0.2, 0.6],
                  [0.5, 0.8, 0.6],
                  [0.1, 0.3, 0.4]])
    hard = np.array([[True, False, False],
                     [False, False, False],
                     [False, True, False]])
    # multi: decisions sorted 0.9(T) 0.8(F) 0.6(F,F) 0.5 0.4 0.3(T) 0.2 0.1; n_pos = 2
    P, R, T = pr_curve(S, hard)
    np.testing.assert_array_equal(T, [np.inf, 0.9, 0.8, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1])
    np.testing.assert_allclose(R, [0, .5, .5, .5, .5, .5, 1, 1, 1])
    np.testing.assert_allclose(P, [1, 1, 1 / 2, 1 / 4, 1 / 5, 1 / 6, 2 / 7, 2 / 8, 2 / 9])
    # AP: recall steps 0 -> 0.5 at precision 1 (0.9), 0.5 -> 1 at precision 2/7 (0.3)
    assert average_precision(S, hard) == pytest.approx(0.5 * 1 + 0.5 * 2 / 7)
    assert recall_at_100p(S, hard) == 0.5
    # single: q0 -> db0 0.9 (T), q1 -> db1 0.8 (F), q2 tie 0.6 -> db0 (no true match: F)
    P, R, T = pr_curve(S, hard, matching="single")
    np.testing.assert_array_equal(T, [np.inf, 0.9, 0.8, 0.6])
    np.testing.assert_allclose(R, [0, .5, .5, .5])
    np.testing.assert_allclose(P, [1, 1, .5, 1 / 3])
    assert auc_pr(S, hard, matching="single") == pytest.approx(0.5 * 1.0)
    # recall@k: q1's true match db2 (0.3) ranks second, behind db1 (0.8)
    assert recall_at_k(S, hard, k=1) == 0.5
    assert recall_at_k(S, hard, k=2) == 1.0
    # a tie with a lower db index ranks first: db0 and db1 tie at 0.6 for q2
    hard2 = np.zeros_like(hard)
    hard2[1, 2] = True
    assert recall_at_k(S, hard2, k=1) == 0.0
    assert recall_at_k(S, hard2, k=2) == 1.0


def test_soft_pairs_are_ignored_not_false():
    S = np.array([[0.9], [0.8], [0.1]])
    hard = np.array([[False], [True], [False]])
    soft = np.array([[True], [True], [False]])
    assert recall_at_k(S, hard, k=1) == 0.0
    assert recall_at_k(S, hard, soft, k=1) == 1.0
    assert recall_at_100p(S, hard) == 0.0
    assert recall_at_100p(S, hard, soft) == 1.0
    assert auc_pr(S, hard, soft) == 1.0


def test_perfect_and_worst_ranking():
    n = 8
    hard = np.eye(n, dtype=bool)
    S = np.eye(n) + 0.01 * np.random.default_rng(0).random((n, n))
    assert evaluate(S, hard) == {"ap": 1.0, "auc_pr": 1.0, "recall_at_100p": 1.0, "recall_at_1": 1.0,
                                 "recall_at_5": 1.0, "auc_pr_single": 1.0}
    res = evaluate(-S, hard)
    assert res["recall_at_100p"] == 0.0 and res["recall_at_1"] == 0.0
    assert res["auc_pr"] < 0.2


def test_loop_closure_mask_restricts_decisions_and_positives():
    T = 6
    labels = np.array([0, 1, 2, 0, 1, 5])
    mask = loop_closure_mask(T, exclude=2)
    gt = loop_closure_gt(labels, exclude=2)
    S = gt_from_labels(labels, labels).astype(float)  # diagonal would be perfect matches
    # only the revisits (0,3) and (1,4) remain; the diagonal is outside the mask
    assert gt.sum() == 2 and gt[0, 3] and gt[1, 4]
    P, R, T_ = pr_curve(S, gt, mask=mask)
    np.testing.assert_array_equal(T_, [np.inf, 1.0, 0.0])
    np.testing.assert_allclose(P[:2], [1, 1])
    assert recall_at_100p(S, gt, mask=mask) == 1.0
    # without the mask the trivial diagonal matches are false positives
    assert recall_at_100p(S, gt) == 0.0


def test_sparse_large_does_not_densify():
    # n_db * n_q = 1e10: any dense temporary would raise MemoryError
    n_db, n_q, K = 200_000, 50_000, 3
    rng = np.random.default_rng(1)
    q = np.repeat(np.arange(n_q), K)
    db = np.clip(q + rng.integers(-5, 6, size=q.size), 0, n_db - 1)
    vals = rng.random(q.size)
    S = sp.csr_matrix((vals, (db, q)), shape=(n_db, n_q))
    gt = gt_from_tolerance(n_db, n_q, 2, sparse=True)
    soft = gt_from_tolerance(n_db, n_q, 4, sparse=True)
    res = evaluate(S, gt, soft)
    assert 0 < res["recall_at_1"] <= res["recall_at_5"] < 1
    # at most K of the 5 true pairs per query are stored, the rest count as missed
    P, R, _ = pr_curve(S, gt, soft)
    assert R[-1] < 0.6 and 0 < res["auc_pr"] < 1
    # AP adds the final tied block of all unstored pairs: its precision is tiny
    ap_curve = float(np.sum(np.diff(R) * P[1:]))
    n_pairs = n_db * n_q - (soft.nnz - gt.nnz)
    assert res["ap"] == pytest.approx(ap_curve + (1 - R[-1]) * gt.nnz / n_pairs, rel=1e-12)


def test_sparse_duplicates_are_summed_and_input_untouched():
    S = sp.coo_matrix((np.array([0.2, 0.3, 0.4]), (np.array([0, 0, 1]), np.array([0, 0, 0]))),
                      shape=(2, 1))
    hard = np.array([[True], [False]])
    assert recall_at_k(S, hard, k=1) == 1.0  # 0.5 beats 0.4
    assert S.nnz == 3


# --------------------------------------------------------------------------- #
# errors
# --------------------------------------------------------------------------- #
def test_bad_input_raises():
    S = np.zeros((3, 2))
    gt = np.zeros((3, 2), dtype=bool)
    gt[0, 0] = True
    with pytest.raises(ValueError, match="gt_hard.*shape"):
        pr_curve(S, gt.T)
    with pytest.raises(ValueError, match="gt_hard.*bool"):
        pr_curve(S, gt.astype(int))
    with pytest.raises(ValueError, match="gt_hard.*bool"):
        recall_at_k(sp.csr_matrix(S), sp.csr_matrix(gt.astype(float)))
    with pytest.raises(ValueError, match="gt_soft.*bool"):
        auc_pr(S, gt, gt.astype(np.uint8))
    with pytest.raises(ValueError, match="mask.*shape"):
        evaluate(S, gt, mask=np.ones((2, 2), bool))
    with pytest.raises(ValueError, match="S contains NaN"):
        pr_curve(np.where(gt, np.nan, 0.0), gt)
    with pytest.raises(ValueError, match="S contains NaN"):
        pr_curve(sp.csr_matrix(np.where(gt, np.nan, 0.0)), gt)
    with pytest.raises(ValueError, match=r"S contains \+inf"):
        recall_at_100p(np.where(gt, np.inf, 0.0), gt)
    with pytest.raises(ValueError, match="S must be 2-D"):
        pr_curve(np.zeros(3), gt)
    with pytest.raises(ValueError, match="S must be real"):
        pr_curve(np.zeros((3, 2), dtype=complex), gt)
    with pytest.raises(ValueError, match="matching"):
        pr_curve(S, gt, matching="best")
    with pytest.raises(ValueError, match="k: must"):
        recall_at_k(S, gt, k=0)
    with pytest.raises(ValueError, match="k: must"):
        recall_at_k(S, gt, k=1.5)
    with pytest.raises(ValueError, match="recall"):
        auc_pr(S, np.zeros((3, 2), bool))
    with pytest.raises(ValueError, match="recall must be non-decreasing"):
        auc_from_pr([1, 1], [1, 0])


# --------------------------------------------------------------------------- #
# ground-truth builders
# --------------------------------------------------------------------------- #
@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 4), max_size=12), st.lists(st.integers(0, 4), max_size=12))
def test_gt_from_labels(db, q):
    gt = gt_from_labels(db, q)
    ref = np.array([[a == b for b in q] for a in db], dtype=bool).reshape(len(db), len(q))
    np.testing.assert_array_equal(gt, ref)
    assert gt.dtype == bool
    np.testing.assert_array_equal(gt_from_labels(db, q, sparse=True).toarray(), ref)


def test_gt_from_labels_strings_and_errors():
    gt = gt_from_labels(["a", "b"], ["b", "c", "a"])
    np.testing.assert_array_equal(gt, [[0, 0, 1], [1, 0, 0]])
    with pytest.raises(ValueError, match="q_labels.*1-D"):
        gt_from_labels([1, 2], [[1, 2]])
    with pytest.raises(ValueError, match="db_labels.*NaN"):
        gt_from_labels([1.0, np.nan], [1.0])


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 9), st.integers(0, 9), st.integers(0, 4))
def test_gt_from_tolerance(n_db, n_q, tol):
    ref = np.array([[abs(i - j) <= tol for j in range(n_q)] for i in range(n_db)],
                   dtype=bool).reshape(n_db, n_q)
    np.testing.assert_array_equal(gt_from_tolerance(n_db, n_q, tol), ref)
    np.testing.assert_array_equal(gt_from_tolerance(n_db, n_q, tol, sparse=True).toarray(), ref)


def test_gt_from_tolerance_errors():
    with pytest.raises(ValueError, match="tol"):
        gt_from_tolerance(3, 3, -1)
    with pytest.raises(ValueError, match="n_db"):
        gt_from_tolerance(2.5, 3, 1)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 30), st.integers(0, 30), st.floats(0, 0.5), st.integers(0, 2 ** 31))
def test_gt_from_positions(n_db, n_q, radius, seed):
    rng = np.random.default_rng(seed)
    db, q = rng.random((n_db, 2)), rng.random((n_q, 2))
    ref = np.array([[math.dist(a, b) <= radius for b in q] for a in db],
                   dtype=bool).reshape(n_db, n_q)
    np.testing.assert_array_equal(gt_from_positions(db, q, radius), ref)
    np.testing.assert_array_equal(gt_from_positions(db, q, radius, sparse=True).toarray(), ref)


def test_gt_from_positions_inclusive_and_errors():
    gt = gt_from_positions([[0, 0], [3, 4]], [[0, 0]], 5)
    np.testing.assert_array_equal(gt, [[True], [True]])
    with pytest.raises(ValueError, match="q_xy has 3"):
        gt_from_positions(np.zeros((2, 2)), np.zeros((2, 3)), 1)
    with pytest.raises(ValueError, match="radius"):
        gt_from_positions(np.zeros((2, 2)), np.zeros((2, 2)), -1)
    with pytest.raises(ValueError, match="db_xy.*NaN"):
        gt_from_positions([[np.nan, 0]], np.zeros((2, 2)), 1)
    with pytest.raises(ValueError, match="db_xy must be 2-D"):
        gt_from_positions(np.zeros(3), np.zeros((2, 2)), 1)


@pytest.mark.parametrize("exclude", [0, 1, 2, 5])
def test_loop_closure_mask_definition(exclude):
    T = 7
    m = loop_closure_mask(T, exclude)
    ref = [[i < j and j - i >= exclude for j in range(T)] for i in range(T)]
    np.testing.assert_array_equal(m, ref)
    np.testing.assert_array_equal(m, np.triu(np.ones((T, T), bool), k=max(exclude, 1)))


def test_loop_closure_gt_positions_and_sparse():
    xy = np.array([[0.0, 0], [10, 0], [0.5, 0], [10, 0.2], [0.1, 0]])
    gt = loop_closure_gt(xy, radius=1.0, exclude=2)
    ref = gt_from_positions(xy, xy, 1.0) & loop_closure_mask(5, 2)
    np.testing.assert_array_equal(gt, ref)
    np.testing.assert_array_equal(loop_closure_gt(xy, radius=1.0, exclude=2, sparse=True).toarray(), ref)
    assert gt[0, 2] and gt[1, 3] and gt[0, 4] and gt[2, 4] and not gt[3, 4]
    with pytest.raises(ValueError, match="labels_or_xy"):
        loop_closure_gt(xy)
    with pytest.raises(ValueError, match="exclude"):
        loop_closure_mask(5, -1)


def test_evaluate_returns_the_curve_it_used():
    rng = np.random.default_rng(5)
    S = rng.random((12, 9))
    gt = rng.random((12, 9)) < 0.2
    metrics, (p, r, t) = E.evaluate(S, gt, return_curve=True)
    p2, r2, t2 = E.pr_curve(S, gt)
    assert np.array_equal(p, p2) and np.array_equal(r, r2) and np.array_equal(t, t2)
    assert metrics == E.evaluate(S, gt)


# --------------------------------------------------------------------------- accepted_precision
def test_accepted_precision_counts_one_decision_per_query():
    gt = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0]], bool)  # query 3 has no true match
    soft = gt | np.array([[0, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 0]], bool)
    best = np.array([0, 2, 1, -1])
    accepted = np.array([True, True, True, True])
    # query 0 right, query 1 wrong, query 2 wrong (a soft pair without soft gt), query 3 has no best match
    m = E.accepted_precision(best, accepted, gt)
    assert m == {"n_accepted": 3, "precision_accepted": pytest.approx(1 / 3), "recall_accepted": 0.5,
                 "n_false": 2, "false_per_1000": 500.0}
    # with soft gt query 2's soft pair counts neither way (it is still accepted); sparse gt gives the same
    m = E.accepted_precision(best, accepted, sp.csr_matrix(gt), sp.csr_matrix(soft))
    assert m == {"n_accepted": 3, "precision_accepted": 0.5, "recall_accepted": 0.5, "n_false": 1,
                 "false_per_1000": 250.0}
    # nothing accepted: the precision of nothing is undefined, not 1.0
    assert E.accepted_precision(best, np.zeros(4, bool), gt) == {"n_accepted": 0, "precision_accepted": None,
                                                                 "recall_accepted": 0.0, "n_false": 0,
                                                                 "false_per_1000": 0.0}
    # no query with a true match (a drive without revisits): recall undefined, every accepted match false
    none = E.accepted_precision(best, accepted, np.zeros_like(gt))
    assert none["recall_accepted"] is None and none["n_false"] == 3 and none["false_per_1000"] == 750.0
    # a mask without query 1's true pair: its match no longer counts for the recall
    mask = np.ones_like(gt)
    mask[1, 1] = False
    for g in (gt, sp.csr_matrix(gt)):
        assert E.accepted_precision(best, accepted, g, mask=mask) == {
            "n_accepted": 3, "precision_accepted": pytest.approx(1 / 3), "recall_accepted": 1.0, "n_false": 2,
            "false_per_1000": 500.0}


# --------------------------------------------------------------------------- #
# average precision against scikit-learn
# --------------------------------------------------------------------------- #
def _sklearn_ap(S, hard, soft, mask):
    """scikit-learn's AP of the evaluated pairs; never-matched (-inf) pairs tie below every score."""
    from sklearn.metrics import average_precision_score  # slow import, only this reference needs it

    keep = np.ones(S.shape, bool) if mask is None else mask.copy()
    if soft is not None:
        keep &= ~(soft & ~hard)
    finite = S[np.isfinite(S)]
    bottom = (finite.min() if finite.size else 0.0) - 1.0
    scores = np.where(np.isfinite(S), S, bottom)[keep]
    labels = hard[keep]
    if not labels.any():
        return None
    return average_precision_score(labels, scores)


@SETTINGS
@given(problems())
def test_average_precision_equals_sklearn(problem):
    S, hard, soft, mask = problem
    ref = _sklearn_ap(S, hard, soft, mask)
    for args in _variants(S, hard, soft, mask):  # dense, and sparse S with -inf entries not stored
        if ref is None:
            with pytest.raises(ValueError, match="gt_hard"):
                average_precision(*args[:3], mask=args[3])
        else:
            assert average_precision(*args[:3], mask=args[3]) == pytest.approx(ref, abs=1e-9)


@SETTINGS
@given(st.integers(1, 40), st.integers(1, 30), st.integers(1, 5), st.integers(2, 6), st.booleans(),
       st.booleans(), st.integers(0, 2**32 - 1))
def test_average_precision_top_k_sparse_equals_sklearn(n_db, n_q, K, levels, with_soft, with_mask, seed):
    # Larger matrices than `problems`, quantised scores (ties), a real top-K retrieval stage.
    rng = np.random.default_rng(seed)
    S = rng.integers(0, levels, size=(n_db, n_q)).astype(float)
    hard = rng.random((n_db, n_q)) < 0.15
    soft = (hard | (rng.random((n_db, n_q)) < 0.1)) if with_soft else None
    mask = rng.random((n_db, n_q)) < 0.8 if with_mask else None
    K = min(K, n_db)
    S_topk, S_dense = _top_k(S, K)
    ref = _sklearn_ap(S_dense, hard, soft, mask)
    if ref is None:
        with pytest.raises(ValueError, match="gt_hard"):
            average_precision(S_topk, hard, soft, mask)
        return
    assert average_precision(S_topk, hard, soft, mask) == pytest.approx(ref, abs=1e-9)
    sparse_gt = [None if a is None else sp.csr_matrix(a) for a in (hard, soft, mask)]
    assert average_precision(S_topk, *sparse_gt) == pytest.approx(ref, abs=1e-9)
    assert evaluate(S_topk, hard, soft, mask)["ap"] == pytest.approx(ref, abs=1e-9)


def test_constant_matrix_scores_the_share_of_true_pairs():
    # the old curve started at an invented (recall 0, precision 1) and gave 0.50 here
    gt = gt_from_tolerance(111, 111, 0)
    share = gt.sum() / gt.size
    assert auc_pr(np.ones((111, 111)), gt) == pytest.approx(share, abs=1e-12)
    assert average_precision(np.ones((111, 111)), gt) == pytest.approx(share, abs=1e-12)
    P, R, _ = pr_curve(np.ones((111, 111)), gt)
    np.testing.assert_allclose(P, [share, share])
    np.testing.assert_allclose(R, [0, 1])
    # one tied block of pairs: a few true pairs above it cannot lend it their precision
    S = np.ones((111, 111))
    S[0, 0] = S[1, 1] = 2.0
    assert average_precision(S, gt) == pytest.approx(2 / 111 * 1 + 109 / 111 * 111 / (111 * 111))


def test_recall_at_100p_ends_before_a_tie_block_with_a_false_pair():
    S = np.array([[0.9, 0.5], [0.5, 0.9], [0.5, 0.1]])
    hard = np.array([[True, False], [False, True], [True, False]])
    # 0.9: two true pairs (recall 2/3); 0.5 admits the true (2, 0) only with the false (0, 1), (1, 0)
    assert recall_at_100p(S, hard) == pytest.approx(2 / 3)
    assert evaluate(S, hard)["recall_at_100p"] == pytest.approx(2 / 3)
    # the same tie block without false pairs does reach 100 % recall
    assert recall_at_100p(S, hard, gt_soft=hard | (S == 0.5)) == 1.0
    # and a tie at the very top with a false pair gives 0
    assert recall_at_100p(np.ones((2, 1)), np.array([[True], [False]])) == 0.0
