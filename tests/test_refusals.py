"""Options never silently ignored, refusals before work, clean stops, errors and warnings that say enough,
pictures people read."""
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.cli import one_error_line as _one_error_line
from tests.cli import run as _run

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def scene(scene_on_disk):
    s = scene_on_disk("two_seasons", (48, 32), 30)
    return {**s, "db": s[s["names"][0]], "q": s[s["names"][1]]}






# ------------------------------------------------------------ 1. headlines
def test_precision_over_nothing_accepted_prints_a_dash_and_the_count():
    from vpr.report import metrics_table

    table = metrics_table({"m": {"ap": 0.5, "n_accepted": 0, "precision_accepted": None, "recall_accepted": 0.0}})
    row = table.splitlines()[1].split()
    assert row[0] == "m" and "1.000" not in table
    header = table.splitlines()[0].split()
    assert row[header.index("accepted")] == "0" and row[header.index("P(acc)")] == "-"


# ------------------------------------------------------------ 2. options silently ignored
@pytest.fixture(scope="module")
def map_file(scene, tmp_path_factory):
    from pipelines.localize import learn

    out = tmp_path_factory.mktemp("map") / "map_noext"
    learn(scene["db"], out, encoder_conf={"k": 60, "standardise": "fit"}, progress=False)
    return out.with_name("map_noext.npz")


@pytest.mark.parametrize("extra, message", [
    (["--encoder", "cnn"], "--encoder"),
    (["--encoder-conf", "k=10"], "--encoder-conf"),
    (["--preset", "paper"], "--preset"),
    (["--method-conf", "rshosm-seq.nosuch=1"], "unknown rshosm-seq option"),
    (["--method-conf", "rshosm-seq.min_score=abc"], "min_score"),
    (["--method-conf", "rshosm-seq.threshold=0.5"], "fixed by the map"),
    (["--method-conf", "seqslam.ds=4"], "--method-conf for seqslam does not apply"),
])
def test_localize_with_a_map_refuses_what_the_map_fixes(scene, map_file, tmp_path, capsys, extra, message):
    code, out, err = _run(["localize", map_file, scene["q"], "--out", tmp_path / "o", *extra], capsys)
    _one_error_line(code, err, message)
    assert not (tmp_path / "o").exists()


@pytest.mark.slow  # command-line integration
def test_localize_applies_query_time_settings_to_a_map(scene, map_file, tmp_path, capsys):
    code, out, err = _run(["localize", map_file, scene["q"], "--out", tmp_path / "o", "--method-conf",
                           "rshosm-seq.min_score=1e9"], capsys)
    assert code == 0, err
    m = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert m["params"]["method_conf"]["rshosm-seq"]["min_score"] == 1e9
    assert m["methods"]["rshosm-seq"]["n_accepted"] == 0


@pytest.mark.slow  # command-line integration
def test_learn_adds_the_suffix_and_maps_are_read_by_content(scene, map_file, tmp_path, capsys):
    assert map_file.is_file() and map_file.suffix == ".npz"
    renamed = tmp_path / "robot_map"  # a map renamed without a suffix is still a map
    shutil.copy(map_file, renamed)
    code, _, err = _run(["localize", renamed, scene["q"], "--out", tmp_path / "o"], capsys)
    assert code == 0, err
    (tmp_path / "dir").mkdir()
    code, _, err = _run(["learn", scene["db"], "--out", str(tmp_path / "dir") + "/"], capsys)
    _one_error_line(code, err, "is a folder")


def test_joined_encoder_conf_without_a_part_applies_to_every_part_or_is_refused():
    import encoders
    from vpr import presets

    s = presets.resolve(None, encoder_conf={"k": "abc"})
    with pytest.raises(ValueError, match=r"part pixel.*cannot read 'abc' as int"):
        encoders.get(s["encoder"], **s["encoder_conf"])
    s = presets.resolve(None, encoder_conf={"k": "30"})
    assert [e.conf["k"] for e in encoders.get(s["encoder"], **s["encoder_conf"]).encoders] == [30, 30]
    with pytest.raises(ValueError, match=r"part pixel \(pixel.KEY\): k must be"):
        encoders.get("pixel+cnn", **{"pixel.k": 0})


def test_every_sub_command_takes_no_progress():
    from pipelines.cli import build_parser, commands

    table = commands()
    for cmd in table:
        ap = build_parser(cmd, table)
        sub = [a for a in ap._actions if a.dest == "command"][0].choices[cmd]
        if cmd == "encoders":
            for action in ("list", "test"):
                inner = [a for a in sub._actions if a.dest == "encoders_action"][0].choices[action]
                assert "--no-progress" in inner._option_string_actions, (cmd, action)
        else:
            assert "--no-progress" in sub._option_string_actions, cmd


