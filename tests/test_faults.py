"""Faults and bad input through the ``vpr`` command line.

Refused runs write nothing, file-system errors end in one line naming the path,
interrupted runs leave only complete files and a rerun gives the uninterrupted
result, outputs are never read back as inputs, methods run into one folder keep
each other's results. Tiny renders (48x32, 30 frames) keep this file fast.
"""
import csv
import json
import multiprocessing
import os
import random
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipelines.cli import main
from tests.cli import one_error_line as _one_error_line
from tests.cli import run as _run
from vpr.groundtruth import load_pairs_csv

pytestmark = pytest.mark.slow  # faults, signals and concurrent runs through the command line

ROOT = Path(__file__).resolve().parents[1]
N_FRAMES = 30


@pytest.fixture(scope="module")
def scene(scene_on_disk):
    s = scene_on_disk("two_seasons", (48, 32), N_FRAMES)
    db, q = s[s["names"][0]], s[s["names"][1]]
    return {**s, "db": db, "q": q, "n_db": len(list(db.glob("*.png"))), "n_q": len(list(q.glob("*.png")))}




def _env():
    return {**os.environ, "PYTHONPATH": str(ROOT)}


def _cli(argv) -> list[str]:
    return [sys.executable, "-m", "pipelines.cli", *map(str, argv)]




def _listing(folder: Path) -> dict:
    return {p.relative_to(folder): p.stat().st_mtime_ns for p in folder.rglob("*")}


# ------------------------------------------------------------ 1. file systems that refuse
@pytest.fixture
def tmpfs(tmp_path):
    """A 200 kB tmpfs (root only); skipped where mounting is not permitted."""
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=200k", "tmpfs", str(mnt)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.decode().strip()})")
    yield mnt
    subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def test_read_only_file_system_gives_one_error_line(scene, tmpfs, capsys):
    r = subprocess.run(["mount", "-o", "remount,ro", str(tmpfs)], capture_output=True)
    if r.returncode != 0:
        pytest.skip("cannot remount read-only")
    code, _, err = _run(["match", scene["db"], scene["q"], "--method", "pairwise", "--out", tmpfs / "out"], capsys)
    _one_error_line(code, err, str(tmpfs / "out"), "Read-only file system")


def test_full_file_system_gives_one_line_and_no_partial_file(scene, tmpfs, capsys):
    # leave about 8 kB: the disk fills part-way through the run (encoding cache or outputs)
    filler = tmpfs / "filler"
    with open(filler, "wb") as fh:
        try:
            fh.write(b"\0" * (200 * 1024 - 8 * 1024))
        except OSError:
            pass
    out = tmpfs / "out"
    code, _, err = _run(["match", scene["db"], scene["q"], "--method", "pairwise", "--out", out,
                         "--tolerance", 2], capsys)
    line = _one_error_line(code, err, "No space left on device")
    assert str(out) in line and ".tmp" not in line
    # atomic writes: no temporary file left, every file present is whole
    leftovers = list(out.rglob(".*"))  # no temporary file, no lock
    assert leftovers == []
    for p in out.rglob("*.npy"):
        np.load(p)
    assert not (out / "metrics.json").exists()


def test_os_error_while_writing_gives_one_error_line(scene, tmp_path, capsys, monkeypatch):
    """The same without a mount: a write fails with ENOSPC."""
    import errno

    def full(*a, **k):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(np, "save", full)
    out = tmp_path / "out"
    code, _, err = _run(["match", scene["db"], scene["q"], "--method", "pairwise", "--out", out], capsys)
    _one_error_line(code, err, str(out / "pairwise" / "similarity.npy"), "No space left on device")
    assert not list(out.rglob(".similarity*"))


# ------------------------------------------------------------ 2. outputs never read back as inputs
def test_out_in_a_source_folder_is_refused(scene, tmp_path, capsys):
    import shutil

    db = tmp_path / "db"
    shutil.copytree(scene["db"], db)
    before = _listing(db)
    code, _, err = _run(["match", db, scene["q"], "--method", "pairwise", "--out", db], capsys)
    _one_error_line(code, err, "source folder", str(db))
    assert _listing(db) == before
    # a method's folder would be the source folder
    shutil.copytree(scene["db"], tmp_path / "pairwise")
    code, _, err = _run(["match", tmp_path / "pairwise", scene["q"], "--method", "pairwise", "--out", tmp_path],
                        capsys)
    _one_error_line(code, err, "pairwise/", "source folder")
    assert not (tmp_path / "metrics.json").exists() and not (tmp_path / "cache").exists()


