"""Presets: the data, resolve() with flags over a preset, and the --preset plumbing of the commands."""
import argparse
import json

import pytest

import encoders
from pipelines import demo, encode, loops, match
from pipelines.args import options_from_args, settings_from_args
from vpr import methods, presets


def test_presets_are_complete_and_build():
    assert presets.available()[0] == presets.DEFAULT == "default"
    assert {"default", "paper", "fast"} <= set(presets.available())
    for name in presets.available():
        p = presets.get(name)
        assert p["methods"] and p["loop_method"]
        enc = encoders.get(p["encoder"], **p["encoder_conf"])  # every conf key exists and has the right type
        for key, value in p["encoder_conf"].items():
            assert enc.conf[key] == value
        # every method is registered, except seqslam-desc while it is being added on another branch
        assert set(p["methods"]) - set(methods.available()) <= {"seqslam-desc"}
        for m, conf in p["method_conf"].items():
            assert methods.get(m, **conf).conf.items() >= conf.items()
        methods.get(p["loop_method"])


def test_the_three_presets():
    d, paper, fast = presets.get("default"), presets.get("paper"), presets.get("fast")
    assert d["methods"][0] == "rshosm-seq" and {"seqslam", "seqslam-desc", "pairwise"} <= set(d["methods"])
    assert d["encoder"] == "pixel+cnn" and d["loop_method"] == "rshosm-seq"
    assert paper["encoder"] == "pixel" and paper["encoder_conf"]["k"] == 40 and paper["encoder_conf"]["n_bits"] == 2048
    assert paper["method_conf"]["rshosm"] == {"p_extra": 0.05} and paper["loop_method"] == "rshosm"
    assert "cnn" not in fast["encoder"] and fast["encoder_conf"] == {"k": 200, "standardise": "fit"}


def test_get_returns_a_copy_and_rejects_unknown_names():
    p = presets.get("paper")
    p["method_conf"]["rshosm"]["p_extra"] = 1.0
    p["methods"].append("x")
    assert presets.PRESETS["paper"]["method_conf"]["rshosm"]["p_extra"] == 0.05
    assert "x" not in presets.PRESETS["paper"]["methods"]
    with pytest.raises(ValueError, match="unknown preset 'nope'.*default"):
        presets.get("nope")
    with pytest.raises(ValueError, match="nope"):
        presets.resolve("nope")


def test_resolve_without_flags_is_the_preset():
    for name in presets.available():
        s = presets.resolve(name)
        p = presets.PRESETS[name]
        assert s == {"preset": name, "encoder": p["encoder"], "encoder_conf": p["encoder_conf"],
                     "methods": p["methods"], "method_conf": p["method_conf"], "loop_method": p["loop_method"]}
    assert presets.resolve(None)["preset"] == "default"
    s = presets.resolve()
    s["encoder_conf"]["pixel.k"] = 1
    s["methods"].clear()
    assert presets.PRESETS["default"]["encoder_conf"]["pixel.k"] == 150 and presets.PRESETS["default"]["methods"]


def test_encoder_conf_merges_only_over_the_presets_own_encoder():
    s = presets.resolve("fast", encoder_conf={"k": "100"})
    assert s["encoder"] == "pixel" and s["encoder_conf"] == {"k": "100", "standardise": "fit"}
    s = presets.resolve("fast", encoder="pixel", encoder_conf={"n_bits": 1024})
    assert s["encoder_conf"] == {"k": 200, "standardise": "fit", "n_bits": 1024}
    # another encoder: the preset's conf belongs to the preset's encoder and is dropped
    s = presets.resolve("default", encoder="pixel")
    assert s["encoder"] == "pixel" and s["encoder_conf"] == {}
    s = presets.resolve("default", encoder="cnn", encoder_conf={"k": 200})
    assert s["encoder_conf"] == {"k": 200}
    assert s["methods"] == presets.PRESETS["default"]["methods"]


def test_methods_replace_and_method_confs_merge():
    s = presets.resolve("paper", methods=["rshosm", "seqslam"], method_conf={"rshosm": {"threshold": "0.3"}})
    assert s["methods"] == ["rshosm", "seqslam"] and s["encoder"] == "pixel"
    assert s["method_conf"] == {"rshosm": {"p_extra": 0.05, "threshold": "0.3"}}
    # explicit conf wins over the preset's, key by key
    s = presets.resolve("paper", method_conf={"rshosm": {"p_extra": "0.1"}, "seqslam": {"ds": "5"}})
    assert s["method_conf"] == {"rshosm": {"p_extra": "0.1"}, "seqslam": {"ds": "5"}}
    # the preset's conf of a method the run does not use is dropped, unless it is the loop method
    assert "rshosm" in presets.resolve("paper", methods=["pairwise"])["method_conf"]
    assert presets.resolve("fast", methods=["pairwise"], method_conf={"seqslam": {"ds": 3}})["method_conf"] == {
        "seqslam": {"ds": 3}}


@pytest.mark.parametrize("kwargs", [{"methods": []}, {"methods": ["ok", ""]}, {"methods": [3]},
                                    {"encoder_conf": ["k=1"]}, {"method_conf": {"rshosm": 1}}])
