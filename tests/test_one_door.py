"""Every method, batch and online, is reached by name through vpr.methods: a toy online method in one file
(``tests/toy_online.py``) plus one registry line runs through ``vpr loops -`` and ``vpr learn`` / ``vpr localize``."""
import csv
import io
import json

import pytest

from pipelines.cli import main
from vpr import methods


@pytest.fixture
def toy():
    methods.register("toy-online", "tests.toy_online", "ToyOnline")  # the one registry line
    yield "toy-online"
    methods.unregister("toy-online")


@pytest.fixture(scope="module")
def laps(scene_on_disk):
    s = scene_on_disk("loop_revisits", (48, 36), 120)
    return {"folder": s["laps"], "paths": sorted(str(p) for p in s["laps"].glob("*.png"))}


def _run(argv, capsys, monkeypatch, stdin=None):
    if stdin is not None:
        monkeypatch.setattr("sys.stdin", io.StringIO("\n".join(stdin) + "\n"))
    code = main([str(a) for a in argv] + ["--no-progress"])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def _rows(out, method):
    with open(out / method / "matches.csv", newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.slow
def test_a_toy_online_method_runs_through_the_online_commands(toy, laps, tmp_path, capsys, monkeypatch):
    assert toy in methods.available() and methods.get_class(toy).runs_online
    fast = ["--preset", "fast"]
    paths = laps["paths"]
    # vpr loops -: one JSON line per frame, its folder, its conf; stopped after 70 frames and resumed: the same
    code, out, err = _run(["loops", "-", "--method", toy, "--out", tmp_path / "whole", *fast], capsys, monkeypatch,
                          paths)
    assert code == 0, err
    whole = [json.loads(line) for line in out.splitlines()]
    assert len(whole) == len(paths) == len(_rows(tmp_path / "whole", toy))
    assert any(r["accepted"] for r in whole)  # the laps come back to their places
    m = json.loads((tmp_path / "whole" / "metrics.json").read_text())
    assert m["params"]["method"] == toy and m["params"]["method_conf"][toy]["min_share"] == 0.5
    code, first, err = _run(["loops", "-", "--method", toy, "--out", tmp_path / "a", "--state-out",
                             tmp_path / "s.npz", *fast], capsys, monkeypatch, paths[:70])
    assert code == 0, err
    code, rest, err = _run(["loops", "-", "--out", tmp_path / "b", "--resume", tmp_path / "s.npz"], capsys,
                           monkeypatch, paths[70:])
    assert code == 0, err
    both = [json.loads(line) for line in (first + rest).splitlines()]
    key = lambda r: (r["query"], r["best_db"], r["accepted"])  # noqa: E731
    assert [key(r) for r in both] == [key(r) for r in whole]
    # vpr learn --method, then vpr localize against the map: the method the map names answers
    code, _, err = _run(["learn", laps["folder"], "--method", toy, "--out", tmp_path / "map.npz", *fast], capsys,
                        monkeypatch)
    assert code == 0, err
    assert methods.load_map(tmp_path / "map.npz").method == toy
    code, out, err = _run(["localize", tmp_path / "map.npz", laps["folder"], "--out", tmp_path / "loc",
                           "--tolerance", 1], capsys, monkeypatch)
    assert code == 0, err
    lines = [json.loads(line) for line in out.splitlines()]
    assert len(lines) == len(paths) == len(_rows(tmp_path / "loc", toy))
    # its own frames against the map of them: each answers itself once the query statistics have settled
    assert sum(r["best_db"] == r["query"] for r in lines[20:]) >= 0.9 * len(lines[20:])
    m = json.loads((tmp_path / "loc" / "metrics.json").read_text())["methods"][toy]
    assert m["recall_at_1"] >= 0.9
