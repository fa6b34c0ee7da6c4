"""vpr.Localizer (online localisation) and the `vpr learn` / `vpr localize` commands."""
from __future__ import annotations

import json

import numpy as np
import pytest

import vpr
from vpr import methods, simulate
from vpr import shosm as ev
from vpr.shosm import MemoryFileError


@pytest.fixture(scope="module")
def traverses():
    db, q, dp, qp = simulate.aliased_traverses(300, 30, seed=5)
    return db, q, dp, qp


def _map(loc) -> vpr.Map:
    return vpr.Map("rshosm-seq", loc, {"name": "pixel", "conf": {"k": 200}})


def test_localizer_equals_batch_forward_and_restarts(traverses, tmp_path):
    db, q, dp, qp = traverses
    names = [f"db{i:04d}.png" for i in range(db.shape[0])]
    loc = vpr.Localizer.from_database(db, names, drift=0.5, min_score=4.0, exact=False)
    whole = vpr.Localizer.from_database(db, names, drift=0.5, min_score=4.0, exact=False)
    n_conn = loc.memory.n_connections
    batch = ev.sparse_evidence(loc.memory, q, loc.db_codes, direction="forward", top_k=50)
    answers = []
    for j in range(q.shape[0]):
        if j == 100:  # the robot stops, and a new process continues from the file
            _map(loc).save(tmp_path / "loc.npz")
            loc = methods.load_map(tmp_path / "loc.npz").localizer
            assert loc.frames == 100
        r, w = loc.update(q[j]), whole.update(q[j])
        assert r.best == batch.best[j] and abs(r.column.best()[1] - batch.z[j]) <= 1e-6
        # (a frame of one appearance with the one before or after is a stand: no frame number singles it out; the
        # query's direction is read from its tenth frame on)
        assert r.accepted == (r.score >= 4.0 and not loc.standing[r.best] and not loc.last.unmoved and j >= 9 and
                              not r.reversed)
        assert (r.best, r.score, r.accepted) == (w.best, w.score, w.accepted)  # the restart changes nothing
        answers.append(r)
    assert loc.memory.n_connections == n_conn  # queries do not change the memory
    best = np.array([a.best for a in answers])
    assert np.mean(np.abs(dp[best] - qp) <= 1) >= 0.85
    acc = np.array([a.accepted for a in answers])
    # a world where every appearance recurs at ten places: only a path of answers stands out
    assert acc.sum() > 0.45 * acc.size and np.mean(np.abs(dp[best[acc]] - qp[acc]) <= 1) >= 0.95
    # same memory, same query, same answers after reset
    loc.reset()
    again = [loc.update(q[j]).best for j in range(q.shape[0])]
    assert np.array_equal(again, best)


def test_map_file_keeps_conf_encoder_statistics_and_positions(traverses, tmp_path):
    db, q, _, _ = traverses
    loc = vpr.Localizer.from_database(db[:50], [str(i) for i in range(50)], decay=0.8, stay=None, top_k=5,
                                      seed=3)
    m = vpr.Map("rshosm-seq", loc, {"name": "pixel", "conf": {"k": 200}}, [(np.arange(4.0), np.ones(4))],
                positions=np.arange(100.0).reshape(50, 2), origin=(48.1, 11.5), info={"db": "day"})
    m.query_state = {"q_n": np.array(3)}
    loc.update(q[0])
    p = m.save(tmp_path / "m.npz")
    back = methods.load_map(p)
    b = back.localizer
    assert b.conf == loc.conf and b.conf["stay"] is None and b.conf["top_k"] == 5
    assert back.encoder == m.encoder and np.array_equal(back.statistics[0][0], np.arange(4.0))
    assert np.array_equal(back.positions, m.positions) and back.origin == (48.1, 11.5) and back.info == m.info
    assert int(back.query_state["q_n"]) == 3
    assert back.method == "rshosm-seq" and b.names == loc.names and (b.db_codes != loc.db_codes).nnz == 0
    x, y = loc.update(q[1]), b.update(q[1])
    assert (x.best, x.score) == (y.best, y.score)
    assert not list(tmp_path.glob(".*"))  # atomic: no temporary file left


