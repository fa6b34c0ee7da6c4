"""Tests for vpr.verify: ORB features, matching, pycolmap two-view RANSAC, re-ranking."""
import cv2
import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from vpr.evaluate import average_precision
from vpr.verify import (
    MODELS,
    Keypoints,
    Verifier,
    extract_features,
    match_features,
    own_distances,
    rerank,
    top_candidates,
    two_view_inliers,
)

W, H = 320, 240
# mild perspective + rotation/shear, like a second visit from a slightly different pose
HOMOGRAPHY = np.array([[0.95, 0.08, 12.0], [-0.06, 1.0, 8.0], [1e-4, 5e-5, 1.0]])


def scene(seed, w=W, h=H):
    """Deterministic textured image: random filled rectangles and discs plus noise."""
    rng = np.random.default_rng(seed)
    img = np.full((h, w), 128, np.uint8)
    for _ in range(60):
        c = int(rng.integers(0, 256))
        x0, y0 = int(rng.integers(0, w)), int(rng.integers(0, h))
        if rng.random() < 0.5:
            x1, y1 = x0 + int(rng.integers(5, 40)), y0 + int(rng.integers(5, 40))
            cv2.rectangle(img, (x0, y0), (x1, y1), c, -1)
        else:
            cv2.circle(img, (x0, y0), int(rng.integers(3, 20)), c, -1)
    return np.clip(img + rng.normal(0, 6, img.shape), 0, 255).astype(np.uint8)


def warp(img, Hm=HOMOGRAPHY):
    return cv2.warpPerspective(img, Hm, (img.shape[1], img.shape[0]), borderMode=cv2.BORDER_REFLECT)


def thumb(img):
    return cv2.resize(img, (64, 32), interpolation=cv2.INTER_AREA)


def hamming(d1, d2):
    return np.unpackbits(np.bitwise_xor(d1[:, None, :], d2[None, :, :]), axis=2).sum(axis=2)


@pytest.fixture(scope="module")
def imgs():
    a = scene(1)
    return {"a": a, "a_warp": warp(a), "b": scene(2), "c": scene(3), "d": scene(4), "e": scene(5)}


@pytest.fixture(scope="module")
def feats(imgs):
    return {k: extract_features(v) for k, v in imgs.items()}


# --------------------------------------------------------------------------- #
# extract_features
# --------------------------------------------------------------------------- #
def test_features_layout_and_grey_bgr_agree(imgs, feats):
    f = feats["a"]
    assert isinstance(f, Keypoints)
    assert 100 < len(f) <= 1000
    assert f.xy.dtype == np.float64 and f.xy.shape == (len(f), 2)
    assert f.descriptors.dtype == np.uint8 and f.descriptors.shape == (len(f), 32)
    np.testing.assert_array_equal(f.scale, [1.0, 1.0])
    assert f.size == (H, W)
    assert (f.xy >= 0).all() and (f.xy[:, 0] < W).all() and (f.xy[:, 1] < H).all()
    fb = extract_features(cv2.cvtColor(imgs["a"], cv2.COLOR_GRAY2BGR))
    np.testing.assert_array_equal(fb.xy, f.xy)
    np.testing.assert_array_equal(fb.descriptors, f.descriptors)
    assert len(extract_features(imgs["a"], n_features=50)) <= 50


def test_tiny_image_is_upscaled_and_keypoints_mapped_back(imgs):
    tiny = thumb(imgs["a"])
    f = extract_features(tiny)
    assert len(f) > 20
    np.testing.assert_allclose(f.scale, [7.5, 7.5])
    assert f.size == (32, 64)  # the original's, not the detection frame's
    assert (f.xy > -0.5).all() and (f.xy[:, 0] < 63.5).all() and (f.xy[:, 1] < 31.5).all()
    # detecting on the same upscaled image directly must give the same keypoints
    big = cv2.resize(tiny, (480, 240), interpolation=cv2.INTER_LINEAR)
    fbig = extract_features(big)
    np.testing.assert_allclose(f.detection_xy(), fbig.xy, atol=1e-6)
    np.testing.assert_array_equal(f.descriptors, fbig.descriptors)