# ------------------------------------------------------------ 3. methods run into one folder
def test_second_method_keeps_the_first(scene, tmp_path, capsys):
    out = tmp_path / "out"
    base = ["match", scene["db"], scene["q"], "--out", out, "--tolerance", 2]
    assert _run(base + ["--method", "rshosm"], capsys)[0] == 0
    S_rshosm = np.load(out / "rshosm" / "similarity.npy")
    code, stdout, _ = _run(base + ["--method", "seqslam"], capsys)
    assert code == 0 and "rshosm" in stdout and "seqslam" in stdout  # the table shows both
    m = json.loads((out / "metrics.json").read_text())
    assert set(m["methods"]) == {"rshosm", "seqslam"}
    assert np.array_equal(np.load(out / "rshosm" / "similarity.npy"), S_rshosm)
    assert (out / "seqslam" / "similarity.npy").is_file() and (out / "rshosm" / "config.json").is_file()


def test_two_concurrent_runs_keep_both_methods(scene, tmp_path):
    out = tmp_path / "out"
    procs = [subprocess.Popen(_cli(["match", scene["db"], scene["q"], "--out", out, "--tolerance", 2,
                                    "--method", m]), env=_env(), cwd=ROOT, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE) for m in ("pairwise", "seqslam")]
    for p in procs:
        _, err = p.communicate(timeout=300)
        assert p.returncode == 0, err.decode()
    m = json.loads((out / "metrics.json").read_text())
    assert set(m["methods"]) == {"pairwise", "seqslam"}


def _merge_worker(args):
    from pipelines.outputs import merge_metrics

    out, name, rounds = args
    for r in range(rounds):
        merge_metrics(Path(out), {"methods": {f"{name}-{r}": {"seconds": 0.0}},
                                  "params": {"inputs": {"kind": "test"}, "method_conf": {}}, "versions": {}}, "t")


def test_metrics_merge_is_locked(tmp_path):
    """Many processes merging at once lose no entry (without the lock they overwrite each other)."""
    ctx = multiprocessing.get_context("fork")
    with ctx.Pool(4) as pool:
        pool.map(_merge_worker, [(str(tmp_path), f"m{i}", 5) for i in range(4)])
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert set(m["methods"]) == {f"m{i}-{r}" for i in range(4) for r in range(5)}


def test_metrics_of_other_inputs_are_replaced_with_a_warning(scene, tmp_path, capsys):
    out = tmp_path / "out"
    assert _run(["match", scene["db"], scene["q"], "--out", out, "--method", "pairwise"], capsys)[0] == 0
    with pytest.warns(UserWarning, match="other inputs"):
        code, _, _ = _run(["match", scene["q"], scene["db"], "--out", out, "--method", "seqslam"], capsys)
    assert code == 0
    assert set(json.loads((out / "metrics.json").read_text())["methods"]) == {"seqslam"}


# ------------------------------------------------------------ 4. ground-truth columns by name
def test_pairs_columns_are_read_by_header_name(tmp_path):
    expected = np.zeros((4, 3), dtype=bool)
    expected[[2, 0], [0, 1]] = True
    for text in ("query,db\n0,2\n1,0\n", "db,query\n2,0\n0,1\n", "DB , Query\n2,0\n0,1\n", "0,2\n1,0\n"):
        p = tmp_path / "p.csv"
        p.write_text(text)
        assert np.array_equal(load_pairs_csv(p, 4, 3), expected), text
    p.write_text("foo,bar\n0,2\n")
    with pytest.raises(ValueError, match=r"p\.csv:1: unknown header 'foo,bar'.*query and db"):
        load_pairs_csv(p, 4, 3)


