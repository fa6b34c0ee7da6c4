"""vpr.Localizer (online localisation) and the `vpr learn` / `vpr localize` commands."""
from __future__ import annotations

import json

import numpy as np
import pytest

import vpr
from vpr import evidence as ev
from vpr import simulate
from vpr.memory import MemoryFileError


@pytest.fixture(scope="module")
def traverses():
    db, q, dp, qp = simulate.aliased_traverses(300, 30, seed=5)
    return db, q, dp, qp


def test_localizer_equals_batch_forward_and_restarts(traverses, tmp_path):
    db, q, dp, qp = traverses
    names = [f"db{i:04d}.png" for i in range(db.shape[0])]
    loc = vpr.Localizer.from_database(db, names, z_min=3.0)
    n_conn = loc.memory.n_connections
    batch = ev.sparse_evidence(loc.memory, q, loc.db_codes, direction="forward", top_k=50)
    answers = []
    for j in range(q.shape[0]):
        if j == 100:  # the robot stops, and a new process continues from the file
            loc.save(tmp_path / "loc.npz")
            loc = vpr.Localizer.load(tmp_path / "loc.npz")
            assert loc.frames == 100
        r = loc.update(q[j])
        assert r.best_db == batch.best_db[j] and abs(r.score - batch.score[j]) <= 1e-6
        assert r.db_name == names[r.best_db]
        assert r.accepted == (r.score >= 3.0)
        answers.append(r)
    assert loc.memory.n_connections == n_conn  # queries do not change the memory
    best = np.array([a.best_db for a in answers])
    assert np.mean(np.abs(dp[best] - qp) <= 1) >= 0.85
    acc = np.array([a.accepted for a in answers])
    assert acc.sum() > 0.5 * acc.size and np.mean(np.abs(dp[best[acc]] - qp[acc]) <= 1) >= 0.95
    # same memory, same query, same answers after reset
    loc.reset()
    again = [loc.update(q[j]).best_db for j in range(q.shape[0])]
    assert np.array_equal(again, best)


def test_localizer_file_keeps_conf_meta_and_arrays(traverses, tmp_path):
    db, q, _, _ = traverses
    loc = vpr.Localizer.from_database(db[:50], [str(i) for i in range(50)], decay=0.8, stay=None, top_k=5,
                                      seed=3)
    loc.meta = {"encoder": "pixel", "encoder_conf": {"k": 200}}
    loc.arrays = {"mean": np.arange(4, dtype=np.float32)}
    loc.update(q[0])
    p = loc.save(tmp_path / "m.npz")
    back = vpr.Localizer.load(p)
    assert back.conf == loc.conf and back.conf["stay"] is None and back.conf["top_k"] == 5
    assert back.meta == loc.meta and np.array_equal(back.arrays["mean"], loc.arrays["mean"])
    assert back.names == loc.names and (back.db_codes != loc.db_codes).nnz == 0
    a, b = loc.update(q[1]), back.update(q[1])
    assert (a.best_db, a.score) == (b.best_db, b.score) and len(b.db_idx) <= 5
    assert not list(tmp_path.glob(".*"))  # atomic: no temporary file left


def test_localizer_bad_input(traverses, tmp_path):
    db, q, _, _ = traverses
    with pytest.raises(ValueError, match="names"):
        vpr.Localizer.from_database(db[:10], ["a"])
    with pytest.raises(ValueError, match="unknown Localizer option"):
        vpr.Localizer.from_database(db[:10], list("abcdefghij"), zmin=3)
    loc = vpr.Localizer.from_database(db[:10], list("abcdefghij"))
    with pytest.raises(ValueError, match="shape"):
        loc.update(np.zeros(10, bool))
    (tmp_path / "x.npz").write_bytes(b"not a zip")
    with pytest.raises(MemoryFileError, match="not a readable localizer"):
        vpr.Localizer.load(tmp_path / "x.npz")
    with pytest.raises(MemoryFileError, match="no such"):
        vpr.Localizer.load(tmp_path / "missing.npz")
    np.savez(tmp_path / "y.npz", header=np.array(json.dumps({"format": "other"})))
    with pytest.raises(MemoryFileError, match="not a localizer file"):
        vpr.Localizer.load(tmp_path / "y.npz")
