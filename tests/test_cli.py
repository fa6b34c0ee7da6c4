"""End to end through the ``vpr`` command line on small renders."""
import csv
import json

import cv2
import numpy as np
import pytest

from pipelines.cli import main

pytestmark = pytest.mark.slow  # the command line end to end

N_FRAMES = 40


@pytest.fixture(scope="module")
def scene(scene_on_disk):
    s = scene_on_disk("two_seasons", (64, 48), N_FRAMES)
    return {**s, "db": s[s["names"][0]], "q": s[s["names"][1]]}


def _run(argv, capsys):
    code = main([str(a) for a in argv] + ["--no-progress"])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def _check_outputs(folder, n_db, n_q):
    S = np.load(folder / "similarity.npy")
    assert S.dtype == np.float32 and S.shape == (n_db, n_q)
    rows = list(csv.DictReader(open(folder / "matches.csv")))
    assert len(rows) == n_q
    assert all(-1 <= int(r["best_db"]) < n_db and r["accepted"] in ("0", "1") for r in rows)
    assert (folder / "similarity.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("method", ["rshosm", "seqslam", "pairwise"])
def test_match_every_method(scene, tmp_path, capsys, method):
    out = tmp_path / method
    code, stdout, _ = _run(["match", scene["db"], scene["q"], "--method", method, "--out", out,
                            "--gt", scene["gt"], "--radius", 3], capsys)
    assert code == 0
    n_db = len(list(scene["db"].glob("*.png")))
    n_q = len(list(scene["q"].glob("*.png")))
    _check_outputs(out / method, n_db, n_q)  # a folder per method, also for one method
    m = json.loads((out / "metrics.json").read_text())
    assert set(m) == {"methods", "params", "versions"}
    for key in ("auc_pr", "recall_at_100p", "recall_at_1", "seconds"):
        assert 0 <= m["methods"][method][key] <= (1 if key != "seconds" else 1e6)
    assert (out / "pr.png").stat().st_size > 0 and (out / method / "config.json").is_file()
    assert method in stdout


def test_compare_uses_the_cache_and_prints_a_table(scene, tmp_path, capsys):
    out = tmp_path / "cmp"
    args = ["compare", scene["db"], scene["q"], "--out", out, "--tolerance", 2]
    code, stdout, _ = _run(args + ["--methods", "rshosm,pairwise"], capsys)
    assert code == 0 and "rshosm" in stdout and "pairwise" in stdout
    for m in ("rshosm", "pairwise"):
        assert (out / m / "similarity.npy").is_file()
    code, _, _ = _run(args + ["--methods", "pairwise"], capsys)
    assert json.loads((out / "metrics.json").read_text())["params"]["cached"] == {"db": True, "query": True}


def test_compare_with_rshosm_seq_sparse_and_the_others_dense(scene, tmp_path, capsys, monkeypatch):
    # between DENSE_EVIDENCE_PAIRS and the memory limit rshosm-seq's matrix is top-K sparse while the
    # ground truth and the other methods' matrices stay dense: one run evaluates, plots and writes both
    import scipy.sparse as sp

    from vpr.methods import rshosm_seq

    monkeypatch.setattr(rshosm_seq, "DENSE_EVIDENCE_PAIRS", 1)
    out = tmp_path / "mixed"
    code, stdout, err = _run(["compare", scene["db"], scene["q"], "--out", out, "--tolerance", 2,
                              "--methods", "rshosm-seq,pairwise", "--method-conf", "rshosm-seq.top_k=5"], capsys)
    assert code == 0, err
    S = sp.load_npz(out / "rshosm-seq" / "similarity_topk.npz")
    assert S.shape == (N_FRAMES, N_FRAMES) and np.diff(S.tocsc().indptr).max() <= 5
    assert not (out / "rshosm-seq" / "similarity.npy").exists() and (out / "pairwise" / "similarity.npy").is_file()
    m = json.loads((out / "metrics.json").read_text())["methods"]
    assert m["rshosm-seq"]["recall_at_1"] >= m["pairwise"]["recall_at_1"] and 0 < m["rshosm-seq"]["ap"] <= 1
    assert (out / "rshosm-seq" / "similarity.png").is_file() and (out / "pr.png").is_file()


def test_video_source_and_verification(scene, tmp_path, capsys):
    video = tmp_path / "query.mp4"
    frames = sorted(scene["q"].glob("*.png"))
    w = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 5.0, (64, 48))
    for f in frames:
        w.write(cv2.imread(str(f)))
    w.release()
    out = tmp_path / "vid"
    code, stdout, _ = _run(["match", scene["db"], video, "--method", "pairwise", "--out", out,
                            "--tolerance", 100, "--verify", 2, "--step", 2], capsys)
    assert code == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["params"]["n_query"] == (len(frames) + 1) // 2
    assert "pairwise+verify" in m["methods"]
    header = open(out / "pairwise" / "matches.csv").readline().strip().split(",")
    assert {"inliers", "verified_db"} <= set(header)