def test_localizer_bad_input(traverses, tmp_path):
    db, q, _, _ = traverses
    with pytest.raises(ValueError, match="names"):
        vpr.Localizer.from_database(db[:10], ["a"])
    with pytest.raises(ValueError, match="unknown rshosm-seq option"):
        vpr.Localizer.from_database(db[:10], list("abcdefghij"), zmin=3)
    loc = vpr.Localizer.from_database(db[:10], list("abcdefghij"))
    with pytest.raises(ValueError, match="shape"):
        loc.update(np.zeros(10, bool))
    (tmp_path / "x.npz").write_bytes(b"not a zip")
    with pytest.raises(MemoryFileError, match="not a readable map"):
        methods.load_map(tmp_path / "x.npz")
    with pytest.raises(MemoryFileError, match="no such"):
        methods.load_map(tmp_path / "missing.npz")
    np.savez(tmp_path / "y.npz", header=np.array(json.dumps({"format": "other"})))
    with pytest.raises(MemoryFileError, match="not a map file"):
        methods.load_map(tmp_path / "y.npz")


# ---------------------------------------------------------------- command line
@pytest.fixture(scope="module")
def scene(scene_on_disk):
    s = scene_on_disk("two_seasons", (48, 36), 40)
    return {name: s[name] for name in s["names"]}


def _cli(argv, capsys, stdin=None, monkeypatch=None):
    import io as _io

    from pipelines.cli import main

    if stdin is not None:
        monkeypatch.setattr("sys.stdin", _io.StringIO(stdin))
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.slow
def test_learn_and_localize_folder_stdin_and_restart(scene, tmp_path, capsys, monkeypatch):
    from pathlib import Path

    day, night = scene["summer_day"], scene["winter_night"]
    enc = ["--encoder-conf", "k=100", "--encoder-conf", "standardise=fit"]
    code, out, err = _cli(["learn", day, "--out", tmp_path / "map.npz", "--no-progress", *enc], capsys)
    assert code == 0, err
    code, out, err = _cli(["localize", tmp_path / "map.npz", day, "--out", tmp_path / "a", "--tolerance", 1], capsys)
    assert code == 0, err
    lines = [json.loads(s) for s in out.splitlines()]
    assert len(lines) == 40 and set(lines[0]) == {"query", "query_name", "best_db", "db_name", "score", "accepted",
                                                  "latency_ms"}
    # the database's own frames localise on themselves once the sequence is under way
    assert np.mean([abs(r["best_db"] - r["query"]) <= 1 for r in lines[5:]]) >= 0.9
    m = json.loads((tmp_path / "a" / "metrics.json").read_text())["methods"]["rshosm-seq"]
    assert m["frames"] == 40 and m["recall_at_1"] >= 0.8
    for k in ("with_encoding", "without_encoding"):
        assert m["latency_ms"][k]["median"] <= m["latency_ms"][k]["p95"] <= m["latency_ms"][k]["max"]
    assert (tmp_path / "a" / "rshosm-seq" / "matches.csv").read_text().count("\n") == 41
    # stdin: paths as they arrive, the same answers; a restart from --state-out continues identically
    paths = sorted(str(p) for p in Path(night).glob("*.png"))
    code, full, err = _cli(["localize", tmp_path / "map.npz", "-", "--out", tmp_path / "b", "--window", 5], capsys,
                           "\n".join(paths) + "\n", monkeypatch)
    assert code == 0, err
    full = [json.loads(s) for s in full.splitlines()]
    code, first, _ = _cli(["localize", tmp_path / "map.npz", "-", "--out", tmp_path / "c", "--window", 5, "--state-out",
                           tmp_path / "state.npz"], capsys, "\n".join(paths[:15]) + "\n", monkeypatch)
    code, rest, _ = _cli(["localize", tmp_path / "state.npz", "-", "--out", tmp_path / "d", "--window", 5], capsys,
                         "\n".join(paths[15:]) + "\n", monkeypatch)
    both = [json.loads(s) for s in (first + rest).splitlines()]
    key = lambda r: (r["best_db"], r["score"], r["accepted"])  # noqa: E731
    assert [key(r) for r in both] == [key(r) for r in full]
    code, folder, _ = _cli(["localize", tmp_path / "map.npz", night, "--out", tmp_path / "e", "--window", 5], capsys)
    assert [key(json.loads(s)) for s in folder.splitlines()] == [key(r) for r in full]


