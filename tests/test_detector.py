"""vpr.LoopDetector: online loop closure equals the batch, resumes after a restart, encodes images itself."""
import numpy as np
import pytest
import scipy.sparse as sp

import encoders
from pipelines.stream import StreamEncoder
from vpr import sdr
from vpr.shosm import LoopDetector, MemoryFileError, loop_evidence


def _loop_stream(T=160, n_bits=1024, k=40, seed=0):
    """Frames 0..79 then a noisy revisit of 0..79: every revisit frame closes a loop."""
    places = sdr.random_sdrs(80, n_bits, k, seed=seed)
    noisy = sdr.add_noise(places, 0.2, seed=seed + 1)
    return sp.vstack([places, noisy]).tocsr()[:T]


def _answer(d):
    return d.frame, d.best, round(d.score, 4), d.accepted


def _loose():
    return {"min_score": 6.0, "drift": 0.5, "n_inputs": 1024}


def _decide(det, items, names=None, end=True):
    """Every decision ``det`` gives for ``items`` (and, with ``end``, at the stream's end), in the order given."""
    out = []
    for k, item in enumerate(items):
        d = det.update(item, name=None if names is None else names[k])
        out.extend(det.take_late())
        out.extend([] if d is None else [d])
    if end:
        det.flush()
        out.extend(det.take_late())
    return out


def test_detector_answers_equal_the_batch_loop_evidence():
    x = _loop_stream()
    conf = _loose()
    batch = loop_evidence(x, exclude=30, **conf)
    det = LoopDetector(exclude=30, **conf)
    out = _decide(det, [x[j] for j in range(x.shape[0])])
    assert [r.frame for r in out] == list(range(x.shape[0]))  # each frame once, in order
    d = batch.decision
    np.testing.assert_array_equal([r.best for r in out], d.best)
    np.testing.assert_array_equal([r.accepted for r in out], d.accepted)
    np.testing.assert_allclose([r.score for r in out], d.score)
    assert d.accepted[100:].mean() > 0.5  # the revisit is found, or the test would compare nothing
    assert det.names[out[120].best] == f"frame {out[120].best}"


def test_detector_resumes_after_save_and_load(tmp_path):
    x = _loop_stream()
    names = [f"f{j}.png" for j in range(x.shape[0])]
    ref = _decide(LoopDetector(exclude=30, **_loose()), list(x), names)
    first = LoopDetector(exclude=30, **_loose())
    before = _decide(first, list(x[:95]), names[:95], end=False)
    assert first.stream.waiting > 0 and len(before) < 95  # closures wait for the frames after them, in the state too
    first.meta["note"] = "robot A"
    first.save(tmp_path / "state.npz")
    again = LoopDetector.load(tmp_path / "state.npz")
    assert again.frames == 95 and again.meta == {"note": "robot A"}
    rest = _decide(again, list(x[95:]), names[95:])
    assert [_answer(r) for r in before + rest] == [_answer(r) for r in ref]
    assert again.names[rest[-1].best] == f"f{rest[-1].best}.png"


def test_detector_refuses_foreign_files_and_images_without_encoder(tmp_path):
    (tmp_path / "x.npz").write_bytes(b"nope")
    with pytest.raises(MemoryFileError, match="x.npz: not a readable loop detector file"):
        LoopDetector.load(tmp_path / "x.npz")
    det = LoopDetector()
    with pytest.raises(ValueError, match="got an image .* no encoder"):
        det.update(np.zeros((48, 64, 3), np.uint8))
    with pytest.raises(ValueError, match="unknown rshosm-seq option"):
        LoopDetector(z_min=3)


def test_detector_with_a_causal_encoder_equals_the_batch_encoding(rendered):
    scene = rendered("loop_revisits", size=(64, 48), n_frames=60)
    images = list(scene.traverses[0].images)
    conf = {"standardise": "causal", "n_bits": 1024, "k": 40}
    x = encoders.get("pixel", **conf).encode(images)
    batch = loop_evidence(x, exclude=12, n_inputs=1024)
    det = LoopDetector(StreamEncoder(encoders.get("pixel", **conf)), exclude=12, n_inputs=1024)
    out = _decide(det, images)
    np.testing.assert_array_equal([r.best for r in out], batch.decision.best)
    np.testing.assert_allclose([r.score for r in out], batch.decision.score)
    assert det.stream.frames == len(images)
    with pytest.raises(ValueError, match="must exceed the encoder's delay"):
        LoopDetector(StreamEncoder(encoders.get("pixel", **conf)), exclude=5)


def test_detector_resumes_a_causal_encoder_mid_warm_up(rendered, tmp_path):
    images = list(rendered("loop_revisits", size=(64, 48), n_frames=40).traverses[0].images)
    conf = {"standardise": "causal", "n_bits": 1024, "k": 40}
    whole = LoopDetector(StreamEncoder(encoders.get("pixel", **conf)), exclude=12, n_inputs=1024)
    ref = [_answer(d) for d in _decide(whole, images)]
    det = LoopDetector(StreamEncoder(encoders.get("pixel", **conf)), exclude=12, n_inputs=1024)
    before = _decide(det, images[:4], end=False)  # still waiting for the first CAUSAL_MIN frames
    det.save(tmp_path / "s.npz")
    det = LoopDetector.load(tmp_path / "s.npz", encoder=StreamEncoder(encoders.get("pixel", **conf)))
    assert [_answer(d) for d in before + _decide(det, images[4:])] == ref


