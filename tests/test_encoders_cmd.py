"""vpr encoders list / test (pipelines.scenes, pipelines/encoders_cmd.py) on tiny renders."""
import argparse
import json

import numpy as np
import pytest

from pipelines import encoders_cmd as E
from pipelines.scenes import METHODS, EncoderTest, average_precision, list_encoders


def _parse(argv):
    ap = argparse.ArgumentParser()
    E.add_arguments(ap, "encoders")
    return ap.parse_args(argv)


def test_list_names_every_encoder_with_its_defaults(capsys):
    confs = list_encoders()
    assert {"pixel", "projection", "orb", "cnn"} <= set(confs)
    assert confs["pixel"]["k"] == 40 and confs["pixel"]["standardise"] == "none"
    assert E.run_command(_parse(["list"])) == 0
    out = capsys.readouterr().out
    encoders_part, _, rest = out.partition("\n\n")
    assert [line.split()[0] for line in encoders_part.splitlines()] == list(confs)
    # how to join them and the presets: the names a newcomer passes to --encoder / --preset
    assert "pixel+cnn" in rest and all(f"  {p} " in rest for p in ("default", "paper", "fast"))


def test_average_precision_leaves_out_soft_and_masked_pairs():
    S = np.array([[0.9, 0.7], [0.8, 0.1]])
    hard = np.eye(2, dtype=bool)
    # ranking 0.9 (true), 0.8 (false), 0.7 (false), 0.1 (true): AP = (1/1 + 2/4) / 2
    assert average_precision(S, hard) == pytest.approx(0.75)
    soft = hard | np.array([[False, False], [True, False]])
    assert average_precision(S, hard, soft) == pytest.approx((1 + 2 / 3) / 2)
    mask = np.array([[True, False], [False, True]])
    assert average_precision(S, hard, mask=mask) == pytest.approx(1.0)


def test_test_command_scores_every_condition_pair(tmp_path, capsys):
    out = tmp_path / "enc"
    code = E.run_command(_parse(["test", "--encoder", "pixel", "--encoder-conf", "standardise=fit",
                                 "--scenes", "two_seasons", "--size", "48x32", "--frames", "30", "--out", str(out)]))
    assert code == 0
    printed = capsys.readouterr().out
    doc = json.loads((out / "metrics.json").read_text())
    assert (out / "metrics.png").stat().st_size > 0
    assert doc["encoder"] == "pixel" and doc["conf"]["standardise"] == "fit" and doc["fit_per_traverse"]
    pairs = {(r["db"], r["query"]) for r in doc["rows"]}
    assert pairs == {("summer_day", "winter_night"), ("winter_night", "summer_day")}
    for r in doc["rows"]:
        assert r["n_db"] == r["n_query"] == 30
        for m in METHODS:
            assert 0.0 <= r[m]["ap"] <= 1.0 and 0.0 <= r[m]["recall_at_1"] <= 1.0
        assert f"{r['rshosm-seq']['ap']:.3f}" in printed
    assert "summer_day -> winter_night" in printed


def test_test_command_names_bad_input(tmp_path, capsys):
    assert E.run_command(_parse(["test", "--encoder", "nope", "--out", str(tmp_path)])) == 2
    assert "nope" in capsys.readouterr().err
    assert E.run_command(_parse(["test", "--encoder", "pixel", "--encoder-conf", "bogus=1", "--scenes",
                                 "two_seasons", "--out", str(tmp_path)])) == 2
    assert "bogus" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        _parse(["test", "--encoder", "pixel", "--size", "8x8", "--out", str(tmp_path)])
    with pytest.raises(ValueError, match="frames"):
        EncoderTest("pixel", tmp_path, n_frames=1)