# ------------------------------------------------------------ 3. distributed encoding
@pytest.mark.parametrize("command", ["loops", "compare"])
def test_a_lag_of_online_localisation_is_refused_before_any_work(scene, tmp_path, capsys, command):
    inputs = [scene["db"]] if command == "loops" else [scene["db"], scene["q"]]
    code, _, err = _run([command, *inputs, "--out", tmp_path / "o", "--cache", tmp_path / "c", "--method-conf",
                         "rshosm-seq.lag=3"], capsys)
    _one_error_line(code, err, "lag applies to online localisation")
    assert not (tmp_path / "o").exists() and not (tmp_path / "c").exists()  # nothing encoded, nothing written


def test_absurd_worker_counts_are_refused(scene, tmp_path, capsys):
    code, _, err = _run(["encode", scene["db"], "--cache", tmp_path / "c", "--workers", 1000], capsys)
    _one_error_line(code, err, "--workers 1000", "--scheduler")


@pytest.mark.slow  # a Dask client's connection timeout: seconds of waiting
def test_scheduler_that_is_not_dask_fails_in_one_error_line(scene, tmp_path, capsys, monkeypatch):
    import socket
    import threading

    import pipelines.cluster as cluster

    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT", 3.0)
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(5)
    port = srv.getsockname()[1]
    conns = []
    threading.Thread(target=lambda: conns.append(srv.accept()), daemon=True).start()  # accepts, says nothing
    t = time.perf_counter()
    code, _, err = _run(["encode", scene["db"], "--cache", tmp_path / "c", "--scheduler", f"tcp://127.0.0.1:{port}"],
                        capsys)
    assert time.perf_counter() - t < 30
    _one_error_line(code, err, "--scheduler", "Dask scheduler")
    assert "Traceback" not in err
    srv.close()


# ------------------------------------------------------------ 4. stops and refusals
def _start(argv):
    return subprocess.Popen([sys.executable, "-m", "pipelines.cli", *map(str, argv)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})


@pytest.mark.slow
def test_sigterm_is_handled_as_an_interrupt_and_leaves_only_complete_files(scene, tmp_path):
    terminated = 0
    for k, delay in enumerate((1.5, 2.5, 3.5, 4.5)):
        out = tmp_path / f"o{k}"
        p = _start(["compare", scene["db"], scene["q"], "--out", out, "--methods", "rshosm-seq,pairwise",
                    "--verify", 2, "--tolerance", 2])
        time.sleep(delay)
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=120)
        assert "Aborted" not in err and "stack trace" not in err and "Traceback" not in err, err
        if p.returncode == -signal.SIGTERM:  # after main had returned: the run was complete
            assert err == "" and (out / "metrics.json").is_file()
        else:
            assert p.returncode in (0, 143), err
        if p.returncode == 143:
            terminated += 1
            assert err.strip().splitlines()[-1] == "vpr: terminated"
        if out.exists():
            assert [q for q in out.rglob(".*") if not q.name.endswith(".lock")] == []
    assert terminated >= 1


def test_demo_refuses_too_few_frames_before_rendering(tmp_path, capsys):
    code, _, err = _run(["demo", "--out", tmp_path / "d", "--frames", 1], capsys)
    _one_error_line(code, err, "--frames 1")
    assert not (tmp_path / "d").exists()


def test_localize_state_out_in_a_read_only_folder_is_refused_before_work(scene, map_file, tmp_path, capsys,
                                                                          monkeypatch):
    ro = tmp_path / "ro"
    ro.mkdir()
    real = os.access
    # root may write anywhere: the folder is read-only as the check sees it
    monkeypatch.setattr(os, "access", lambda p, mode, **k: False if Path(p) == ro else real(p, mode, **k))
    code, _, err = _run(["localize", map_file, scene["q"], "--out", tmp_path / "o", "--state-out",
                         ro / "state.npz"], capsys)
    _one_error_line(code, err, "state.npz", "cannot write")
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------ 5. errors and warnings that say enough
def test_one_frame_for_a_fitted_encoder_names_source_and_option(scene, tmp_path, capsys):
    code, _, err = _run(["match", scene["db"], scene["q"], "--out", tmp_path / "o", "--max-frames", 1,
                         "--preset", "fast"], capsys)
    _one_error_line(code, err, str(scene["db"]), "--max-frames 1", "standardise=fit")


