"""Tests for vpr.plots: files are written as valid PNGs, pooling is right, bad input raises."""
import sys

import matplotlib.image as mpimg
import numpy as np
import pytest
import scipy.sparse as sp

import vpr.plots
from vpr.evaluate import evaluate, pr_curve
from vpr.groundtruth import gt_from_tolerance
from vpr.plots import block_any, block_max, plot_bars, plot_pr, plot_similarity

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _assert_png(path):
    assert path.exists()
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100
    # a blank canvas would mean nothing was drawn
    assert img[..., :3].std() > 0.01
    # atomic write leaves no temporary files behind
    assert [p.name for p in path.parent.iterdir() if p.name.startswith(".")] == []


def _no_pyplot_figures():
    if "matplotlib.pyplot" in sys.modules:
        assert sys.modules["matplotlib.pyplot"].get_fignums() == []


@pytest.fixture
def example():
    rng = np.random.default_rng(0)
    n = 40
    gt = gt_from_tolerance(n, n, 1)
    S = rng.random((n, n)) + 2 * np.eye(n)
    return S, gt


def test_plot_pr_writes_png(tmp_path, example):
    S, gt = example
    curves = {"ours": pr_curve(S, gt), "noise": pr_curve(-S, gt)[:2]}
    out = plot_pr(curves, tmp_path / "sub" / "pr.png", title="PR")
    assert out == tmp_path / "sub" / "pr.png"
    _assert_png(out)
    _no_pyplot_figures()


def test_plot_pr_bad_input(tmp_path):
    p = tmp_path / "pr.png"
    with pytest.raises(ValueError, match="non-empty"):
        plot_pr({}, p)
    with pytest.raises(ValueError, match="'a'.*equal length"):
        plot_pr({"a": ([1, 0.5], [0, 0.5, 1])}, p)
    with pytest.raises(ValueError, match="'a'.*precision must lie"):
        plot_pr({"a": ([1, np.nan], [0, 1])}, p)
    with pytest.raises(ValueError, match="'b'.*recall must be non-decreasing"):
        plot_pr({"a": ([1, 1], [0, 1]), "b": ([1, 1], [1, 0])}, p)
    with pytest.raises(ValueError, match="'a'"):
        plot_pr({"a": [1, 0.5]}, p)
    assert not p.exists()


def test_plot_similarity_with_markers_and_gt(tmp_path, example):
    S, gt = example
    best = S.argmax(axis=0)
    best[3] = -1  # no match for this query
    accepted = S.max(axis=0) > 1.5
    out = plot_similarity(S, tmp_path / "S.png", best_db=best, accepted=accepted, gt_hard=gt,
                          title="S")
    _assert_png(out)
    _assert_png(plot_similarity(S, tmp_path / "S2.png", best_db=best))
    _no_pyplot_figures()


@pytest.mark.slow
def test_plot_similarity_large_and_sparse(tmp_path):
    rng = np.random.default_rng(1)
    n_db, n_q = 2500, 2100
    S = rng.random((n_db, n_q)).astype(np.float32)
    _assert_png(plot_similarity(S, tmp_path / "big.png", best_db=S.argmax(0),
                                gt_hard=gt_from_tolerance(n_db, n_q, 2), max_pixels=500))
    # sparse top-1 per query, far too large to densify
    n_db, n_q = 100_000, 80_000
    q = np.arange(n_q)
    Ssp = sp.csr_matrix((rng.random(n_q), (q, q)), shape=(n_db, n_q))
    gt = gt_from_tolerance(n_db, n_q, 1, sparse=True)
    _assert_png(plot_similarity(Ssp, tmp_path / "sparse.png", best_db=q, accepted=q % 2 == 0,
                                gt_hard=gt, max_pixels=300))


def test_block_pooling_matches_brute_force():
    rng = np.random.default_rng(2)
    S = rng.integers(-3, 4, size=(7, 11)).astype(float)
    S[S == -3] = -np.inf
    G = rng.random((7, 11)) < 0.2
    fr, fc = 3, 4
    pooled = block_max(S, fr, fc)
    pooled_sp = block_max(sp.csr_matrix(np.where(np.isinf(S), 0, S) + 0.0), fr, fc)
    anyg = block_any(G, fr, fc)
    assert pooled.shape == (3, 3) and anyg.shape == (3, 3)
    for a in range(3):
        for b in range(3):
            block = S[a * fr:(a + 1) * fr, b * fc:(b + 1) * fc]
            finite = block[np.isfinite(block)]
            if finite.size:
                assert pooled[a, b] == finite.max()
            else:
                assert np.isnan(pooled[a, b])
            assert anyg[a, b] == G[a * fr:(a + 1) * fr, b * fc:(b + 1) * fc].any()
    np.testing.assert_array_equal(block_any(sp.csr_matrix(G), fr, fc), anyg)
    # sparse: only stored entries count, unstored blocks are NaN
    stored = sp.csr_matrix(np.where(np.isinf(S), 0, S))
    for a in range(3):
        for b in range(3):
            block = stored[a * fr:(a + 1) * fr, b * fc:(b + 1) * fc]
            if block.nnz:
                assert pooled_sp[a, b] == block.data.max()
            else:
                assert np.isnan(pooled_sp[a, b])