@pytest.mark.parametrize("img", [np.zeros((H, W), np.uint8), np.full((32, 64, 3), 200, np.uint8),
                                 np.zeros((1, 1), np.uint8)])
def test_blank_image_gives_no_features_and_no_inliers(img, feats):
    f = extract_features(img)
    assert len(f) == 0 and f.xy.shape == (0, 2) and f.descriptors.shape == (0, 32) and f.size == img.shape[:2]
    m = match_features(f, feats["a"])
    assert m.shape == (0, 2)
    assert match_features(feats["a"], f).shape == (0, 2)
    for model in MODELS:
        assert two_view_inliers(f, feats["a"], m, model) == 0


def test_extract_features_bad_input():
    with pytest.raises(ValueError, match="query image 3"):
        extract_features(np.zeros((0, 5), np.uint8), name="query image 3")
    with pytest.raises(ValueError, match="n_features"):
        extract_features(np.zeros((10, 10), np.uint8), n_features=0)


# --------------------------------------------------------------------------- #
# match_features
# --------------------------------------------------------------------------- #
def test_matches_pass_ratio_test_and_are_mutual(feats):
    f1, f2 = feats["a"], feats["a_warp"]
    m = match_features(f1, f2, ratio=0.8)
    assert m.dtype == np.intp and m.ndim == 2 and m.shape[1] == 2 and len(m) > 100
    d = hamming(f1.descriptors, f2.descriptors)
    srt = np.sort(d, axis=1)
    assert (d[m[:, 0], m[:, 1]] == srt[m[:, 0], 0]).all()
    assert (d[m[:, 0], m[:, 1]] < 0.8 * srt[m[:, 0], 1]).all()
    # mutual: each f2 keypoint is used once and is nearest to its partner
    assert len(np.unique(m[:, 1])) == len(m)
    assert (d[m[:, 0], m[:, 1]] == d[:, m[:, 1]].min(axis=0)).all()
    # a stricter ratio keeps a subset
    loose = {tuple(p) for p in match_features(f1, f2, ratio=0.9, mutual=False)}
    strict = {tuple(p) for p in match_features(f1, f2, ratio=0.6, mutual=False)}
    assert strict < loose


def test_true_matches_follow_the_homography(feats):
    f1, f2 = feats["a"], feats["a_warp"]
    m = match_features(f1, f2)
    p = cv2.perspectiveTransform(f1.xy[m[:, 0]][None], HOMOGRAPHY)[0]
    err = np.linalg.norm(p - f2.xy[m[:, 1]], axis=1)
    assert np.mean(err < 3.0) > 0.8


def test_own_distances_are_each_keypoints_nearest_other_descriptor(feats):
    f = feats["a"]
    d = hamming(f.descriptors, f.descriptors).astype(float)
    np.fill_diagonal(d, np.inf)
    assert np.array_equal(own_distances(f), d.min(axis=1))
    one = Keypoints(f.xy[:1], f.descriptors[:1], f.scale)
    assert np.isinf(own_distances(one)).all() and own_distances(one).shape == (1,)
    # some keypoints only, in the order asked
    np.testing.assert_array_equal(own_distances(f, [5, 2, 2]), d.min(axis=1)[[5, 2, 2]])


def crossing(seed):
    """Scene ``seed`` with a crossing painted over its lower part: one stripe repeated across the frame."""
    img = scene(seed).copy()
    img[150:230] = 90
    for x in range(5, W - 20, 26):
        cv2.rectangle(img, (x, 160), (x + 13, 220), 235, -1)
    return img


@pytest.mark.parametrize("seeds", [(1, 2), (3, 4), (5, 6)])
def test_distinct_matches_do_not_verify_a_pattern_repeated_within_the_image(seeds):
    # two places with the same crossing: its stripes verify them, unless a match must be distinct in its own image
    a, b = (extract_features(crossing(s)) for s in seeds)
    every = two_view_inliers(a, b, match_features(a, b))
    distinct = two_view_inliers(a, b, match_features(a, b, distinct=True))
    assert every >= 20 and distinct <= every // 2