def test_degenerate_sdrs_warn_with_their_count(tmp_path, capsys):
    import cv2

    folder = tmp_path / "same"
    folder.mkdir()
    for i in range(12):
        cv2.imwrite(str(folder / f"{i:03d}.png"), np.full((32, 48, 3), 128, np.uint8))
    with pytest.warns(UserWarning) as rec:
        code, _, err = _run(["match", folder, folder, "--out", tmp_path / "o", "--method", "pairwise", "--preset",
                             "fast", "--encoder-conf", "standardise=none"], capsys)
    assert code == 0, err
    assert "11 of 12 frames repeat another frame's SDR exactly" in " | ".join(str(w.message) for w in rec)


@pytest.mark.slow  # command-line integration
def test_a_cache_file_of_another_source_is_not_trusted(scene, tmp_path, capsys):
    import encoders
    from pipelines.extract import cache_path
    from vpr.sources import open_source

    args = ["--method", "pairwise", "--preset", "fast", "--tolerance", 2, "--cache", tmp_path / "c"]
    code, _, err = _run(["match", scene["db"], scene["q"], "--out", tmp_path / "a", *args], capsys)
    assert code == 0, err
    enc = encoders.get("pixel", k=200, standardise="fit")
    a = cache_path(tmp_path / "c", open_source(scene["db"]), enc)
    b = cache_path(tmp_path / "c", open_source(scene["q"]), enc)
    assert a.is_file() and b.is_file()
    shutil.copy(a, b)  # the database's encodings under the query's name
    with pytest.warns(UserWarning, match="written for another source"):
        code, _, err = _run(["match", scene["db"], scene["q"], "--out", tmp_path / "b", *args], capsys)
    assert code == 0, err
    same = [json.loads((tmp_path / d / "metrics.json").read_text())["methods"]["pairwise"]["ap"] for d in "ab"]
    assert same[0] == same[1]


def test_cache_that_is_a_file_is_refused(scene, tmp_path, capsys):
    (tmp_path / "c").write_text("x")
    code, _, err = _run(["match", scene["db"], scene["q"], "--out", tmp_path / "o", "--cache", tmp_path / "c"],
                        capsys)
    _one_error_line(code, err, "--cache", "is a file")


def test_random_bytes_are_not_a_map(tmp_path, capsys, scene):
    (tmp_path / "m.npz").write_bytes(os.urandom(2000))
    code, _, err = _run(["localize", tmp_path / "m.npz", scene["q"], "--out", tmp_path / "o"], capsys)
    _one_error_line(code, err, "m.npz", "not a readable map file")
    assert "allow_pickle" not in err


# ------------------------------------------------------------ 6. pictures
def test_pr_plot_twins_share_a_colour_and_the_legend_is_outside(tmp_path, monkeypatch):
    import matplotlib.figure

    from vpr import plots

    seen = {}
    orig = matplotlib.figure.Figure.savefig

    def spy(fig, *a, **k):
        seen["fig"] = fig
        return orig(fig, *a, **k)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", spy)
    c = (np.array([1.0, 0.5]), np.array([0.0, 1.0]))
    plots.plot_pr({"a": c, "a+verify": c, "b": c}, tmp_path / "pr.png")
    ax = seen["fig"].axes[0]
    lines = {ln.get_label().split(" ")[0]: ln for ln in ax.get_lines()}
    assert lines["a"].get_color() == lines["a+verify"].get_color() != lines["b"].get_color()
    assert lines["a+verify"].get_linestyle() == "--" and lines["a"].get_linestyle() == "-"
    assert lines["a+verify"].get_zorder() > lines["a"].get_zorder()  # equal curves: the dashed twin shows
    legend = ax.get_legend()
    assert legend._bbox_to_anchor is not None and legend._bbox_to_anchor.x0 > ax.bbox.x1 - 1


def test_heatmap_labels_right_and_wrong_and_its_axes(tmp_path, monkeypatch):
    import matplotlib.figure

    from vpr import plots

    seen = {}
    orig = matplotlib.figure.Figure.savefig
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig",
                        lambda fig, *a, **k: (seen.setdefault("fig", fig), orig(fig, *a, **k))[1])
    S = np.full((6, 6), -np.inf)
    S[np.triu_indices(6, 2)] = 1.0
    best = np.array([-1, -1, 0, 1, 0, 0])
    acc = np.array([False, False, True, True, True, False])
    gt = np.zeros((6, 6), bool)
    gt[0, 2] = gt[1, 3] = True
    plots.plot_similarity(S, tmp_path / "s.png", best_db=best, accepted=acc, gt_hard=gt, value_label="z-score",
                          axis_labels=("earlier frame", "frame"))
    ax = seen["fig"].axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert {"accepted, right", "accepted, wrong", "rejected", "no score"} <= set(labels)
    assert ax.get_xlabel() == "frame" and ax.get_ylabel() == "earlier frame"
    assert seen["fig"].axes[1].get_ylabel() == "z-score"
    seen.clear()
    plots.plot_similarity(np.eye(3), tmp_path / "t.png", best_db=np.array([0, 1, 2]), accepted=np.ones(3, bool))
    labels = [t.get_text() for t in seen["fig"].axes[0].get_legend().get_texts()]
    assert "rejected" not in labels and "no score" not in labels