def test_localize_bad_input(scene, tmp_path, capsys):
    code, _, err = _cli(["localize", tmp_path / "nothing.npz", scene["summer_day"], "--out", tmp_path / "o"], capsys)
    assert code == 2 and "nothing.npz" in err
    np.savez(tmp_path / "mem.npz", header=np.array("{}"))
    code, _, err = _cli(["localize", tmp_path / "mem.npz", scene["summer_day"], "--out", tmp_path / "o"], capsys)
    assert code == 2 and "not a map file" in err
    code, _, err = _cli(["learn", scene["summer_day"], "--out", tmp_path / "m.npz", "--no-progress",
                         "--encoder-conf", "standardise=per_batch"], capsys)
    assert code == 2 and "per_batch" in err


def test_causal_standardisation_only_looks_back():
    import encoders
    from encoders.projection import CAUSAL_MIN, CAUSAL_WINDOW

    rng = np.random.default_rng(0)
    d = rng.normal(size=(CAUSAL_WINDOW + 60, 32)).astype(np.float32)
    d[80:] += 5.0  # the condition changes at frame 80
    enc = encoders.get("projection", descriptor="pixel", standardise="causal", k=10, n_bits=256)
    x = enc.projection.standardised(d)
    # a frame's value does not depend on later frames
    y = enc.projection.standardised(np.vstack([d[:120], rng.normal(size=(40, 32)).astype(np.float32)]))
    np.testing.assert_allclose(x[CAUSAL_MIN:120], y[CAUSAL_MIN:120], rtol=1e-5, atol=1e-5)
    t = CAUSAL_WINDOW + 30
    w = d[t - CAUSAL_WINDOW + 1:t + 1].astype(np.float64)
    np.testing.assert_allclose(x[t], (d[t] - w.mean(0)) / w.std(0), rtol=1e-4, atol=1e-4)
    assert enc.encode_descriptors(d).shape == (d.shape[0], 256)


@pytest.mark.slow
@pytest.mark.parametrize("lag", [0, 2])
def test_localize_stdin_answers_each_path_lag_frames_after_it_arrives(scene, tmp_path, lag):
    import subprocess
    import sys
    from pathlib import Path

    from pipelines.localize import learn

    learn(scene["summer_day"], tmp_path / "map.npz", encoder_conf={"k": 100, "standardise": "fit"}, progress=False)
    paths = sorted(Path(scene["winter_night"]).glob("*.png"))[:5]
    p = subprocess.Popen([sys.executable, "-m", "pipelines.cli", "localize", str(tmp_path / "map.npz"), "-",
                          "--out", str(tmp_path / "o"), "--method-conf", f"rshosm-seq.lag={lag}"],
                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         cwd=Path(__file__).resolve().parents[1])
    try:
        for i, path in enumerate(paths):
            p.stdin.write(f"{path}\n")
            p.stdin.flush()
            if i >= lag:  # blocks until frame i - lag is answered: stdin is still open
                line = json.loads(p.stdout.readline())
                assert line["query"] == i - lag and line["query_name"] == str(paths[i - lag])
        p.stdin.close()  # the end of the stream: the frames still waiting are answered
        rest = [json.loads(x) for x in p.stdout.read().splitlines()]
        assert [r["query"] for r in rest] == list(range(len(paths) - lag, len(paths)))
        assert p.wait(timeout=60) == 0, p.stderr.read()
    finally:
        p.kill()


@pytest.mark.slow
def test_a_corrupt_speed_follower_state_is_refused_naming_the_map(scene, tmp_path, capsys):
    code, _, err = _cli(["learn", scene["summer_day"], "--out", tmp_path / "map.npz", "--no-progress",
                         "--encoder-conf", "k=100"], capsys)
    assert code == 0, err
    the_map = methods.load_map(tmp_path / "map.npz")
    the_map.follow_state = ({"step": 2}, {})  # what a damaged --state-out file could hold
    the_map.save(tmp_path / "bad.npz")
    code, out, err = _cli(["localize", tmp_path / "bad.npz", scene["summer_day"], "--out", tmp_path / "o"], capsys)
    assert code == 2 and "bad.npz" in err and "speed follower" in err and len(err.strip().splitlines()) == 1
    assert out == "" and not (tmp_path / "o").exists()
    code, _, err = _cli(["localize", tmp_path / "bad.npz", scene["summer_day"], "--out", tmp_path / "o2",
                         "--query-speed", "as-is"], capsys)  # the localizer alone does not read it
    assert code == 0, err
