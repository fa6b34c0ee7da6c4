"""Tests of vpr.config: the one configuration helper of encoders, methods, descriptors and the verifier."""
import pytest

from vpr.config import coerce_value, merge_conf, parse_key_values

DEFAULTS = {"k": 40, "ratio": 0.8, "fit": False, "size": (64, 32), "name": "pixel", "extra": {}, "model": None,
            "stay": 0.05}


def test_merge_coerces_strings_to_the_defaults_types():
    c = merge_conf(DEFAULTS, {"k": "20", "ratio": "1", "fit": "yes", "size": "[32, 16]", "name": "hog",
                              "extra": '{"a": 1}', "model": "3.5"}, "test")
    assert c == {"k": 20, "ratio": 1.0, "fit": True, "size": (32, 16), "name": "hog", "extra": {"a": 1},
                 "model": 3.5, "stay": 0.05}
    assert type(c["ratio"]) is float and type(c["size"]) is tuple
    # a None default has no type: strings are read as scalars, other values pass as they are
    assert merge_conf(DEFAULTS, {"model": "none"}, "test")["model"] is None
    assert merge_conf(DEFAULTS, {"model": [1, 2]}, "test")["model"] == [1, 2]


def test_merge_copies_defaults_and_leaves_them_alone():
    a = merge_conf(DEFAULTS, None, "test")
    a["extra"]["x"] = 1
    assert DEFAULTS["extra"] == {} and merge_conf(DEFAULTS, {}, "test")["extra"] == {}


def test_unknown_keys_are_listed_with_the_valid_ones():
    with pytest.raises(ValueError, match=r"unknown rshosm-seq option\(s\) \['foo', 'zz'\]; valid: \['extra', 'fit'"):
        merge_conf(DEFAULTS, {"foo": 1, "zz": 2, "k": 3}, "rshosm-seq")


@pytest.mark.parametrize("key,value", [("k", "2.5"), ("k", True), ("fit", "maybe"), ("fit", 2), ("ratio", "x"),
                                       ("name", 3), ("extra", "[1]"), ("stay", None)])
def test_values_that_are_not_the_defaults_type_are_refused(key, value):
    with pytest.raises(ValueError, match=f"test: conf '{key}': cannot read"):
        merge_conf(DEFAULTS, {key: value}, "test")


def test_nullable_keys_accept_none_and_its_spelling():
    for v in (None, "none", "None", "null"):
        assert merge_conf(DEFAULTS, {"stay": v}, "test", nullable=("stay",))["stay"] is None
    assert merge_conf(DEFAULTS, {"stay": "0.2"}, "test", nullable=("stay",))["stay"] == 0.2


def test_coerce_value_bools_and_numbers():
    assert coerce_value("b", "0", True) is False and coerce_value("b", 1, False) is True
    assert coerce_value("n", 3.0, 1) == 3 and coerce_value("n", "1e3", 1) == 1000
    assert coerce_value("t", "1, 2", (0, 0)) == (1, 2) and coerce_value("t", "a,3", ()) == ("a", 3)


def test_parse_key_values_names_the_flag():
    assert parse_key_values(["k=40", " name =a=b", "empty="], "--x-conf") == {"k": "40", "name": "a=b", "empty": ""}
    assert parse_key_values(None, "--x-conf") == {}
    for bad in ("k", "=3"):
        with pytest.raises(ValueError, match=f"--x-conf: expected key=value, got '{bad}'"):
            parse_key_values([bad], "--x-conf")


def test_a_key_taken_out_is_refused_naming_why_and_dropped_unset():
    from vpr import methods
    from vpr.shosm import RshosmSeqConf

    # a saved map or detector state holds it unset: read as before
    assert "place_frames" not in RshosmSeqConf.build({"place_frames": None, "decay": 0.8}).flat()
    for build in (lambda: RshosmSeqConf.build({"place_frames": 20}), lambda: methods.get("rshosm-seq", place_frames=0)):
        with pytest.raises(ValueError, match="place_frames was taken out: closures are no longer placed"):
            build()