def test_plot_similarity_bad_input(tmp_path, example):
    S, gt = example
    p = tmp_path / "S.png"
    with pytest.raises(ValueError, match="S contains NaN"):
        plot_similarity(np.where(gt, np.nan, S), p)
    with pytest.raises(ValueError, match="S must be 2-D"):
        plot_similarity(S[0], p)
    with pytest.raises(ValueError, match="at least one database entry"):
        plot_similarity(S[:0], p)
    with pytest.raises(ValueError, match=r"S contains \+inf"):
        plot_similarity(sp.csr_matrix(np.where(gt, np.inf, 0.0)), p)
    with pytest.raises(ValueError, match="gt_hard must be boolean"):
        plot_similarity(S, p, gt_hard=gt.astype(int))
    with pytest.raises(ValueError, match="gt_hard has shape"):
        plot_similarity(S, p, gt_hard=gt[:-1])
    with pytest.raises(ValueError, match="best_db must have shape"):
        plot_similarity(S, p, best_db=np.zeros(3, int))
    with pytest.raises(ValueError, match="best_db has indices"):
        plot_similarity(S, p, best_db=np.full(S.shape[1], S.shape[0]))
    with pytest.raises(ValueError, match="best_db must hold integers"):
        plot_similarity(S, p, best_db=np.zeros(S.shape[1]))
    with pytest.raises(ValueError, match="accepted requires best_db"):
        plot_similarity(S, p, accepted=np.ones(S.shape[1], bool))
    with pytest.raises(ValueError, match="accepted must be a bool"):
        plot_similarity(S, p, best_db=S.argmax(0), accepted=np.ones(S.shape[1]))
    with pytest.raises(ValueError, match="max_pixels"):
        plot_similarity(S, p, max_pixels=0)
    assert not p.exists()


def test_plot_bars(tmp_path):
    table = {"nordland": {"sift": 0.4, "cnn": 0.7}, "oxford": {"cnn": 0.5, "hog": 0.2}}
    _assert_png(plot_bars(table, tmp_path / "bars.png", ylabel="AUC", title="encoders"))
    p = tmp_path / "bad.png"
    with pytest.raises(ValueError, match="non-empty"):
        plot_bars({}, p, ylabel="x")
    with pytest.raises(ValueError, match=r"table\['a'\]\['m'\] must be a finite number"):
        plot_bars({"a": {"m": float("nan")}}, p, ylabel="x")
    with pytest.raises(ValueError, match=r"table\['a'\]\['m'\]"):
        plot_bars({"a": {"m": "high"}}, p, ylabel="x")
    with pytest.raises(ValueError, match="no values"):
        plot_bars({"a": {}}, p, ylabel="x")
    with pytest.raises(ValueError, match=r"table\['a'\] must be a dict"):
        plot_bars({"a": [1, 2]}, p, ylabel="x")
    assert not p.exists()
    _no_pyplot_figures()


def _capture(monkeypatch):
    """Replace the file writer by one that keeps the figure, so tests can read what was drawn."""
    figs = []

    def keep(fig, path, dpi=150, **kwargs):
        figs.append(fig)
        return path

    monkeypatch.setattr(vpr.plots, "save_figure", keep)
    return figs


def _markers(fig):
    """(x, y) of every scatter marker on the figure's first axes."""
    offsets = [c.get_offsets() for c in fig.axes[0].collections if len(c.get_offsets())]
    return {tuple(map(float, xy)) for o in offsets for xy in np.asarray(o)}


def test_plot_pr_legend_shows_average_precision(tmp_path, monkeypatch, example):
    S, gt = example
    figs = _capture(monkeypatch)
    metrics, curve = evaluate(S, gt, return_curve=True)
    plot_pr({"ours": curve, "other": pr_curve(-S, gt)}, tmp_path / "pr.png", ap={"ours": metrics["ap"]})
    labels = [t.get_text() for t in figs[0].axes[0].get_legend().get_texts()]
    P, R, _ = pr_curve(-S, gt)
    assert labels == [f"ours (AP = {metrics['ap']:.3f})", f"other (AP = {np.sum(np.diff(R) * P[1:]):.3f})"]
    with pytest.raises(ValueError, match=r"ap\['ours'\] must be a number in \[0, 1\]"):
        plot_pr({"ours": curve}, tmp_path / "pr.png", ap={"ours": 1.5})
    with pytest.raises(ValueError, match="ap has names without a curve"):
        plot_pr({"ours": curve}, tmp_path / "pr.png", ap={"theirs": 0.5})