# ---------------------------------------------------------------- vpr loops -
def _cli(argv, capsys, monkeypatch, stdin=""):
    import io as _io

    from pipelines.cli import main

    monkeypatch.setattr("sys.stdin", _io.StringIO(stdin))
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def laps(scene_on_disk):
    return scene_on_disk("loop_revisits", (48, 36), 240)


LOOSE = ["--preset", "fast", "--exclude", "12", "--method-conf", "rshosm-seq.min_score=10"]


@pytest.mark.slow  # the command line end to end
def test_vpr_loops_stdin_equals_the_batch_and_resumes(laps, tmp_path, capsys, monkeypatch):
    import csv
    import json

    paths = sorted(str(p) for p in laps["laps"].glob("*.png"))
    gt = ["--gt", laps["dir"] / "loop_pairs.csv"]
    # online, nothing is matched again at another speed: the batch as it comes (--query-speed as-is)
    code, _, err = _cli(["loops", laps["laps"], "--out", tmp_path / "a", "--no-progress", "--query-speed", "as-is",
                         *LOOSE, *gt], capsys, monkeypatch)
    assert code == 0, err
    with open(tmp_path / "a" / "rshosm-seq" / "matches.csv") as fh:
        batch = [(int(r["best_db"]), r["accepted"] == "1") for r in csv.DictReader(fh)]
    assert sum(a for _, a in batch) >= 50  # closures are found, so the comparison means something
    code, _, err = _cli(["loops", laps["laps"], "--out", tmp_path / "e", "--no-progress", *LOOSE, *gt], capsys,
                        monkeypatch)
    with open(tmp_path / "e" / "rshosm-seq" / "matches.csv") as fh:
        default = [(int(r["best_db"]), r["accepted"] == "1") for r in csv.DictReader(fh)]
    runs = (json.loads((tmp_path / "e" / "metrics.json").read_text())["methods"]["rshosm-seq"].get("sampling")
            or {}).get("runs", [])
    changed = [j for j, (x, y) in enumerate(zip(batch, default, strict=True)) if x != y]
    # by default only the closures its stretches matched again took differ, each onto a frame the as-is left open
    assert len(changed) == sum(r["closures"] for r in runs) and all(default[j][1] and not batch[j][1] for j in changed)
    code, out, err = _cli(["loops", "-", "--out", tmp_path / "b", *LOOSE, *gt], capsys, monkeypatch,
                          "\n".join(paths) + "\n")
    assert code == 0, err
    lines = [json.loads(s) for s in out.splitlines()]
    assert set(lines[0]) == {"query", "query_name", "best_db", "db_name", "score", "accepted", "latency_ms"}
    # a revisit read faster (the batch's stretch) is said online, where nothing is matched again
    assert runs and "revisit driven faster than the first pass" in err and "not matched again online" in err
    assert [(r["best_db"] if r["best_db"] is not None else -1, r["accepted"]) for r in lines] == batch
    m = json.loads((tmp_path / "b" / "metrics.json").read_text())["methods"]["rshosm-seq"]
    a = json.loads((tmp_path / "a" / "metrics.json").read_text())["methods"]["rshosm-seq"]
    for k in ("n_accepted", "precision_accepted", "recall_accepted", "frame_recall_at_100p", "recall_at_1"):
        assert m[k] == pytest.approx(a[k]), k
    assert "loop closures accepted" in err
    # stop after 100 frames, resume from the file: the same answers (closures waiting at the pause come after it)
    code, first, err = _cli(["loops", "-", "--out", tmp_path / "c", *LOOSE, "--state-out", tmp_path / "s.npz"],
                            capsys, monkeypatch, "\n".join(paths[:100]) + "\n")
    waited = json.loads((tmp_path / "c" / "metrics.json").read_text())["methods"]["rshosm-seq"].get("waiting", [])
    assert len(first.splitlines()) + len(waited) == 100 and (not waited or "wait in" in err)
    code, rest, err = _cli(["loops", "-", "--out", tmp_path / "d", "--resume", tmp_path / "s.npz"], capsys,
                           monkeypatch, "\n".join(paths[100:]) + "\n")
    assert code == 0, err
    both = [json.loads(s) for s in (first + rest).splitlines()]
    assert [{k: r[k] for k in r if k != "latency_ms"} for r in both] == \
        [{k: r[k] for k in r if k != "latency_ms"} for r in lines]


@pytest.mark.parametrize("extra, message", [
    (["--fps", "2"], "--fps apply to a folder or video"),
    (["--exclude", "3s"], "seconds need the frames' times, and image paths on stdin have none"),
    (["--preset", "paper"], "rshosm does not run online (one frame at a time as it comes); methods that do: "
                               "rshosm-seq"),
    (["--method-conf", "seqslam.ds=4"], "--method-conf for seqslam does not apply"),
    (["--exclude", "5"], "must exceed the encoder's delay"),
    (["--gt", "nope.csv"], "no such ground-truth file"),
])
def test_vpr_loops_stdin_refuses_before_reading(tmp_path, capsys, monkeypatch, extra, message):
    code, out, err = _cli(["loops", "-", "--out", tmp_path / "o", *extra], capsys, monkeypatch, "/no/such.png\n")
    assert code == 2 and message in err and out == ""
    assert not (tmp_path / "o").exists()


def test_state_flags_need_stdin(laps, tmp_path, capsys, monkeypatch):
    code, _, err = _cli(["loops", laps["laps"], "--out", tmp_path / "o", "--state-out", tmp_path / "s.npz"], capsys,
                        monkeypatch)
    assert code == 2 and "SEQ - (image paths on stdin)" in err
