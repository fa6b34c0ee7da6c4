"""Settings that must agree do, or are refused before any work: the memory reads the encoder's SDR width, a pairs
file is named for what it holds, and a run says nothing of what was not asked."""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from pipelines.cli import main
from tests import gt_routes as g
from tests.cli import one_error_line, run
from vpr import methods


def test_the_memory_reads_the_encoders_width():
    built = methods.build(["rshosm-seq", "rshosm", "pairwise"], {}, sdr_bits=4096, encoder="--encoder pixel")
    assert built["rshosm-seq"].conf["n_inputs"] == 4096 and built["rshosm"].conf["n_inputs"] == 4096
    assert "n_inputs" not in built["pairwise"].conf
    assert methods.get_online("rshosm-seq", sdr_bits=1024).conf["n_inputs"] == 1024
    # given alike: kept; given otherwise: refused naming both settings and the fix
    assert methods.build(["rshosm-seq"], {"rshosm-seq": {"n_inputs": "4096"}}, sdr_bits=4096)["rshosm-seq"]
    with pytest.raises(ValueError, match=r"rshosm-seq.n_inputs=2048: --encoder pixel makes SDRs of 4096 bits.*leave "
                                         r"n_inputs out.*--encoder-conf n_bits=2048"):
        methods.build(["rshosm-seq"], {"rshosm-seq": {"n_inputs": 2048}}, sdr_bits=4096, encoder="--encoder pixel")
    with pytest.raises(ValueError, match="n_inputs"):  # a value that is no number: the conf's own refusal
        methods.build(["rshosm-seq"], {"rshosm-seq": {"n_inputs": "many"}}, sdr_bits=4096)


@pytest.fixture(scope="module")
def traverses(tmp_path_factory):
    root = tmp_path_factory.mktemp("agree")
    return {role: g.write_route("folder", root, role, g.images(role), g.positions(role))[0] for role in ("db", "query")}


@pytest.mark.slow
@pytest.mark.parametrize("command", ["match", "loops", "learn"])
def test_an_encoders_width_runs_the_memory_or_is_refused_writing_nothing(command, traverses, tmp_path, capsys):
    db, q = traverses["db"], traverses["query"]
    inputs = {"match": [db, q], "loops": [db, "--exclude", 10], "learn": [db]}[command]
    out = tmp_path / ("map.npz" if command == "learn" else "o")
    wide = ["--preset", "fast", "--encoder-conf", "n_bits=4096"]
    code, _, err = run([command, *inputs, "--out", out, *wide], capsys)
    assert code == 0, err
    if command == "learn":
        code, _, err = run(["localize", out, q, "--out", tmp_path / "loc"], capsys)
        assert code == 0, err
        conf = json.loads((tmp_path / "loc" / "metrics.json").read_text())["params"]["method_conf"]
    else:
        conf = json.loads((out / "metrics.json").read_text())["params"]["method_conf"]
    assert conf["rshosm-seq"]["n_inputs"] == 4096
    refused = tmp_path / ("refused.npz" if command == "learn" else "refused")
    code, _, err = run([command, *inputs, "--out", refused, *wide, "--method-conf", "rshosm-seq.n_inputs=2048"],
                       capsys)
    one_error_line(code, err, "n_inputs=2048", "4096 bits", "--encoder-conf n_bits=2048")
    assert not refused.exists()  # no outputs, no encoding cache


@pytest.mark.slow
def test_a_pairs_file_beyond_the_database_is_refused_before_any_work(traverses, tmp_path, capsys):
    for command in ("match", "localize"):
        out = tmp_path / command
        code, _, err = run([command, traverses["db"], traverses["query"], "--out", out, "--preset", "fast",
                            "--pairs", 400], capsys)
        one_error_line(code, err, "--pairs 400", f"database's {g.N_DB} frames", f"at most {g.N_DB}")
        assert not out.exists()


@pytest.mark.slow
def test_a_run_over_descriptors_says_nothing_unasked(tmp_path, capsys):
    rows = {role: np.stack([im[:, :, 0].ravel() for im in g.images(role)]).astype(np.float32)
            for role in ("db", "query")}
    for role, a in rows.items():
        np.save(tmp_path / f"{role}.npy", a)
    runs = (["match", tmp_path / "db.npy", tmp_path / "query.npy"], ["loops", tmp_path / "db.npy", "--exclude", 10])
    for argv in runs:
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            code = main([str(a) for a in [*argv, "--out", tmp_path / argv[0], "--no-progress"]])
        err = capsys.readouterr().err
        assert code == 0, err
        assert not [str(w.message) for w in said if "--method-conf" in str(w.message)]
        assert "--method-conf" not in err


def test_every_input_and_the_help_name_descriptor_files(capsys):
    for command in ("match", "compare", "loops", "learn", "localize", "encode"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        assert ".npy" in text and ".h5" in text, command


@pytest.mark.slow
def test_localize_prints_its_metrics_with_recall_at_n(traverses, tmp_path, capsys):
    gt = g.db_query_gt("pairs", tmp_path, "folder", {})
    code, out, err = run(["localize", traverses["db"], traverses["query"], "--out", tmp_path / "o", "--preset",
                          "fast", *gt], capsys)
    assert code == 0, err
    assert len(out.splitlines()) == g.N_Q  # stdout: a JSON line a frame, the table on stderr
    assert "R@1" in err and "Recall@N over every query" in err and "R@20" in err
