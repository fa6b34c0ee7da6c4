"""One large match split in blocks of query frames: the blocks give the whole match's answers, in
this process, on a local cluster, through `vpr match --workers`, and when a worker dies mid-block."""
import json
import time

import numpy as np
import pytest
import scipy.sparse as sp

from vpr import methods, similarity, simulate
from vpr.types import EncodedTraverse

METHOD_CONF = {"seed": 0}


def _aliased(n, seed=0):
    db, q, _, _ = simulate.aliased_traverses(n, n // 10, seed=seed)
    return (EncodedTraverse(names=list(range(db.shape[0])), sdr=db),
            EncodedTraverse(names=list(range(q.shape[0])), sdr=q))


def _dense(S):
    return S.toarray() if sp.issparse(S) else np.asarray(S)


def _same_answers(whole, split):
    """The same best matches and decisions; similarity and scores equal up to the forgotten warm-up (float32)."""
    assert np.array_equal(whole.best, split.best)
    assert np.array_equal(whole.accepted, split.accepted)
    a, b = _dense(whole.similarity), _dense(split.similarity)
    assert a.shape == b.shape and sp.issparse(whole.similarity) == sp.issparse(split.similarity)
    assert np.allclose(a, b, atol=1e-4 * np.abs(a).max())
    fin = np.isfinite(whole.score)
    assert np.array_equal(fin, np.isfinite(split.score))
    assert np.allclose(whole.score[fin], split.score[fin], atol=1e-3 * np.abs(whole.score[fin]).max())


def _blocks(fitted, q, size):
    t = time.perf_counter()
    blocks = [fitted.match_block(q, a, min(a + size, len(q))) for a in range(0, len(q), size)]
    return fitted.combine(blocks, time.perf_counter() - t, q)


def test_blocks_with_their_margins_give_the_whole_match():
    db, q = _aliased(500)
    fitted = methods.get("rshosm-seq", **METHOD_CONF).fit(db)
    assert fitted.method.block_margin == 132  # decay 0.9: 0.9 ** 132 < 1e-6
    whole = fitted.match(q)
    assert whole.accepted.any() and not whole.accepted.all()  # the decision runs, and it refuses some
    _same_answers(whole, _blocks(fitted, q, 120))


def test_blocks_above_the_dense_limit_stay_top_k_like_the_whole(monkeypatch):
    from vpr.methods import rshosm_seq

    db, q = _aliased(400, seed=1)
    monkeypatch.setattr(rshosm_seq, "DENSE_EVIDENCE_PAIRS", 100)
    monkeypatch.setattr(similarity, "DENSE_PAIRS_LIMIT", 100)
    fitted = methods.get("rshosm-seq", **METHOD_CONF).fit(db)
    whole = fitted.match(q)
    assert sp.issparse(whole.similarity)
    # a block is small enough for a dense matrix: it takes the whole match's shape to choose top-K
    _same_answers(whole, _blocks(fitted, q, 90))


def test_a_shorter_memory_needs_a_shorter_margin_and_single_frame_methods_are_not_split():
    assert methods.get("rshosm-seq", decay=0.5).block_margin == 20
    db, q = _aliased(60)
    for name in ("pairwise", "rshosm"):
        fitted = methods.get(name).fit(db)
        assert fitted.method.block_margin is None
        with pytest.raises(ValueError, match="cannot match a query traverse in blocks"):
            fitted.match_block(q, 0, 10)


def test_block_size_keeps_the_warm_up_small():
    from pipelines.cluster import block_size

    assert block_size(50_000, 132, 2) == 12_500  # two blocks per worker
    assert block_size(2_000, 132, 8) == 8 * 132  # but at least eight margins
    assert block_size(10, 0, 1) == 8


@pytest.mark.slow
def test_local_cluster_split_equals_the_whole_match(tmp_path):
    from pipelines.cluster import dask_client, split_match

    db, q = _aliased(500, seed=2)
    fitted = methods.get("rshosm-seq", **METHOD_CONF).fit(db)
    whole = fitted.match(q)
    shipped = {}
    with dask_client(2, None, tmp_path / "scratch") as client:
        split = split_match(fitted, q, client, 2, shipped, block_frames=100)
        with pytest.raises(ValueError, match="block_frames"):
            split_match(fitted, q, client, 2, block_frames=0)
    _same_answers(whole, split)
    assert shipped["blocks"] == 5 and shipped["margin"] == 132
    # a task carries its block and margins, not the map
    assert 0 < shipped["task_bytes"] < shipped["map_bytes"]


@pytest.fixture(scope="module")
def split_scene(scene_on_disk):
    s = scene_on_disk("two_seasons", (48, 32), 30)
    return s[s["names"][0]], s[s["names"][1]], s["gt"]


def _answers(folder, name):
    import csv

    rows = list(csv.DictReader((folder / name / "matches.csv").open()))
    scores = [float(r["score"]) if r["score"] else np.nan for r in rows]
    return [(r["query"], r["best_db"], r["accepted"]) for r in rows], scores


@pytest.mark.slow
def test_vpr_compare_with_workers_splits_one_query_and_answers_like_the_serial_run(split_scene, tmp_path):
    from pipelines.cli import main

    db, q, gt = split_scene
    common = [str(db), str(q), "--gt", str(gt), "--radius", "3", "--gt-soft", "10", "--methods",
              "rshosm-seq,pairwise", "--no-progress", "--encoder-conf", "k=60"]
    assert main(["compare", *common, "--out", str(tmp_path / "serial")]) == 0
    assert main(["compare", *common, "--out", str(tmp_path / "split"), "--workers", "2"]) == 0
    m_serial = json.loads((tmp_path / "serial" / "metrics.json").read_text())
    m_split = json.loads((tmp_path / "split" / "metrics.json").read_text())
    for name in ("rshosm-seq", "pairwise"):
        a, b = _answers(tmp_path / "serial", name), _answers(tmp_path / "split", name)
        assert a[0] == b[0], name
        assert np.allclose(a[1], b[1], rtol=1e-4, atol=1e-4), name
        assert m_split["methods"][name]["ap"] == pytest.approx(m_serial["methods"][name]["ap"], abs=1e-6)
    # rshosm-seq went to the cluster, pairwise (a single-frame method) stayed in the client
    assert set(m_split["params"]["split"]) == {"rshosm-seq"}
    assert m_split["params"]["split"]["rshosm-seq"]["blocks"] == 1
    assert not list((tmp_path / "split").glob(".dask-scratch-*"))




@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::UserWarning")
def test_a_killed_worker_loses_its_block_to_the_other_and_the_answers_stay(tmp_path):
    from distributed import Client

    from pipelines.cluster import split_match
    from tests.dask_cluster import busy_cluster, kill_a_busy_worker, run_in_thread, slowed_task

    db, q = _aliased(400, seed=3)
    fitted = methods.get("rshosm-seq", **METHOD_CONF).fit(db)
    whole = fitted.match(q)
    slow = slowed_task("pipelines.cluster", "_block", 1.0)
    with busy_cluster(tmp_path, slow) as (address, workers, log, busy_dir):
        killed = kill_a_busy_worker(workers, busy_dir)

        def run():
            with Client(address, timeout="30s") as client:
                return split_match(fitted, q, client, 2, block_frames=100)

        split = run_in_thread(run, 240, log)
        assert killed, "no worker was killed while it held a block"
    _same_answers(whole, split)