@pytest.mark.parametrize("sparse", [False, True])
def test_plot_similarity_draws_no_marker_for_a_query_without_candidate(tmp_path, monkeypatch, sparse):
    S = np.array([[0.0, 0.2, 0.0, 0.0, 0.5],
                  [0.0, 0.9, 0.0, 0.0, 0.5],
                  [0.0, 0.1, 0.0, -np.inf, 0.5]])
    S[:, 3] = -np.inf  # query 3: never matched anywhere
    # q0: all zero (argmax says row 0); q1: real best row 1; q2: all zero; q4: all tied
    best = np.array([0, 1, 0, 0, 0])
    accepted = np.array([False, True, False, False, False])
    if sparse:
        r, c = np.nonzero(np.isfinite(S))
        S = sp.csr_matrix((S[r, c], (r, c)), shape=S.shape)  # explicit zeros stored, -inf not
    figs = _capture(monkeypatch)
    plot_similarity(S, tmp_path / "S.png", best_db=best, accepted=accepted)
    assert _markers(figs[0]) == {(1.0, 1.0)}
    plot_similarity(S, tmp_path / "S.png", best_db=best)
    assert _markers(figs[1]) == {(1.0, 1.0)}


def test_plot_similarity_sparse_marker_needs_a_stored_entry(tmp_path, monkeypatch):
    # top-1 sparse: the stored entry is the candidate, an unstored one never is
    S = sp.csr_matrix((np.array([0.0, 0.4]), (np.array([2, 0]), np.array([0, 1]))), shape=(3, 3))
    figs = _capture(monkeypatch)
    plot_similarity(S, tmp_path / "S.png", best_db=np.array([2, 1, 0]))
    assert _markers(figs[0]) == {(0.0, 2.0)}
    # a single database frame has nothing to tie with: its stored entry is the candidate
    plot_similarity(np.zeros((1, 2)), tmp_path / "S.png", best_db=np.array([0, -1]))
    assert _markers(figs[1]) == {(0.0, 0.0)}


def test_plot_similarity_bins_a_sparse_matrix_max_per_bin_with_thinned_markers(tmp_path, monkeypatch):
    # a small top-3 sparse matrix forced through the binning of a 50k x 50k one by max_pixels
    rng = np.random.default_rng(5)
    n_db, n_q, k, px = 60, 45, 3, 10
    rows = np.stack([rng.choice(n_db, k, replace=False) for _ in range(n_q)], axis=1)
    vals = rng.normal(size=(k, n_q))
    S = sp.csr_matrix((vals.ravel(), (rows.ravel(), np.tile(np.arange(n_q), k))), shape=(n_db, n_q))
    best = rows[vals.argmax(0), np.arange(n_q)]
    figs = _capture(monkeypatch)
    plot_similarity(S, tmp_path / "S.png", best_db=best, gt_hard=gt_from_tolerance(n_db, n_q, 1, sparse=True),
                    max_pixels=px)
    shown = np.ma.filled(figs[0].axes[0].images[0].get_array().astype(float), np.nan)
    fr, fc = -(-n_db // px), -(-n_q // px)
    assert shown.shape == (-(-n_db // fr), -(-n_q // fc)) and max(shown.shape) <= px
    dense = np.full((n_db, n_q), np.nan)
    dense[rows, np.arange(n_q)] = vals
    for a in range(shown.shape[0]):
        for b in range(shown.shape[1]):
            block = dense[a * fr:(a + 1) * fr, b * fc:(b + 1) * fc]
            expect = np.nanmax(block) if np.isfinite(block).any() else np.nan
            assert np.isnan(shown[a, b]) if np.isnan(expect) else shown[a, b] == pytest.approx(expect)
    # 45 markers exceed 2 * max_pixels: every second query's, each at its exact best match
    marks = _markers(figs[0])
    assert 0 < len(marks) <= 2 * px
    assert all(best[int(x)] == int(y) for x, y in marks)


@pytest.mark.parametrize("shape", [(20, 10), (30, 400)])
def test_plot_similarity_says_where_its_matrix_lies_in_the_picture(tmp_path, shape):
    import json

    from vpr.report import png_text

    S = np.zeros(shape)
    S[7, 3] = 1.0  # the one bright cell
    path = plot_similarity(S, tmp_path / "s.png", title="t")
    where = json.loads(png_text(path.read_bytes())["vpr-matrix"])
    assert where["shape"] == list(shape)
    x0, y0, x1, y1 = where["box"]
    img = mpimg.imread(path)[..., :3]
    h, w = img.shape[:2]

    def near(r, c):  # the pixels within 2 of where cell (r, c)'s centre should be (cells are drawn pixel-snapped)
        y, x = int((y0 + (r + 0.5) / shape[0] * (y1 - y0)) * h), int((x0 + (c + 0.5) / shape[1] * (x1 - x0)) * w)
        return img[y - 2:y + 3, x - 2:x + 3].reshape(-1, 3)

    yellow = (near(7, 3)[:, 0] > 0.8) & (near(7, 3)[:, 2] < 0.4)  # viridis' top
    assert yellow.any() and (near(9, 3)[:, 0] < 0.5).all()  # and dark purple two rows down
    assert img[int(y0 * h) - 3, w // 2].min() > 0.9 and img[int(y1 * h) + 3, w // 2].min() > 0.9  # white beyond