def test_read_only_cache_folder_is_read_and_said_so(scene, tmp_path, capsys, monkeypatch):
    cache = tmp_path / "c"
    cache.mkdir()
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, **k: False if Path(p) == cache else real(p, mode, **k))
    with pytest.warns(UserWarning, match="not writable; encodings found there are read, new ones are not cached"):
        code, _, err = _run(["match", scene["db"], scene["q"], "--out", tmp_path / "o", "--method", "pairwise",
                             "--preset", "fast", "--cache", cache], capsys)
    assert code == 0, err


@pytest.mark.slow
@pytest.mark.parametrize("after", [0.3, 1.0], ids=["cluster-starting", "encoding"])
def test_sigterm_of_a_local_dask_encode_leaves_no_scratch_and_no_semaphores(scene, tmp_path, after):
    cache = tmp_path / "cache"
    p = subprocess.Popen([sys.executable, "-m", "pipelines.cli", "encode", str(scene["db"]), str(scene["q"]),
                          "--cache", str(cache), "--workers", "2", "--chunk-frames", "1", "--preset", "fast"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    deadline = time.time() + 60
    while time.time() < deadline and not any(cache.glob(".dask-scratch-*")):
        time.sleep(0.02)  # the first worker's folder: the local cluster is starting
    time.sleep(after)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=120)
    # 143: the run was stopped (one line); 0 or killed by the signal itself: it had finished, and the
    # signal came before or after main() put the previous handler back (a shell shows 143 for both)
    assert p.returncode in (0, 143, -signal.SIGTERM), err
    assert "leaked semaphore" not in err and "Traceback" not in err, err
    assert not list(tmp_path.glob("dask-scratch-space*")) and not list(cache.glob(".dask-scratch-*"))


# ------------------------------------------------------------ huge values and what a run leaves
@pytest.mark.parametrize("argv, expect", [
    (["match", "{db}", "{q}", "--method", "pairwise", "--verify", "1000000000"],
     ["--verify 1000000000: more candidates per query than the database's", "at most"]),
    (["demo", "--frames", "100000000"], ["--frames 100000000: the demo renders at most 20000 frames"]),
    (["render", "two_seasons", "--frames", "100000000"], ["at most 1000000 frames per traverse"]),
    # settings of loop closure within one stream, given to database x query matching or a map
    (["compare", "{db}", "{q}", "--methods", "rshosm-seq", "--method-conf", "rshosm-seq.confirm_frames=5"],
     ["rshosm-seq: confirm_frames applies to loop closure within one stream"]),
    (["learn", "{db}", "--method-conf", "rshosm-seq.stop_ratio=0.2"],
     ["rshosm-seq: stop_ratio applies to loop closure within one stream"]),
])
def test_huge_or_misplaced_values_are_refused_in_one_line_before_anything_is_written(scene, tmp_path, capsys, argv,
                                                                                     expect):
    out = tmp_path / "o"
    argv = [a.format(db=scene["db"], q=scene["q"]) for a in argv] + ["--out", out]
    code, _, err = _run(argv, capsys)
    _one_error_line(code, err, *expect)
    assert not out.exists()


@pytest.mark.slow  # command-line integration
def test_a_run_leaves_no_lock_behind_and_a_refused_one_no_folder(scene, tmp_path, capsys):
    out = tmp_path / "o"
    code, _, err = _run(["compare", scene["db"], scene["q"], "--out", out, "--methods", "pairwise,seqslam",
                         "--tolerance", 2], capsys)
    assert code == 0, err
    assert not list(out.rglob("*.lock")) and (out / "metrics.json").is_file()
    from vpr import io

    with io.claimed(tmp_path / "new" / ".m.lock", "m"):  # a run refused once it holds its claim
        assert (tmp_path / "new" / ".m.lock").is_file()
    assert not (tmp_path / "new").exists()  # the folder the claim made, empty, goes with it
