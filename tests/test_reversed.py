"""A query that runs the map backwards: read from the evidence of the map's transitions reversed, said, and not
accepted (``vpr.shosm.reversed_frames``, ``Direction``, ``direction="reversed"``)."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest
import scipy.sparse as sp

import vpr
from vpr import methods, sdr
from vpr.shosm import Direction, SequenceMemory, memory_params, query_evidence, reversed_frames
from vpr.types import EncodedTraverse


def test_reversed_frames_compares_trailing_means():
    f = np.array([3.0, 3.0, 1.0, 1.0, 1.0, -np.inf])
    r = np.array([1.0, 2.0, 4.0, 4.0, 4.0, 4.0])
    assert reversed_frames(f, r, window=2).tolist() == [False, False, True, True, True, True]
    assert reversed_frames(f, r, window=5).tolist() == [False, False, False, True, True, True]
    # a whole traverse at once: its first frames as the first window read
    assert reversed_frames(f, r, window=5, causal=False).tolist() == [True] * 6
    assert reversed_frames(f[:3], r[:3], window=5, causal=False).tolist() == [False] * 3
    # a frame that did not move is not read: it takes the reading of the frame before (none yet: False)
    moved = np.array([False, True, True, False, True, True])
    assert reversed_frames(f, r, window=2, moved=moved).tolist() == [False, False, True, True, True, True]
    r2 = np.array([5.0, 2.0, 0.0, 9.0, 0.0, 0.0])
    assert reversed_frames(f, r2, window=1, moved=moved).tolist() == [False, False, False, False, False, False]
    d = Direction(window=1)
    assert [d.update(a, b, m) for a, b, m in zip(f, r2, moved, strict=True)] == [False] * 6  # frame 3 not read
    assert reversed_frames(f, r2, window=1).tolist() == [True, False, False, True, False, False]
    d = Direction(window=2)
    assert [d.update(a, b) for a, b in zip(f, r, strict=True)] == reversed_frames(f, r, window=2).tolist()
    with pytest.raises(ValueError, match="one value per frame"):
        reversed_frames(f, r[:3])


def _world(seed=7, n=150):
    """A map whose consecutive frames share half their bits (a camera moving on) and a noisy query of its route."""
    rows = [sdr.random_sdrs(1, 2048, 40, seed=seed)]
    for i in range(1, n):
        rows.append(sdr.add_noise(rows[-1], 0.5, seed=seed + 100 + i))
    db = sp.vstack(rows).tocsr()
    return db, sdr.add_noise(db, 0.4, seed=seed + 1)


def test_the_reversed_evidence_follows_a_query_that_runs_the_map_backwards():
    db, q = _world()
    mem = SequenceMemory(**memory_params())
    codes = mem.run(db)
    mem.reset()
    back = q[::-1]
    truth = np.arange(db.shape[0])[::-1]
    for top_k in (None, 20):
        rev = query_evidence(mem, back, codes, direction="reversed", top_k=top_k)
        fwd = query_evidence(mem, back, codes, direction="forward", top_k=top_k)
        assert np.mean(rev.best[10:] == truth[10:]) > 0.95
        assert np.mean(rev.z[10:] > fwd.z[10:]) > 0.95  # it is the stronger evidence all along
        # and the other way round for the query in the map's direction
        ahead = query_evidence(mem, q, codes, direction="reversed", top_k=top_k)
        assert np.mean(ahead.z[10:] < query_evidence(mem, q, codes, direction="forward", top_k=top_k).z[10:]) > 0.95


def _encoded(x):
    return EncodedTraverse(names=[f"{i:04d}" for i in range(x.shape[0])], sdr=x)


def test_match_accepts_nothing_of_a_reversed_query_and_counts_its_frames():
    db, q = _world()
    m = methods.get("rshosm-seq")
    ahead = m.match(_encoded(db), _encoded(q))
    assert ahead.reversed <= 5 and ahead.accepted.sum() > 130
    back = m.match(_encoded(db), _encoded(q[::-1]))
    assert back.reversed > 140 and not back.accepted.any()
    # the rule is what refuses them: the path score alone accepts some
    assert m.decisions(back.similarity, back.best, back.score).accepted.any()


def test_localizer_refuses_a_reversed_query_and_a_restart_keeps_the_reading(tmp_path):
    db, q = _world()
    names = [str(i) for i in range(db.shape[0])]
    for query, reversed_ in ((q[::-1], True), (q, False)):
        loc, whole = vpr.Localizer.from_database(db, names), vpr.Localizer.from_database(db, names)
        out = []
        for j in range(query.shape[0]):
            if j == 60:
                vpr.Map("rshosm-seq", loc, {"name": "pixel", "conf": {}}).save(tmp_path / "m.npz")
                loc = methods.load_map(tmp_path / "m.npz").localizer
            a, b = loc.update(query[j]), whole.update(query[j])
            assert (a.best, a.accepted, a.reversed) == (b.best, b.accepted, b.reversed)
            out.append(a)
        back = np.array([d.reversed for d in out])
        acc = np.array([d.accepted for d in out])
        if reversed_:  # (one frame has no direction)
            assert back[10:].all() and not acc[1:].any()
        else:
            assert back.sum() <= 5 and acc.sum() > 120


def _reversed_folder(src, dst):
    """A folder of ``src``'s images whose sorted names run them last to first."""
    dst.mkdir()
    files = sorted(src.iterdir())
    for i, f in enumerate(files[::-1]):
        os.symlink(f, dst / f"{i:05d}{f.suffix}")
    return dst