def test_db_query_header_through_the_cli(scene, tmp_path, capsys):
    # the same pairs (database frame j + 1 for query frame j) as db,query and as headerless query,db
    swapped, plain = tmp_path / "swapped.csv", tmp_path / "plain.csv"
    swapped.write_text("db,query\n" + "".join(f"{j + 1},{j}\n" for j in range(0, 20, 3)))
    plain.write_text("".join(f"{j},{j + 1}\n" for j in range(0, 20, 3)))
    got = []
    for gt in (swapped, plain):
        out = tmp_path / gt.stem
        code, _, _ = _run(["match", scene["db"], scene["q"], "--out", out, "--method", "pairwise", "--gt", gt], capsys)
        assert code == 0
        m = json.loads((out / "metrics.json").read_text())["methods"]["pairwise"]
        got.append({k: v for k, v in m.items() if k not in ("seconds", "similarity_file", "pr_curve")})
    assert got[0] == got[1]


# ------------------------------------------------------------ 5. every check before the work
@pytest.mark.parametrize("case", ["tolerance", "missing_gt", "bad_gt", "conf_value", "no_match", "radius_tol"])
def test_refused_before_any_work_and_nothing_written(scene, tmp_path, capsys, case):
    out = tmp_path / "out"
    bad = tmp_path / "bad.csv"
    bad.write_text("query,db\n0,1\n1,x\n")
    argv, expect = {
        "tolerance": (["--tolerance", -1], ["--tolerance", ">= 0"]),
        "missing_gt": (["--gt", tmp_path / "nope.csv"], ["nope.csv"]),
        "bad_gt": (["--gt", bad], ["bad.csv:3"]),
        "conf_value": (["--method-conf", "seqslam.ds=-5", "--method", "seqslam"], ["seqslam", "ds"]),
        # the two traverses are driven at different speeds: no frame pair at exactly the same position
        "no_match": (["--gt", scene["gt"], "--radius", 0], ["--radius 0", "no query frame is within 0"]),
        "radius_tol": (["--tolerance", 2, "--radius", 3], ["--radius", "--tolerance"]),
    }[case]
    t = time.perf_counter()
    code, _, err = _run(["match", scene["db"], scene["q"], "--out", out, *argv], capsys)
    _one_error_line(code, err, *expect)
    assert not out.exists()  # no cache, no folder: nothing was written
    assert time.perf_counter() - t < 30


def test_loops_without_true_match_is_said_in_user_words_and_counts_false_closures(tmp_path, capsys):
    from vpr.render import write_scene

    res = write_scene("two_seasons", tmp_path / "s", size=(48, 32), n_frames=20, progress=False)
    folder = res["traverses"][list(res["traverses"])[0]]["folder"]
    out = tmp_path / "out"
    # a straight drive never comes back: no loop closure within 1 m; what it accepts is false
    with pytest.warns(UserWarning, match="no frame is within 1 of a frame at least --exclude 5 frames earlier"):
        code, _, err = _run(["loops", folder, "--out", out, "--gt", res["ground_truth"], "--radius", 1,
                             "--exclude", 5], capsys)
    assert code == 0, err
    m = json.loads((out / "metrics.json").read_text())["methods"]["rshosm-seq"]
    assert m["revisits"] == 0 and m["false_per_1000"] == 1000 * m["n_false"] / 20


@pytest.mark.parametrize("conf", ["stop_ratio=2", "min_score=-1", "confirm=2"])
def test_bad_loop_acceptance_conf_is_refused_before_any_work(scene, tmp_path, capsys, conf):
    out = tmp_path / "out"
    code, _, err = _run(["loops", scene["db"], "--out", out, "--method-conf", f"rshosm-seq.{conf}"], capsys)
    _one_error_line(code, err, "--method-conf rshosm-seq", conf.split("=")[0])
    assert not out.exists()


# ------------------------------------------------------------ 6. options silently ignored
@pytest.mark.parametrize("case", ["soft_without_gt", "soft_below_radius", "soft_below_tolerance", "exclude"])
def test_ignored_options_are_errors(scene, tmp_path, capsys, case):
    out = tmp_path / "out"
    argv, expect = {
        "soft_without_gt": (["match", scene["db"], scene["q"], "--gt-soft", 5], ["--gt-soft", "needs"]),
        "soft_below_radius": (["match", scene["db"], scene["q"], "--gt", scene["gt"], "--radius", 3,
                               "--gt-soft", 2], ["--gt-soft 2", "--radius 3"]),
        "soft_below_tolerance": (["match", scene["db"], scene["q"], "--tolerance", 3, "--gt-soft", 1],
                                 ["--gt-soft 1", "--tolerance 3"]),
        "exclude": (["loops", scene["db"], "--exclude", 100], ["--exclude 100", f"{scene['n_db']} frames"]),
    }[case]
    code, _, err = _run(argv + ["--out", out], capsys)
    _one_error_line(code, err, *expect)
    assert not out.exists()