def test_loops_on_a_loop_scene(tmp_path, capsys):
    from vpr.render import write_scene

    res = write_scene("loop_revisits", tmp_path / "loop", size=(64, 48), n_frames=60, progress=False)
    (name,) = list(res["traverses"])[:1]
    out = tmp_path / "loops"
    code, _, _ = _run(["loops", res["traverses"][name]["folder"], "--method", "rshosm", "--out", out,
                       "--exclude", 5, "--gt", res["ground_truth"], "--radius", 3], capsys)
    assert code == 0
    m = json.loads((out / "metrics.json").read_text())["methods"]["rshosm"]
    assert 0 <= m["auc_pr"] <= 1
    rows = list(csv.DictReader(open(out / "rshosm" / "matches.csv")))
    assert m["n_accepted"] == sum(r["accepted"] == "1" for r in rows) and 0 <= m["precision_accepted"] <= 1
    assert all(int(r["best_db"]) <= int(r["query"]) - 5 for r in rows if r["accepted"] == "1")
    # soft ground truth: pairs within 8 but not 3 are ignored, which can only raise AP
    code, _, _ = _run(["loops", res["traverses"][name]["folder"], "--method", "rshosm", "--out", tmp_path / "soft",
                       "--exclude", 5, "--gt", res["ground_truth"], "--radius", 3, "--gt-soft", 8], capsys)
    assert code == 0
    soft = json.loads((tmp_path / "soft" / "metrics.json").read_text())
    assert soft["params"]["ground_truth"]["gt_soft"] == 8
    assert soft["methods"]["rshosm"]["ap"] > m["ap"]
    code, _, err = _run(["loops", res["traverses"][name]["folder"], "--out", tmp_path / "bad", "--gt",
                         res["ground_truth"], "--radius", 3, "--gt-soft", 2], capsys)
    assert code == 2 and "--gt-soft 2" in err


def test_corrupt_png_is_skipped_and_recorded(scene, tmp_path, capsys):
    import shutil

    db = tmp_path / "db"
    shutil.copytree(scene["db"], db)
    (db / "000003.png").write_bytes(b"\x89PNG\r\n\x1a\ngarbage")
    (db / "notes.txt").write_text("not an image")
    out = tmp_path / "out"
    with pytest.warns(UserWarning, match="000003.png"):
        code, _, _ = _run(["match", db, scene["q"], "--method", "pairwise", "--out", out], capsys)
    assert code == 0
    p = json.loads((out / "metrics.json").read_text())["params"]
    assert [s[0] for s in p["skipped"]["db"]] == ["000003.png"]
    assert p["ignored_files"]["db"] == 1


@pytest.mark.parametrize("case", ["missing", "empty", "video", "gt", "gt_tolerance", "method_conf"])
def test_bad_input_gives_one_line_and_exit_2(scene, tmp_path, capsys, case):
    out = tmp_path / "out"
    if case == "missing":
        argv, expect = ["match", tmp_path / "nope", scene["q"], "--out", out], "nope"
    elif case == "empty":
        (tmp_path / "empty").mkdir()
        argv, expect = ["match", tmp_path / "empty", scene["q"], "--out", out], "no images"
    elif case == "video":
        bad = tmp_path / "bad.mp4"
        bad.write_bytes(b"\x00" * 1000)
        argv, expect = ["match", scene["db"], bad, "--out", out], "bad.mp4"
    elif case == "gt":
        gt = tmp_path / "gt.csv"
        gt.write_text("query,db\n0,1\n1,x\n")
        argv, expect = ["match", scene["db"], scene["q"], "--out", out, "--gt", gt], "gt.csv:3"
    elif case == "gt_tolerance":  # OpenSeqSLAM's rows: the tolerance's unit must be said
        gt = tmp_path / "truth.csv"
        gt.write_text("1,1,15\n2,2,15\n")
        argv, expect = ["match", scene["db"], scene["q"], "--out", out, "--gt", gt], "--gt-tolerance-unit N"
    else:
        argv, expect = ["match", scene["db"], scene["q"], "--out", out, "--method-conf", "seqslam.nope=1"], "nope"
    code, _, err = _run(argv, capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and expect in lines[0]
    assert not out.exists()  # a refused run writes nothing


def test_demo_tiny(tmp_path, capsys):
    code, stdout, _ = _run(["demo", "--out", tmp_path / "demo", "--size", "64x48", "--frames", 30,
                            "--verify", 1], capsys)
    assert code == 0
    for m in ("rshosm", "seqslam", "seqslam-desc", "pairwise", "rshosm-seq+verify"):
        assert m in stdout
    assert "pairwise+verify" not in stdout  # the demo verifies rshosm-seq only
    assert (tmp_path / "demo" / "scene" / "contact_sheet.png").is_file()
    assert (tmp_path / "demo" / "pr.png").is_file()


def test_commands_are_declared_by_the_pipeline_modules():
    import importlib

    from pipelines import cli

    table = cli.commands()
    assert {"demo", "match", "compare", "loops", "render", "paper-fig3", "nordland"} <= set(table)
    for cmd, (module, help_) in table.items():
        mod = importlib.import_module(module)
        # the literal read from the source is the module's own table, and the module can run the command
        assert mod.COMMANDS[cmd] == help_ and callable(mod.add_arguments) and callable(mod.run_command)


def test_help_imports_no_pipeline_module():
    import subprocess
    import sys

    code = ("import sys, contextlib, io\nfrom pipelines.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n    main([])\n"
            "print(sorted(m for m in sys.modules if m.startswith(('pipelines.', 'encoders', 'vpr.methods'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    # the command line alone (its signal handling is vpr.interrupts, the standard library), no command module
    assert out.strip() == "['pipelines.cli']"


def test_closed_stdout_ends_quietly(monkeypatch, capsys):
    import pipelines.encoders_cmd as cmd

    def closed(args):
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(cmd, "run_command", closed)
    code = main(["encoders", "list"])
    assert code == 141 and capsys.readouterr().err == ""