def test_resolve_rejects_bad_arguments(kwargs):
    with pytest.raises(ValueError):
        presets.resolve("default", **kwargs)


def run_options(args):
    return options_from_args(args)


def _args(command, argv):
    ap = argparse.ArgumentParser()
    (loops if command == "loops" else match).add_arguments(ap, command)
    args = ap.parse_args(argv)
    args.command = command
    return args


def test_commands_without_flags_take_the_default_preset():
    d = presets.PRESETS["default"]
    args = _args("compare", ["db", "q", "--out", "o"])
    # not given stays None (so that a command can tell a flag given from one not given); resolved to default
    assert args.encoder is None and args.methods is None and args.preset is None
    opts = run_options(args)
    assert (opts.preset, opts.encoder, opts.encoder_conf) == ("default", d["encoder"], d["encoder_conf"])
    assert settings_from_args(args)["methods"] == d["methods"]
    assert settings_from_args(_args("match", ["db", "q", "--out", "o"]))["methods"] == [d["methods"][0]]
    assert settings_from_args(_args("loops", ["s", "--out", "o"]))["methods"] == [d["loop_method"]]
    paper = _args("loops", ["s", "--out", "o", "--preset", "paper"])
    assert settings_from_args(paper)["methods"] == ["rshosm"]
    assert run_options(paper).method_conf == {"rshosm": {"p_extra": 0.05}}


def test_flags_override_the_preset_on_the_command_line():
    args = _args("compare", ["db", "q", "--out", "o", "--preset", "fast", "--methods", "pairwise,rshosm",
                             "--encoder-conf", "k=50", "--method-conf", "rshosm.p_extra=0"])
    s = settings_from_args(args)
    assert s["methods"] == ["pairwise", "rshosm"] and s["encoder"] == "pixel"
    assert s["encoder_conf"] == {"k": "50", "standardise": "fit"} and s["method_conf"] == {"rshosm": {"p_extra": "0"}}
    s = settings_from_args(_args("match", ["db", "q", "--out", "o", "--encoder", "cnn", "--method", "seqslam"]))
    assert (s["encoder"], s["encoder_conf"], s["methods"]) == ("cnn", {}, ["seqslam"])
    with pytest.raises(ValueError, match="empty"):
        settings_from_args(_args("compare", ["db", "q", "--out", "o", "--methods", ","]))
    with pytest.raises(SystemExit):
        _args("compare", ["db", "q", "--out", "o", "--preset", "nope"])


def test_encode_and_demo_take_the_preset():
    ap = argparse.ArgumentParser()
    encode.add_arguments(ap)
    args = ap.parse_args(["src", "--cache", "c", "--preset", "fast"])
    assert args.preset == "fast" and args.encoder is None
    ap = argparse.ArgumentParser()
    demo.add_arguments(ap)
    args = ap.parse_args(["--out", "o"])
    assert (args.preset, args.encoder, args.methods, args.encoder_conf) == (None, None, None, None)


@pytest.mark.slow  # command-line integration
def test_config_json_records_the_resolved_settings(tmp_path):
    from vpr.render import write_scene

    res = write_scene("two_seasons", tmp_path / "scene", size=(48, 36), n_frames=20, progress=False)
    db, q = (res["traverses"][n]["folder"] for n in list(res["traverses"])[:2])
    args = _args("compare", [str(db), str(q), "--out", str(tmp_path / "out"), "--preset", "paper",
                             "--methods", "rshosm,pairwise", "--no-progress"])
    assert match.run_command(args) == 0
    for m in ("rshosm", "pairwise"):  # one folder per method, each with the run's config
        config = json.loads((tmp_path / "out" / m / "config.json").read_text())
        assert config["preset"] == "paper" and config["methods"] == ["rshosm", "pairwise"]
        assert config["encoder"] == "pixel" and config["encoder_conf"] == presets.PRESETS["paper"]["encoder_conf"]
        assert config["method_conf"] == {"rshosm": {"p_extra": 0.05}}
    params = json.loads((tmp_path / "out" / "metrics.json").read_text())["params"]
    assert params["preset"] == "paper" and params["encoder_conf"]["k"] == 40
    assert params["method_conf"]["rshosm"]["p_extra"] == 0.05


def test_loops_standardise_causally_unless_told_otherwise():
    for name, p in presets.PRESETS.items():
        s = presets.resolve(name, loops=True)
        assert s["encoder_conf"] == {**p["encoder_conf"], **p["loop_encoder_conf"]}
    assert presets.resolve("default", loops=True)["encoder_conf"]["standardise"] == "causal"
    assert presets.resolve("paper", loops=True)["encoder_conf"]["standardise"] == "none"
    assert presets.resolve("default")["encoder_conf"]["standardise"] == "fit"
    s = settings_from_args(_args("loops", ["s", "--out", "o", "--encoder-conf", "standardise=fit"]))
    assert s["encoder_conf"]["standardise"] == "fit"
    assert run_options(_args("loops", ["s", "--out", "o"])).encoder_conf["standardise"] == "causal"
    # another encoder than the preset's takes only the conf given
    s = settings_from_args(_args("loops", ["s", "--out", "o", "--encoder", "orb"]))
    assert s["encoder_conf"] == {}
