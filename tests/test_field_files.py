"""The files the field's tools read: each query's top N (CSV), hloc's pairs file, a MATLAB .mat."""
import csv

import numpy as np
import pytest
import scipy.io

from pipelines.cli import main
from tests.reference import hloc_pairs


def _ranked_files(argv, tmp_path, capsys):
    """Run ``vpr ARGV`` (its --out tmp_path/o); (rshosm-seq's folder, its top.csv rows, each query's best_db)."""
    assert main([str(a) for a in argv]) == 0, capsys.readouterr().err
    folder = tmp_path / "o" / "rshosm-seq"
    with open(folder / "top.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    with open(folder / "matches.csv", newline="") as fh:
        best = {r["query"]: r["best_db"] for r in csv.DictReader(fh)}
    return folder, rows, best


@pytest.mark.slow
def test_top_n_hloc_pairs_and_mat_of_a_compare(scene_on_disk, tmp_path, capsys):
    s = scene_on_disk("two_seasons", (48, 32), 60)
    db, q = s[s["names"][0]], s[s["names"][1]]
    argv = ["compare", db, q, "--tolerance", 2, "--preset", "fast", "--methods", "rshosm-seq,pairwise", "--top", 7,
            "--pairs", 5, "--mat", "--out", tmp_path / "o", "--no-progress"]
    folder, rows, best = _ranked_files(argv, tmp_path, capsys)
    assert len(rows) == 60 * 7 and {r["rank"] for r in rows} == {str(k) for k in range(1, 8)}
    for r in rows:  # rank 1 is the best match; scores fall with the rank
        if r["rank"] == "1":
            assert r["db"] == best[r["query"]]
    for qn in {r["query"] for r in rows}:
        scores = [float(r["score"]) for r in rows if r["query"] == qn]
        assert scores == sorted(scores, reverse=True)
    # hloc's parsing rule: one pair a line, names of the folders' images, 5 a query, the top.csv's first five
    pairs = hloc_pairs(folder / "pairs-query-rshosm-seq5.txt")
    db_names, q_names = {p.name for p in db.glob("*.png")}, {p.name for p in q.glob("*.png")}
    assert set(pairs) == q_names and all(len(v) == 5 and set(v) <= db_names for v in pairs.values())
    first = next(iter(pairs))
    assert pairs[first] == [r["db_name"] for r in rows if r["query_name"] == first][:5]
    m = scipy.io.loadmat(folder / "similarity.mat")
    S = np.load(folder / "similarity.npy")
    np.testing.assert_allclose(m["S"], S, rtol=1e-6)
    assert m["best"].ravel().tolist() == [int(best[str(j)]) + 1 if int(best[str(j)]) >= 0 else 0 for j in range(60)]
    # refused: a negative count, in one line, nothing written
    argv[argv.index("--top") + 1] = -1
    argv[argv.index("--out") + 1] = tmp_path / "bad"
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--top -1" in err and not (tmp_path / "bad").exists()


@pytest.mark.slow
def test_localize_writes_the_top_n_hloc_pairs_and_mat_of_its_answers(scene_on_disk, tmp_path, capsys):
    s = scene_on_disk("two_seasons", (48, 32), 60)
    db, q = s[s["names"][0]], s[s["names"][1]]
    argv = ["localize", db, q, "--preset", "fast", "--top", 4, "--pairs", 3, "--mat", "--out", tmp_path / "o",
            "--no-progress"]
    folder, rows, best = _ranked_files(argv, tmp_path, capsys)
    assert {r["rank"] for r in rows} == {"1", "2", "3", "4"}
    assert all(r["db"] == best[r["query"]] for r in rows if r["rank"] == "1")  # rank 1: the frame's answer
    pairs = hloc_pairs(folder / "pairs-query-rshosm-seq3.txt")
    db_names = {p.name for p in db.glob("*.png")}
    assert set(pairs) == {p.name for p in q.glob("*.png")} and all(len(v) == 3 and set(v) <= db_names
                                                                  for v in pairs.values())
    m = scipy.io.loadmat(folder / "similarity.mat")
    assert m["S"].shape == (60, 60) and m["best"].ravel().tolist() == [int(best[str(j)]) + 1 for j in range(60)]
    capsys.readouterr()
    argv[argv.index("--pairs") + 1] = -2
    argv[argv.index("--out") + 1] = tmp_path / "bad"
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--pairs -2" in err and not (tmp_path / "bad").exists()


def test_a_folder_of_subfolders_is_read_through_them(tmp_path):
    import cv2

    from vpr.sources import open_source

    img = np.zeros((8, 8, 3), np.uint8)
    for sub, names in (("000", ["b@1@2@.jpg", "a@1@2@.jpg"]), ("001", ["c@1@2@.jpg"])):
        (tmp_path / "db" / sub).mkdir(parents=True)
        for n in names:
            cv2.imwrite(str(tmp_path / "db" / sub / n), img)
    with pytest.warns(UserWarning, match="no images of its own; the 3 in its subfolders are read"):
        src = open_source(tmp_path / "db")
    assert src.names() == ["000/a@1@2@.jpg", "000/b@1@2@.jpg", "001/c@1@2@.jpg"]
    assert [f.name for f in src] == src.names()
    # a dataset's test folder holds the two traverses: refused, naming both
    for sub in ("database", "queries"):
        (tmp_path / "test" / sub).mkdir(parents=True)
        cv2.imwrite(str(tmp_path / "test" / sub / "x.jpg"), img)
    with pytest.raises(ValueError, match="holds database/ and queries/, two traverses"):
        open_source(tmp_path / "test")


@pytest.mark.slow
def test_loops_write_the_streams_sequential_and_loop_pairs(scene_on_disk, tmp_path, capsys, monkeypatch):
    import io

    s = scene_on_disk("loop_revisits", (48, 36), 240)
    argv = ["loops", s["laps"], "--pairs", 2, "--top", 3, "--mat", "--preset", "fast", "--out", tmp_path / "o",
            "--no-progress"]
    assert main([str(a) for a in argv]) == 0, capsys.readouterr().err
    folder = tmp_path / "o" / "rshosm-seq"
    with open(folder / "matches.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    names = [r["query_name"] for r in rows]
    with open(folder / "top.csv", newline="") as fh:  # each frame's 3 best earlier frames by the similarity
        top = list(csv.DictReader(fh))
    assert top and all(int(r["db"]) < int(r["query"]) and r["rank"] in ("1", "2", "3") for r in top)
    for qn in {r["query"] for r in top}:
        scores = [float(r["score"]) for r in top if r["query"] == qn]
        assert scores == sorted(scores, reverse=True)
    assert scipy.io.loadmat(folder / "similarity.mat")["S"].shape == (len(rows), len(rows))
    pairs = {(a, b) for a, rs in hloc_pairs(folder / "pairs-sequential2-loops.txt").items() for b in rs}
    sequential = {(names[j], names[k]) for j in range(len(names)) for k in (j + 1, j + 2) if k < len(names)}
    closures = {(r["db_name"], r["query_name"]) for r in rows if r["accepted"] == "1"}
    assert closures and pairs == sequential | closures
    monkeypatch.setattr("sys.stdin", io.StringIO(""))
    assert main(["loops", "-", "--pairs", "2", "--out", str(tmp_path / "online")]) == 2
    assert "--pairs" in capsys.readouterr().err and not (tmp_path / "online").exists()
    assert main(["loops", "-", "--mat", "--out", str(tmp_path / "online")]) == 2
    assert "--mat" in capsys.readouterr().err and not (tmp_path / "online").exists()