def test_distinct_matches_keep_a_scene_without_repeats(feats):
    f1, f2 = feats["a"], feats["a_warp"]
    own = (own_distances(f1), own_distances(f2))
    kept, m = match_features(f1, f2, distinct=True), match_features(f1, f2)
    assert len(kept) >= 0.6 * len(m)
    assert two_view_inliers(f1, f2, kept) >= 0.6 * two_view_inliers(f1, f2, m)
    # exactly the matches below the ratio times both keypoints' own distances
    d = hamming(f1.descriptors, f2.descriptors)[m[:, 0], m[:, 1]]
    assert np.array_equal(kept, m[(d < 0.8 * own[0][m[:, 0]]) & (d < 0.8 * own[1][m[:, 1]])])


def test_match_features_bad_args(feats):
    with pytest.raises(ValueError, match="ratio"):
        match_features(feats["a"], feats["b"], ratio=0)
    with pytest.raises(ValueError, match="f2"):
        match_features(feats["a"], np.zeros((3, 32), np.uint8))


# --------------------------------------------------------------------------- #
# two_view_inliers
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("model", ["fundamental", "homography"])
def test_true_pair_has_far_more_inliers_than_unrelated(feats, model):
    true = two_view_inliers(feats["a"], feats["a_warp"], match_features(feats["a"], feats["a_warp"]), model)
    unrelated = [two_view_inliers(feats["a"], feats[k], match_features(feats["a"], feats[k]), model)
                 for k in ("b", "c", "d")]
    assert true >= 150
    assert max(unrelated) < 15
    assert true > 10 * max(unrelated)


@pytest.mark.parametrize("model", ["fundamental", "homography"])
def test_thumbnails_are_verified(imgs, model):
    fa, fw, fb = (extract_features(thumb(imgs[k])) for k in ("a", "a_warp", "b"))
    true = two_view_inliers(fa, fw, match_features(fa, fw), model)
    unrelated = two_view_inliers(fa, fb, match_features(fa, fb), model)
    assert true >= 15 and unrelated < 8


def test_inliers_deterministic_and_bounded(feats):
    f1, f2 = feats["a"], feats["b"]  # outlier-dominated: RANSAC randomness matters most here
    m = match_features(f1, f2, ratio=0.95, mutual=False)
    assert len(m) >= 8
    runs = [two_view_inliers(f1, f2, m, "fundamental", seed=7) for _ in range(3)]
    assert runs[0] == runs[1] == runs[2]
    assert 8 <= runs[0] <= len(m)


def test_minimum_match_counts(feats):
    f1, f2 = feats["a"], feats["a_warp"]
    m = match_features(f1, f2)
    assert two_view_inliers(f1, f2, m[:7], "fundamental") == 0
    assert two_view_inliers(f1, f2, m[:3], "homography") == 0
    assert two_view_inliers(f1, f2, m[:8], "fundamental") == 8
    assert two_view_inliers(f1, f2, m[:4], "homography") == 4
    assert two_view_inliers(f1, f2, np.zeros((0, 2), int)) == 0


def test_two_view_inliers_bad_args(feats):
    f1, f2 = feats["a"], feats["a_warp"]
    m = match_features(f1, f2)
    with pytest.raises(ValueError, match="model"):
        two_view_inliers(f1, f2, m, model="affine")
    with pytest.raises(ValueError, match="max_error"):
        two_view_inliers(f1, f2, m, max_error=0)
    with pytest.raises(ValueError, match="matches"):
        two_view_inliers(f1, f2, m[:, :1])
    with pytest.raises(ValueError, match="matches"):
        two_view_inliers(f1, f2, m + len(f1))
    with pytest.raises(ValueError, match="matches"):
        two_view_inliers(f1, f2, m.astype(float))


# --------------------------------------------------------------------------- #
# candidate ranking
# --------------------------------------------------------------------------- #
def test_top_candidates_dense_ties_and_minus_inf():
    S = np.array([[0.5, -np.inf],
                  [0.9, -np.inf],
                  [0.5, 0.2],
                  [0.1, -np.inf]])
    c = top_candidates(S, 3)
    np.testing.assert_array_equal(c, [[1, 0, 2], [2, -1, -1]])
    np.testing.assert_array_equal(top_candidates(S, 10)[0], [1, 0, 2, 3] + [-1] * 6)


