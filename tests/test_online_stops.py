"""Online runs keep what they decided: a stopped ``vpr loops -`` / ``vpr localize`` writes its outputs and state.

A robot that is stopped (SIGTERM from its supervisor, Ctrl-C) must not lose the
session: the frames answered so far are written (``METHOD/matches.csv``,
``metrics.json``) with the state of ``--state-out``, and ``--resume`` from that
state gives the answers of a run that was never stopped.
"""
import csv
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from pipelines.cli import main
from vpr.shosm import LOCALIZE_LAG

pytestmark = pytest.mark.slow  # command-line runs in a subprocess, stopped by a signal

ROOT = Path(__file__).resolve().parents[1]
LOOSE = ["--preset", "fast", "--exclude", "12", "--method-conf", "rshosm-seq.min_score=10"]
#: each frame answered before the next is read (the stop tests feed frames one by one): nothing accepted back
ONE_BY_ONE = [*LOOSE, "--method-conf", "rshosm-seq.backfill_frames=0"]


@pytest.fixture(scope="module")
def laps(scene_on_disk):
    s = scene_on_disk("loop_revisits", (48, 36), 240)
    return {**s, "paths": sorted(str(p) for p in s["laps"].glob("*.png"))}


def _start(argv) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "pipelines.cli", *map(str, argv)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})


def _feed_then_stop(p: subprocess.Popen, paths, sig, late: int = 0) -> tuple[list[dict], str]:
    """Send ``paths`` one by one, each answered before the next (``late``: the answer of the frame that many before);
    then ``sig`` while the run waits for more."""
    answers = []
    for k, path in enumerate(paths):
        p.stdin.write(path + "\n")
        p.stdin.flush()
        if k >= late:
            answers.append(json.loads(p.stdout.readline()))
    p.send_signal(sig)
    out, err = p.communicate(timeout=120)
    return answers + [json.loads(s) for s in out.splitlines()], err


def _main(argv) -> int:
    return main([str(a) for a in argv] + ["--no-progress"])


