"""The memory budget: where matrices stop being dense, set by the machine or by ``--memory-budget``."""
import json

import numpy as np
import pytest
import scipy.sparse as sp

from pipelines import outputs
from pipelines.args import parse_size
from pipelines.cli import main
from vpr import groundtruth, similarity
from vpr.shosm import loop_evidence
from vpr.similarity import DENSE_BYTES_PER_PAIR, dense_budget, dense_pairs, fits_dense


def test_sizes_read_as_a_user_writes_them():
    assert parse_size("4GB") == parse_size("4g") == parse_size("4 GiB") == parse_size("4") == 4 * 2**30
    assert parse_size("512MB") == 512 * 2**20 and parse_size("100B") == 100 and parse_size("1.5k") == 1536
    for bad in ("x", "0", "-1", "4 miles", ""):
        with pytest.raises(ValueError, match="--memory-budget: a size such as 4GB"):
            parse_size(bad)


def test_the_budget_sets_the_dense_switch_and_the_default_follows_the_machine(monkeypatch):
    with dense_budget(100 * DENSE_BYTES_PER_PAIR):
        assert dense_pairs() == 100 and fits_dense(10, 10) and not fits_dense(11, 10)
        assert similarity.budget_setting()["given"] is True
    monkeypatch.setattr(similarity, "physical_memory", lambda: 8 * 2**30)  # a laptop of 8 GiB: 1 GiB of matrices
    assert dense_pairs() == 2**30 // DENSE_BYTES_PER_PAIR and not similarity.budget_setting()["given"]
    monkeypatch.setattr(similarity, "physical_memory", lambda: 2**40)  # a server: never beyond the pair limit
    assert dense_pairs() == similarity.DENSE_PAIRS_LIMIT
    with pytest.raises(ValueError, match=r"above the memory budget: 100 pairs; --memory-budget"), \
            dense_budget(100 * DENSE_BYTES_PER_PAIR):
        similarity.check_dense("a method", 20, 20)


def test_a_loop_matrix_beyond_the_budget_is_top_k_with_the_same_decisions():
    rng = np.random.default_rng(0)
    places = [np.sort(rng.choice(512, 20, replace=False)) for _ in range(30)]
    rows = [places[i % 30] for i in range(60)]  # a lap, then the same lap again
    x = sp.csr_matrix((np.ones(1200, bool), np.concatenate(rows), np.arange(0, 1201, 20)), shape=(60, 512))
    dense = loop_evidence(x, exclude=5, n_inputs=512)
    with dense_budget(59 * 59 * DENSE_BYTES_PER_PAIR):
        small = loop_evidence(x, exclude=5, n_inputs=512)
    assert isinstance(dense.similarity, np.ndarray) and sp.issparse(small.similarity)
    np.testing.assert_array_equal(dense.decision.accepted, small.decision.accepted)
    np.testing.assert_array_equal(dense.best, small.best)


def test_a_large_dense_similarity_is_written_as_its_top_k(tmp_path, monkeypatch):
    S = np.arange(200 * 60, dtype=np.float32).reshape(200, 60)
    S[:, 0] = -np.inf  # a loop matrix's first frame has no earlier frame
    monkeypatch.setattr(outputs, "DENSE_FILE_BYTES", S.size * 4 - 1)
    assert outputs.write_similarity(tmp_path, S) == "similarity_topk.npz"
    T = sp.load_npz(tmp_path / "similarity_topk.npz").tocsc()
    assert T.shape == S.shape and np.diff(T.indptr).tolist() == [0] + [similarity.TOP_K] * 59
    np.testing.assert_array_equal(T[:, 1].toarray().ravel()[-50:], S[-50:, 1])
    monkeypatch.setattr(outputs, "DENSE_FILE_BYTES", S.size * 4)
    assert outputs.write_similarity(tmp_path, S) == "similarity.npy"


@pytest.mark.slow
def test_compare_keeps_to_the_budget_given_and_records_it(scene_on_disk, tmp_path, capsys):
    s = scene_on_disk("two_seasons", (64, 48), 40)
    db, q = s[s["names"][0]], s[s["names"][1]]
    argv = ["compare", db, q, "--out", tmp_path / "a", "--tolerance", 2, "--methods", "pairwise,seqslam",
            "--memory-budget", "1KB", "--no-progress"]
    assert main([str(a) for a in argv]) == 0, capsys.readouterr().err
    for m in ("pairwise", "seqslam"):
        assert (tmp_path / "a" / m / "similarity_topk.npz").is_file()
        assert not (tmp_path / "a" / m / "similarity.npy").exists()
    budget = json.loads((tmp_path / "a" / "metrics.json").read_text())["params"]["memory_budget"]
    assert budget["bytes"] == 1024 and budget["given"] and budget["dense_pairs"] == 1024 // DENSE_BYTES_PER_PAIR
    page = (tmp_path / "a" / "report.html").read_text()
    assert "memory_budget" in page and "(top-K, beyond the memory budget, 0.00 GiB" in page
    assert "pairwise, seqslam" in page and "the others dense" not in page
    # a size that is not one: one line, nothing written
    argv[4] = tmp_path / "b"
    argv[argv.index("1KB")] = "lots"
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--memory-budget: a size such as 4GB" in err and not (tmp_path / "b").exists()

def test_an_online_stream_refuses_a_memory_budget(tmp_path, capsys):
    # frames decided one by one keep no matrix to budget: the option is refused, not ignored
    assert main(["loops", "-", "--out", str(tmp_path / "o"), "--memory-budget", "1GB", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "--memory-budget" in err and err.count("\n") == 1 and not (tmp_path / "o").exists()


def test_the_loop_pairs_of_a_sparse_ground_truth_are_those_of_the_dense_one():
    rng = np.random.default_rng(1)
    G = rng.random((40, 40)) < 0.3
    for exclude, starts in ((0, None), (5, None), (3, [0, 15, 31])):
        dense = groundtruth.loop_pairs(G, exclude, starts)
        np.testing.assert_array_equal(dense, G & groundtruth.loop_closure_mask(40, exclude, starts))
        small = groundtruth.loop_pairs(sp.csr_matrix(G), exclude, starts)
        assert sp.issparse(small) and small.dtype == bool
        np.testing.assert_array_equal(small.toarray(), dense)


@pytest.mark.slow
def test_loops_with_positions_beyond_the_budget_score_as_the_dense_run(scene_on_disk, tmp_path, capsys):
    s = scene_on_disk("loop_revisits", (48, 36), 240)
    argv = ["loops", s["laps"], "--gt", s["gt"], "--radius", 6, "--preset", "fast", "--no-progress"]
    got = {}
    for out, extra in (("dense", []), ("topk", ["--memory-budget", "1KB"])):
        assert main([str(a) for a in [*argv, "--out", tmp_path / out, *extra]]) == 0, capsys.readouterr().err
        got[out] = json.loads((tmp_path / out / "metrics.json").read_text())["methods"]["rshosm-seq"]
    assert (tmp_path / "topk" / "rshosm-seq" / "similarity_topk.npz").is_file()
    assert got["topk"]["n_accepted"] > 0 and got["topk"]["frames_with_loop"] > 0
    for key in ("precision_accepted", "recall_accepted", "n_accepted", "n_false", "frames_with_loop"):
        assert got["topk"][key] == got["dense"][key], key  # the same decisions, scored on the same pairs
    assert got["topk"]["ap"] == pytest.approx(got["dense"]["ap"], abs=0.01)  # the top-K of each frame ranked