def test_top_candidates_sparse_only_stored_entries():
    S = sp.csc_matrix((np.array([0.3, 0.0, 0.7]), (np.array([4, 1, 2]), np.array([0, 0, 1]))), shape=(5, 3))
    np.testing.assert_array_equal(top_candidates(S, 3), [[4, 1, -1], [2, -1, -1], [-1, -1, -1]])


def test_top_candidates_matches_full_sort():
    rng = np.random.default_rng(0)
    S = rng.integers(0, 5, size=(40, 7)).astype(float)  # many ties
    c = top_candidates(S, 6)
    for j in range(S.shape[1]):
        ref = np.lexsort((np.arange(40), -S[:, j]))[:6]
        np.testing.assert_array_equal(c[j], ref)
    np.testing.assert_array_equal(top_candidates(sp.csr_matrix(S + 1), 6), c)


# --------------------------------------------------------------------------- #
# Verifier
# --------------------------------------------------------------------------- #
@pytest.fixture(scope="module")
def place(imgs):
    """Database [b, c, a, d]; queries [warped a, e]: query 0 truly matches db 2, query 1 nothing."""
    db = [imgs["b"], imgs["c"], imgs["a"], imgs["d"]]
    q = [imgs["a_warp"], imgs["e"]]
    # S ranks wrong candidates first for both queries
    S = np.array([[0.9, 0.9],
                  [0.8, 0.8],
                  [0.7, 0.1],
                  [0.1, 0.6]])
    return db, q, S


@pytest.mark.parametrize("model", ["fundamental", "homography"])
def test_reranking_moves_true_match_to_top(place, model):
    db, q, S = place
    res = Verifier(db, q, model=model, min_inliers=15).verify(S, 3, progress=False)
    np.testing.assert_array_equal(res.candidates, [[0, 1, 2], [0, 1, 3]])
    assert res.inliers.shape == (2, 3) and res.inliers.dtype.kind == "i"
    assert res.inliers[0, 2] >= 150 and res.inliers[0, :2].max() < 15
    assert res.best_db[0] == 2
    np.testing.assert_array_equal(res.accepted, [True, False])
    assert res.score[0] == res.inliers[0, 2]
    # the verified similarity agrees with best_db
    V = res.similarity()
    assert V.shape == S.shape
    np.testing.assert_array_equal(np.asarray(V.argmax(axis=0)).ravel(), res.best_db)


def test_acceptance_gating(place):
    db, q, S = place
    strict = Verifier(db, q, min_inliers=10**6).verify(S, 3, progress=False)
    assert not strict.accepted.any()
    assert strict.best_db[0] == 2
    lenient = Verifier(db, q, min_inliers=0).verify(S, 3, progress=False)
    assert lenient.accepted.all()
    # with the true match outside the candidate list, query 0 is rejected
    short = Verifier(db, q).verify(S, 2, progress=False)
    np.testing.assert_array_equal(short.accepted, [False, False])


def test_ties_in_inliers_follow_S(imgs):
    a = imgs["a"]
    db = [a, a.copy(), imgs["b"]]
    S = np.array([[0.2], [0.5], [0.9]])
    res = Verifier(db, [warp(a)]).verify(S, 3, progress=False)
    np.testing.assert_array_equal(res.candidates, [[2, 1, 0]])
    assert res.inliers[0, 1] == res.inliers[0, 2] > 100
    assert res.best_db[0] == 1


def test_sparse_S_padding_and_blank_images(imgs):
    blank = np.zeros((H, W), np.uint8)
    db = [imgs["b"], blank, imgs["a"]]
    q = [imgs["a_warp"], blank, imgs["c"]]
    S = sp.csc_matrix((np.array([0.4, 0.9, 0.5]), (np.array([2, 1, 0]), np.array([0, 1, 1]))), shape=(3, 3))
    res = Verifier(db, q).verify(S, 2, progress=False)
    np.testing.assert_array_equal(res.candidates, [[2, -1], [1, 0], [-1, -1]])
    assert res.inliers[0, 0] > 100 and res.inliers[0, 1] == -1
    np.testing.assert_array_equal(res.inliers[1], [0, 0])
    np.testing.assert_array_equal(res.best_db, [2, 1, -1])
    np.testing.assert_array_equal(res.accepted, [True, False, False])
    assert res.score[2] == -np.inf
    assert res.similarity().nnz == 3