def test_harmless_ignored_options_warn(scene, tmp_path, capsys):
    out = tmp_path / "out"
    with pytest.warns(UserWarning) as rec:
        code, _, _ = _run(["compare", scene["db"], scene["q"], "--out", out, "--methods", "pairwise,pairwise",
                           "--method-conf", "seqslam.ds=4", "--min-inliers", 3], capsys)
    assert code == 0
    msgs = " | ".join(str(w.message) for w in rec)
    assert "pairwise more than once" in msgs
    assert "--method-conf for seqslam" in msgs and "ignored" in msgs
    assert "--min-inliers 3 has no effect without --verify" in msgs
    assert list(json.loads((out / "metrics.json").read_text())["methods"]) == ["pairwise"]


# ------------------------------------------------------------ 8, 9. decoder noise, logs off a terminal
def _garbage_video(path: Path, n=30):
    """A valid mp4 whose data is damaged after the first frames."""
    rng = np.random.default_rng(0)
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 5.0, (48, 32))
    for _ in range(n):
        w.write(cv2.GaussianBlur(rng.integers(0, 255, (32, 48, 3), dtype=np.uint8), (5, 5), 0))
    w.release()
    b = bytearray(path.read_bytes())
    i, j = b.find(b"mdat"), b.find(b"moov")
    assert 0 < i < j, "expected the index (moov) after the data (mdat)"
    lo = i + 8 + (j - i) // 4
    b[lo:j - 8] = rng.integers(0, 256, j - 8 - lo, dtype=np.uint8).tobytes()
    path.write_bytes(bytes(b))


