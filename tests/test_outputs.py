"""One output schema for every command: each command's ``matches.csv`` and ``metrics.json`` read by one reader."""
import csv
import io
import json
from pathlib import Path

import pytest

from pipelines.cli import main
from pipelines.outputs import MATCH_COLUMNS

pytestmark = pytest.mark.slow  # every command through the command line

N_FRAMES = 24
FAST = ["--preset", "fast", "--no-progress"]


def read_outputs(out: Path) -> tuple[dict, dict]:
    """(metrics.json, {method: matches.csv rows}) of any command's ``--out``, checked against the one schema."""
    metrics = json.loads((out / "metrics.json").read_text(encoding="utf-8"))
    assert {"methods", "params", "versions"} <= set(metrics), set(metrics)
    rows = {}
    for method, m in metrics["methods"].items():
        if method.endswith("+verify"):
            continue  # the verified twin shares its method's folder
        raw = (out / method / "matches.csv").read_bytes()
        assert b"\r" not in raw
        reader = csv.DictReader(io.StringIO(raw.decode("utf-8")))
        assert tuple(reader.fieldnames[:len(MATCH_COLUMNS)]) == MATCH_COLUMNS, reader.fieldnames
        rows[method] = list(reader)
        assert isinstance(m["seconds"], float) and isinstance(m["n_accepted"], int)
        assert m["n_accepted"] == sum(r["accepted"] == "1" for r in rows[method])
        for r in rows[method]:
            assert int(r["best_db"]) >= -1 and (r["db_name"] == "") == (int(r["best_db"]) < 0)
        assert method in metrics["params"].get("method_conf", {}), metrics["params"].keys()
    return metrics, rows


@pytest.fixture(scope="module")
def scene(scene_on_disk):
    s = scene_on_disk("two_seasons", (48, 32), N_FRAMES)
    return {"db": s[s["names"][0]], "q": s[s["names"][1]], "gt": s["gt"]}


def _run(argv, capsys, stdin=None, monkeypatch=None):
    if stdin is not None:
        monkeypatch.setattr("sys.stdin", io.StringIO(stdin))
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert code == 0, err
    return out


def test_every_command_writes_the_one_schema(scene, tmp_path, capsys, monkeypatch):
    db, q = scene["db"], scene["q"]
    gt = ["--gt", scene["gt"], "--radius", "3"]
    paths = "\n".join(str(p) for p in sorted(Path(q).glob("*.png"))) + "\n"
    _run(["compare", db, q, "--out", tmp_path / "compare", *FAST, *gt], capsys)
    _run(["match", db, q, "--out", tmp_path / "match", *FAST, *gt], capsys)
    _run(["loops", q, "--out", tmp_path / "loops", "--exclude", "12", *FAST], capsys)
    lines = _run(["loops", "-", "--out", tmp_path / "online", "--exclude", "12", *FAST], capsys, paths, monkeypatch)
    _run(["learn", db, "--out", tmp_path / "map.npz", *FAST], capsys)
    located = _run(["localize", tmp_path / "map.npz", "-", "--out", tmp_path / "localize", "--no-progress"], capsys,
                   paths, monkeypatch)
    seen = {}
    for name in ("compare", "match", "loops", "online", "localize"):
        metrics, rows = read_outputs(tmp_path / name)
        seen[name] = set(rows)
        for method_rows in rows.values():
            assert len(method_rows) == N_FRAMES
    assert seen["compare"] == {"rshosm-seq", "seqslam", "seqslam-desc", "pairwise"}
    assert seen["match"] == seen["loops"] == seen["online"] == seen["localize"] == {"rshosm-seq"}
    # the JSON lines of the online commands carry the same fields as matches.csv, in the same order
    for text, name in ((lines, "online"), (located, "localize")):
        first = json.loads(text.splitlines()[0])
        assert tuple(first)[:len(MATCH_COLUMNS)] == MATCH_COLUMNS
        _, rows = read_outputs(tmp_path / name)
        assert [json.loads(s)["query_name"] for s in text.splitlines()] == \
            [r["query_name"] for r in rows["rshosm-seq"]]