@pytest.mark.slow
def test_compare_and_localize_say_a_reversed_query(scene_on_disk, tmp_path, capsys):
    from pipelines.cli import main

    s = scene_on_disk("two_seasons", (48, 36), 60)
    db = s[s["names"][0]]
    q = _reversed_folder(db, tmp_path / "rev")  # the map's own drive, last frame first: evidence enough to say so
    with pytest.warns(UserWarning, match="the query runs the map backwards"):
        assert main(["compare", str(db), str(q), "--methods", "rshosm-seq", "--out", str(tmp_path / "c"),
                     "--no-progress"]) == 0
    m = json.loads((tmp_path / "c" / "metrics.json").read_text())["methods"]["rshosm-seq"]
    assert m["reversed_frames"] > 0
    assert main(["learn", str(db), "--out", str(tmp_path / "m.npz"), "--no-progress"]) == 0
    assert main(["localize", str(tmp_path / "m.npz"), str(q), "--out", str(tmp_path / "l"), "--no-progress"]) == 0
    err = capsys.readouterr().err
    m = json.loads((tmp_path / "l" / "metrics.json").read_text())["methods"]["rshosm-seq"]
    assert m["reversed_frames"] > 0 and "the query runs the map backwards" in err


def test_a_few_frames_read_backwards_do_not_say_the_query_runs_backwards():
    """Said of most of a query, never of a few frames of a forward one on which little is accepted."""
    from vpr.groundtruth import runs_backwards

    assert not runs_backwards(1, 0, 18)        # one weak frame early in a forward run
    assert not runs_backwards(10, 0, 300)      # a forward run that accepts nothing
    assert not runs_backwards(190, 200, 400)   # more of it is accepted along the map
    assert runs_backwards(341, 0, 358) and runs_backwards(11, 0, 20)


@pytest.mark.slow
def test_a_smooth_forward_descriptor_stream_is_not_said_backwards(tmp_path, capsys):
    """Descriptors whose neighbours are near alike (a random walk): a few frames may read backwards, the query is
    not said to run backwards."""
    from pipelines.cli import main

    rng = np.random.default_rng(1)
    walk = np.cumsum(rng.normal(size=(300, 128)), axis=0).astype(np.float32)
    np.save(tmp_path / "db.npy", walk)
    np.save(tmp_path / "q.npy", walk + 0.2 * rng.normal(size=walk.shape).astype(np.float32))
    argv = ["localize", str(tmp_path / "db.npy"), str(tmp_path / "q.npy"), "--tolerance", "1", "--out",
            str(tmp_path / "l"), "--no-progress"]
    assert main(argv) == 0
    assert "runs the map backwards" not in capsys.readouterr().err