def test_features_cached_once_per_image(imgs):
    db_imgs = [imgs["a"], imgs["b"], imgs["c"]]
    q_imgs = [imgs["a_warp"], imgs["d"]]
    calls = {"db": [], "q": []}

    def db(i):
        calls["db"].append(i)
        return db_imgs[i]

    def q(j):
        calls["q"].append(j)
        return q_imgs[j]

    S = np.ones((3, 2))
    v = Verifier(db, q)
    first = v.verify(S, 3, progress=False)
    second = v.verify(S, 2, progress=False)
    assert sorted(calls["db"]) == [0, 1, 2] and sorted(calls["q"]) == [0, 1]
    np.testing.assert_array_equal(second.inliers, first.inliers[:, :2])
    calls = {"db": [], "q": []}
    Verifier(db, q, cache=False).verify(S, 3, progress=False)
    assert len(calls["db"]) == 6
    # at most 2 images a side: the third database image pushes out the least recently used
    calls = {"db": [], "q": []}
    v = Verifier(db, q, max_cached=2)
    v.pair_inliers(0, 0), v.pair_inliers(1, 0), v.pair_inliers(0, 1), v.pair_inliers(2, 1)
    assert calls["db"] == [0, 1, 2] and calls["q"] == [0, 1]
    v.pair_inliers(0, 0)  # 0 was used after 1: kept
    v.pair_inliers(1, 1)  # 1 was dropped for 2
    assert calls["db"] == [0, 1, 2, 1]


def test_verifier_bad_args(place):
    db, q, S = place
    v = Verifier(db, q)
    with pytest.raises(ValueError, match="n_candidates"):
        v.verify(S, 0)
    with pytest.raises(ValueError, match="db_images"):
        v.verify(S[:3], 2)
    with pytest.raises(ValueError, match="q_images"):
        v.verify(S[:, :1], 2)
    with pytest.raises(ValueError, match="NaN"):
        v.verify(np.full(S.shape, np.nan), 2)
    with pytest.raises(ValueError, match="2-D"):
        v.verify(S[:, 0], 2)
    with pytest.raises(ValueError, match="model"):
        Verifier(db, q, model="essential")
    with pytest.raises(ValueError, match="min_inliers"):
        Verifier(db, q, min_inliers=-1)
    with pytest.raises(ValueError, match=r"unknown verifier option\(s\) \['inliers'\]; valid: .*'min_inliers'"):
        Verifier(db, q, inliers=3)
    # command-line strings are read as the defaults' types
    v = Verifier(db, q, min_inliers="7", mutual="no", seed="none")
    assert (v.min_inliers, v.mutual, v.seed) == (7, False, None)
    with pytest.raises(ValueError, match="db_images"):
        Verifier(42, q)
    with pytest.raises(ValueError, match="query image 1"):
        Verifier(db, lambda j: None if j == 1 else q[0]).verify(S, 1, progress=False)


# --------------------------------------------------------------------------- #
# rerank: verification changes only the order within each query's candidates
# --------------------------------------------------------------------------- #
@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n_db=st.integers(1, 8), n_q=st.integers(1, 6), n=st.integers(1, 4),
       levels=st.integers(2, 6), sparse=st.booleans())