def _rows(folder: Path) -> list[dict]:
    with open(folder / "rshosm-seq" / "matches.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def _key(r: dict):
    return r["query"], r["best_db"], r["score"], r["accepted"]


@pytest.mark.parametrize("sig, code, said", [(signal.SIGTERM, 143, "vpr: terminated"),
                                              (signal.SIGINT, 130, "vpr: interrupted")])
def test_stopped_loops_writes_its_outputs_and_state_then_resumes_exactly(laps, tmp_path, capsys, monkeypatch, sig,
                                                                          code, said):
    import io

    paths = laps["paths"]
    monkeypatch.setattr("sys.stdin", io.StringIO("\n".join(paths) + "\n"))
    assert _main(["loops", "-", "--out", tmp_path / "full", *ONE_BY_ONE]) == 0
    full = [json.loads(s) for s in capsys.readouterr().out.splitlines()]
    p = _start(["loops", "-", "--out", tmp_path / "a", *ONE_BY_ONE, "--state-out", tmp_path / "state.npz"])
    first, err = _feed_then_stop(p, paths[:40], sig)
    assert p.returncode == code, err
    assert err.strip().splitlines()[-1] == said
    assert len(first) == 40
    rows = _rows(tmp_path / "a")
    assert [int(r["query"]) for r in rows] == list(range(40))
    m = json.loads((tmp_path / "a" / "metrics.json").read_text())["methods"]["rshosm-seq"]
    assert m["frames"] == 40 and m["stopped"] is True
    assert not list(tmp_path.rglob(".*"))  # no temporary file or lock left
    monkeypatch.setattr("sys.stdin", io.StringIO("\n".join(paths[40:]) + "\n"))
    assert _main(["loops", "-", "--out", tmp_path / "b", "--resume", tmp_path / "state.npz"]) == 0
    rest = [json.loads(s) for s in capsys.readouterr().out.splitlines()]
    strip = [{k: v for k, v in r.items() if k != "latency_ms"} for r in first + rest]
    assert strip == [{k: v for k, v in r.items() if k != "latency_ms"} for r in full]


def test_stopped_localize_writes_its_outputs_and_state(laps, tmp_path):
    day = laps["laps"]
    assert _main(["learn", day, "--out", tmp_path / "map.npz", "--preset", "fast"]) == 0
    p = _start(["localize", tmp_path / "map.npz", "-", "--out", tmp_path / "a", "--state-out", tmp_path / "s.npz"])
    answers, err = _feed_then_stop(p, laps["paths"][:25], signal.SIGTERM, late=LOCALIZE_LAG)
    assert p.returncode == 143, err
    # each frame is answered LOCALIZE_LAG frames late: the last ones wait in the state, answered first on resuming
    n = 25 - LOCALIZE_LAG
    assert [a["query"] for a in answers] == list(range(n)) and len(_rows(tmp_path / "a")) == n
    assert f"{LOCALIZE_LAG} frames read" in err and "their answers come first" in err, err
    assert (tmp_path / "s.npz").is_file()
    assert json.loads((tmp_path / "a" / "metrics.json").read_text())["methods"]["rshosm-seq"]["stopped"] is True


def test_a_nul_byte_line_is_skipped_with_its_line_number(laps, tmp_path, capsys, monkeypatch):
    import io

    paths = laps["paths"][:30]
    text = "\n".join(paths[:10]) + "\nbad\x00line\n" + "\n".join(paths[10:]) + "\n"
    monkeypatch.setattr("sys.stdin", io.StringIO(text))
    assert _main(["loops", "-", "--out", tmp_path / "o", *LOOSE]) == 0
    err = capsys.readouterr().err
    assert "skipped stdin line 11: not a path (a NUL byte)" in err
    assert len(_rows(tmp_path / "o")) == 30


def test_binary_data_on_stdin_is_refused_naming_stdin(laps, tmp_path):
    png = Path(laps["paths"][0]).read_bytes()
    r = subprocess.run([sys.executable, "-m", "pipelines.cli", "loops", "-", "--out", str(tmp_path / "o"),
                        *LOOSE], input=png, capture_output=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    err = r.stderr.decode()
    assert r.returncode == 2 and len(err.strip().splitlines()) == 1, err
    assert "stdin: binary data" in err
    assert not (tmp_path / "o").exists()


def test_a_second_run_into_the_same_out_is_refused_while_the_first_runs(laps, tmp_path):
    assert _main(["learn", laps["laps"], "--out", tmp_path / "map.npz", "--preset", "fast"]) == 0
    first = _start(["localize", tmp_path / "map.npz", "-", "--out", tmp_path / "o", "--method-conf",
                    "rshosm-seq.lag=0"])
    first.stdin.write(laps["paths"][0] + "\n")
    first.stdin.flush()
    json.loads(first.stdout.readline())  # the first run has claimed --out
    second = subprocess.run([sys.executable, "-m", "pipelines.cli", "localize", str(tmp_path / "map.npz"),
                             laps["paths"][1].rsplit("/", 1)[0], "--out", str(tmp_path / "o"), "--max-frames", "3"],
                            capture_output=True, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    first.stdin.close()
    assert first.wait(timeout=60) == 0
    lines = second.stderr.strip().splitlines()
    assert second.returncode == 2 and len(lines) == 1, second.stderr
    assert "rshosm-seq: another run is writing it now" in lines[0]
    assert json.loads((tmp_path / "o" / "metrics.json").read_text())["methods"]["rshosm-seq"]["frames"] == 1


# ------------------------------------------------------------------ where a stop leaves a stream
def _stop_while_reading(monkeypatch, path: str) -> None:
    """A stop (Ctrl-C) that comes while ``path`` is being read: its line is read, the frame is not taken."""
    from vpr.sources.stdin import StdinSource

    read = StdinSource._read

    def reading(self, p, name):
        if name == path:
            raise KeyboardInterrupt
        return read(self, p, name)

    monkeypatch.setattr(StdinSource, "_read", reading)


def test_a_stop_while_a_frame_is_read_names_that_frames_line_to_go_on_from(laps, tmp_path, capsys, monkeypatch):
    import io

    paths = laps["paths"]
    _stop_while_reading(monkeypatch, paths[120])  # 120 frames answered, the 121st line read when the stop comes
    monkeypatch.setattr("sys.stdin", io.StringIO("\n".join(paths) + "\n"))
    assert _main(["loops", "-", "--out", tmp_path / "a", *LOOSE, "--state-out", tmp_path / "s.npz"]) == 130
    err = capsys.readouterr().err
    # the frames up to line 120 are answered, or wait in the state for the frames that confirm a closure
    waiting = json.loads((tmp_path / "a" / "metrics.json").read_text())["methods"]["rshosm-seq"].get("waiting", [])
    assert len(_rows(tmp_path / "a")) + len(waiting) == 120
    assert ("every frame up to input line 120 is answered in the outputs" in err) == (not waiting), err
    assert f"--resume {tmp_path / 's.npz'} with another --out and feed it from input line 121" in err
    monkeypatch.undo()
    monkeypatch.setattr("sys.stdin", io.StringIO("\n".join(paths[120:]) + "\n"))  # as the message says
    assert _main(["loops", "-", "--out", tmp_path / "b", "--resume", tmp_path / "s.npz"]) == 0
    done = [int(r["query"]) for f in ("a", "b") for r in _rows(tmp_path / f)]
    assert sorted(done) == list(range(len(paths)))  # every frame answered once


def test_a_resumed_run_is_scored_against_the_frames_in_its_state(laps, tmp_path, capsys, monkeypatch):
    import io

    paths, gt = laps["paths"], ["--gt", laps["gt"], "--radius", 4]
    monkeypatch.setattr("sys.stdin", io.StringIO("\n".join(paths) + "\n"))
    assert _main(["loops", "-", "--out", tmp_path / "whole", *LOOSE, *gt]) == 0
    monkeypatch.setattr("sys.stdin", io.StringIO("\n".join(paths[:120]) + "\n"))
    assert _main(["loops", "-", "--out", tmp_path / "a", *LOOSE, "--state-out", tmp_path / "s.npz"]) == 0
    monkeypatch.setattr("sys.stdin", io.StringIO("\n".join(paths[120:]) + "\n"))
    before = (tmp_path / "a" / "rshosm-seq" / "matches.csv").read_bytes()
    capsys.readouterr()
    assert _main(["loops", "-", "--out", tmp_path / "a", "--resume", tmp_path / "s.npz", *gt]) == 2  # the first part's
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "holds rshosm-seq's answers of an earlier run" in err and "another --out" in err
    assert (tmp_path / "a" / "rshosm-seq" / "matches.csv").read_bytes() == before
    monkeypatch.setattr("sys.stdin", io.StringIO("\n".join(paths[120:]) + "\n"))
    assert _main(["loops", "-", "--out", tmp_path / "b", "--resume", tmp_path / "s.npz", *gt]) == 0
    err = capsys.readouterr().err
    assert "no loop closure to find" not in err
    whole = {r["query"]: r for r in _rows(tmp_path / "whole")}
    resumed = _rows(tmp_path / "b")
    assert sum(r["accepted"] == "1" for r in resumed) > 50  # the laps after the first revisit frames of the first
    for r in resumed:  # each answer scored as in the run that was never stopped
        assert (r["best_db"], r["accepted"], r["right"], r["true_db"]) == \
            tuple(whole[r["query"]][k] for k in ("best_db", "accepted", "right", "true_db"))
    m = json.loads((tmp_path / "b" / "metrics.json").read_text())["methods"]["rshosm-seq"]
    right = [r for r in resumed if r["accepted"] == "1" and r["right"] != ""]
    assert m["precision_accepted"] == sum(r["right"] == "1" for r in right) / len(right)
    assert (tmp_path / "b" / "pr.png").is_file() and 'class="matrix"' in (tmp_path / "b" / "report.html").read_text()
    assert m["precision_accepted"] > 0.9 and m["n_false"] == sum(r["right"] == "0" for r in right)


def test_a_stopped_localize_says_how_to_go_on_with_its_state(laps, tmp_path, capsys, monkeypatch):
    import io

    assert _main(["learn", laps["laps"], "--out", tmp_path / "map.npz", "--preset", "fast"]) == 0
    paths = laps["paths"]
    _stop_while_reading(monkeypatch, paths[30])
    monkeypatch.setattr("sys.stdin", io.StringIO("\n".join(paths) + "\n"))
    assert _main(["localize", tmp_path / "map.npz", "-", "--out", tmp_path / "a", "--state-out",
                  tmp_path / "s.npz"]) == 130
    err = capsys.readouterr().err
    assert "--resume" not in err
    assert (f"{LOCALIZE_LAG} frames read ({paths[30 - LOCALIZE_LAG]} .. {paths[29]}) wait in "
            f"{tmp_path / 's.npz'} for later frames, not yet in the outputs: to continue, give {tmp_path / 's.npz'} as "
            f"the map (vpr localize {tmp_path / 's.npz'} QUERY) with another --out and feed it from input line 31; "
            "their answers come first") in err, err
    monkeypatch.undo()
    # into the stopped run's --out: refused in one line, its answers kept
    before = (tmp_path / "a" / "rshosm-seq" / "matches.csv").read_bytes()
    monkeypatch.setattr("sys.stdin", io.StringIO("\n".join(paths[30:]) + "\n"))
    assert _main(["localize", tmp_path / "s.npz", "-", "--out", tmp_path / "a"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "holds rshosm-seq's answers of an earlier run" in err and "another --out" in err
    assert (tmp_path / "a" / "rshosm-seq" / "matches.csv").read_bytes() == before
    monkeypatch.setattr("sys.stdin", io.StringIO("\n".join(paths[30:]) + "\n"))
    assert _main(["localize", tmp_path / "s.npz", "-", "--out", tmp_path / "b"]) == 0
    assert len(_rows(tmp_path / "a")) + len(_rows(tmp_path / "b")) == len(paths)