def test_damaged_video_and_logs_off_a_terminal(scene, tmp_path):
    video = tmp_path / "damaged.mp4"
    _garbage_video(video)
    out = tmp_path / "out"
    r = subprocess.run(_cli(["match", scene["db"], video, "--out", out, "--method", "pairwise",
                             "--method-conf", "seqslam.ds=4"]),
                       env=_env(), cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    # no FFmpeg log, no progress bar, no source path and code line of a Python warning
    assert all(line.startswith("vpr: warning: ") for line in lines), r.stderr
    assert "\r" not in r.stderr
    skipped = [line for line in lines if "damaged.mp4" in line]
    assert len(skipped) == 1 and "of 30 frames could not be read" in skipped[0]
    assert any("--method-conf for seqslam" in line for line in lines)
    n_read = json.loads((out / "metrics.json").read_text())["params"]["n_query"]
    assert f"{30 - n_read} of 30 frames" in skipped[0]


def test_warning_format_is_restored_after_main(scene, tmp_path, capsys):
    before = warnings.formatwarning
    _run(["match", tmp_path / "nope", scene["q"], "--out", tmp_path / "o"], capsys)
    assert warnings.formatwarning is before


# ------------------------------------------------------------ 10. Ctrl-C during start-up
def test_ctrl_c_while_importing_in_process(monkeypatch, capsys):
    import importlib

    def interrupted(name, *a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(importlib, "import_module", interrupted)
    try:
        code = main(["match", "a", "b", "--out", "c"])
    except KeyboardInterrupt:
        pytest.fail("KeyboardInterrupt escaped main")
    assert code == 130
    assert capsys.readouterr().err.strip() == "vpr: interrupted"


def _start(argv) -> subprocess.Popen:
    """``vpr ARGV`` in a subprocess, returned once ``main`` is about to run (it has not imported much yet)."""
    code = ("import sys\nfrom pipelines.cli import main\nsys.stderr.write('ready\\n'); sys.stderr.flush()\n"
            f"sys.exit(main({[str(a) for a in argv]!r}))")
    p = subprocess.Popen([sys.executable, "-c", code], env=_env(), cwd=ROOT, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    assert p.stderr.readline() == "ready\n"
    return p


def test_ctrl_c_right_after_start(scene, tmp_path):
    p = _start(["match", scene["db"], scene["q"], "--out", tmp_path / "o"])
    # 0.2 s after the last line before main(): main is loading NumPy, OpenCV and the methods
    time.sleep(0.2)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130, err
    assert err.strip() == "vpr: interrupted"


def test_ctrl_c_while_a_library_loads_lazily_is_an_interrupt(scene, tmp_path, monkeypatch, capsys):
    import encoders.cnn

    def stopped(name):  # what onnxruntime's extension raises when Ctrl-C comes while it initialises
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as e:
            raise ImportError("initialization failed") from e

    monkeypatch.setattr(encoders.cnn, "import_held", stopped)
    assert main(["match", str(scene["db"]), str(scene["q"]), "--out", str(tmp_path / "o")]) == 130
    assert capsys.readouterr().err.strip() == "vpr: interrupted"
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------ interrupted runs, corrupt cache
def _check_complete(out: Path, n_db: int, n_q: int) -> None:
    """Every file present is whole; no temporary file is left."""
    assert [p for p in out.rglob(".*") if not p.name.endswith(".lock")] == []
    for p in out.rglob("*"):
        if p.suffix == ".npy":
            assert np.load(p).shape == (n_db, n_q)
        elif p.suffix == ".npz":
            with np.load(p) as z:
                dict(z)
        elif p.suffix == ".json":
            json.loads(p.read_text())
        elif p.suffix == ".png":
            assert cv2.imread(str(p)) is not None, p
        elif p.suffix == ".csv":  # a row per query (top.csv: each query's 20 best, here every database frame or 20)
            assert len(list(csv.DictReader(open(p)))) == (n_q * min(20, n_db) if p.name == "top.csv" else n_q), p


def _results(out: Path, names) -> dict:
    m = json.loads((out / "metrics.json").read_text())["methods"]
    res = {}
    for name in names:
        res[name] = (np.load(out / name / "similarity.npy"), (out / name / "matches.csv").read_text(),
                     {k: v for k, v in m[name].items() if k != "seconds"})
    return res


def _assert_same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        assert np.array_equal(a[k][0], b[k][0]) and a[k][1:] == b[k][1:], k


def test_sigint_at_random_points_then_rerun(scene, tmp_path, capsys):
    names = ["rshosm", "pairwise"]
    argv = ["compare", scene["db"], scene["q"], "--methods", ",".join(names), "--tolerance", 2]
    ref_out = tmp_path / "ref"
    p = _start(argv + ["--out", ref_out])
    t0 = time.perf_counter()
    _, err = p.communicate(timeout=300)
    duration = time.perf_counter() - t0
    assert p.returncode == 0, err
    reference = _results(ref_out, names)
    rng = random.Random(11)
    interrupted = 0
    for k in range(3):
        out = tmp_path / f"run{k}"
        p = _start(argv + ["--out", out])
        time.sleep(rng.uniform(0.05, duration))
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=300)
        assert p.returncode in (0, 130, -signal.SIGINT), err
        assert "Traceback" not in err
        if p.returncode == -signal.SIGINT:
            # the signal came while the interpreter shut down, after main had returned
            assert err == "" and (out / "metrics.json").is_file()
        interrupted += p.returncode == 130
        if out.exists():
            _check_complete(out, scene["n_db"], scene["n_q"])
        code, _, _ = _run(argv + ["--out", out], capsys)
        assert code == 0
        _check_complete(out, scene["n_db"], scene["n_q"])
        _assert_same(_results(out, names), reference)
    assert interrupted >= 1


def test_corrupt_cache_and_metrics_are_recomputed(scene, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["match", scene["db"], scene["q"], "--out", out, "--method", "pairwise", "--tolerance", 2]
    assert _run(argv, capsys)[0] == 0
    reference = _results(out, ["pairwise"])
    caches = sorted((out / "cache").glob("*.npz"))
    assert len(caches) == 2
    caches[0].write_bytes(b"PK\x03\x04 damaged")
    caches[1].write_bytes(caches[1].read_bytes()[:100])
    (out / "metrics.json").write_text('{"methods": {"pairwise": ')
    with pytest.warns(UserWarning, match="metrics.json: unreadable"):
        code, _, _ = _run(argv, capsys)
    assert code == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["params"]["cached"] == {"db": False, "query": False}
    _assert_same(_results(out, ["pairwise"]), reference)
    for c in caches:  # rewritten whole
        with np.load(c) as z:
            assert "names" in z.files