def test_rerank_permutes_only_the_candidates_values(seed, n_db, n_q, n, levels, sparse):
    rng = np.random.default_rng(seed)
    S = rng.integers(0, levels, (n_db, n_q)).astype(float)  # few levels: many ties
    if sparse:
        S[rng.random(S.shape) < 0.3] = 0
        S = sp.csc_matrix(S)  # zeros unstored: those pairs were never matched
    cand = top_candidates(S, n)
    inl = rng.integers(0, 4, cand.shape)
    R = rerank(S, cand, inl)
    assert sp.issparse(R) == sparse and R.shape == S.shape
    D, RD = (S.toarray(), R.toarray()) if sparse else (S, R)
    if sparse:
        np.testing.assert_array_equal(sp.csc_matrix(R).indices, S.indices)  # same stored pattern
    for j in range(n_q):
        c = cand[j][cand[j] >= 0]
        others = np.setdiff1d(np.arange(n_db), c)
        np.testing.assert_array_equal(RD[others, j], D[others, j])       # unverified pairs keep their score
        np.testing.assert_array_equal(np.sort(RD[c, j]), np.sort(D[c, j]))  # same values, re-ordered
        v, k = RD[c, j], inl[j][: len(c)]
        for a in range(len(c)):
            for b in range(len(c)):
                if k[a] > k[b]:
                    assert v[a] >= v[b]                                  # more inliers rank higher
                if k[a] == k[b] and a < b:
                    assert v[a] >= v[b]                                  # ties keep the S order


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), sparse=st.booleans())
def test_rerank_keeps_ap_when_inliers_agree_with_S(seed, sparse):
    rng = np.random.default_rng(seed)
    S = rng.random((12, 7))
    gt = rng.random(S.shape) < 0.2
    if sparse:
        S[rng.random(S.shape) < 0.4] = 0
        S = sp.csc_matrix(S)
    cand = top_candidates(S, 3)
    # inliers decreasing along each query's candidates (which are in S order): no change at all
    inl = np.where(cand >= 0, 100 - np.arange(3), -1)
    R = rerank(S, cand, inl)
    D = S.toarray() if sparse else S
    np.testing.assert_array_equal(R.toarray() if sparse else R, D)
    assert average_precision(R, gt) == average_precision(S, gt)


def test_rerank_moves_the_verified_true_match_up_and_ap_rises():
    # query 0's true match (db 2) is S's third candidate, query 1's (db 3) its first
    S = np.array([[0.9, 0.2], [0.8, 0.1], [0.7, 0.3], [0.1, 0.95], [0.05, 0.05]])
    gt = np.zeros(S.shape, bool)
    gt[2, 0] = gt[3, 1] = True
    cand = top_candidates(S, 3)
    R = rerank(S, cand, np.array([[2, 5, 90], [80, 3, 3]]))
    np.testing.assert_array_equal(R[:, 0], [0.7, 0.8, 0.9, 0.1, 0.05])  # by inliers 2 < 5 < 90
    np.testing.assert_array_equal(R[:, 1], S[:, 1])  # inliers agreed with S
    assert R[4, 0] == S[4, 0] and R[3, 0] == S[3, 0]
    assert average_precision(R, gt) > average_precision(S, gt)


def test_rerank_bad_args():
    S = np.array([[0.9, 0.2], [0.8, -np.inf]])
    cand = np.array([[0, 1], [0, -1]])
    with pytest.raises(ValueError, match="candidates must be an integer"):
        rerank(S, cand[:1], np.zeros((1, 2), int))
    with pytest.raises(ValueError, match="inliers must have the shape"):
        rerank(S, cand, np.zeros((2, 1), int))
    with pytest.raises(ValueError, match="beyond the 2 database rows"):
        rerank(S, np.array([[0, 2], [0, -1]]), np.zeros((2, 2), int))
    with pytest.raises(ValueError, match="repeated"):
        rerank(S, np.array([[0, 0], [0, -1]]), np.zeros((2, 2), int))
    with pytest.raises(ValueError, match="-inf"):
        rerank(S, np.array([[0, 1], [1, -1]]), np.zeros((2, 2), int))
    with pytest.raises(ValueError, match="stored entry"):
        rerank(sp.csc_matrix(np.array([[0.9, 0.0], [0.8, 0.5]])), np.array([[0, 1], [0, -1]]), np.zeros((2, 2), int))


def test_verify_result_reranked_agrees_with_best_db(place):
    db, q, S = place
    res = Verifier(db, q, min_inliers=15).verify(S, 3, progress=False)
    R = res.reranked(S)
    np.testing.assert_array_equal(R.argmax(axis=0), res.best_db)
    np.testing.assert_array_equal(np.sort(R, axis=0), np.sort(S, axis=0))
