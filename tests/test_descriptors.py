"""Global descriptors computed elsewhere as an input: .npy (N x D) and hloc's global-feature .h5."""
import json

import h5py
import numpy as np
import pytest

from pipelines.cli import main
from vpr.sources import DescriptorSource, open_source, read_descriptors


def _h5(path, names, rows):
    with h5py.File(path, "w") as f:
        for name, row in zip(names, rows, strict=True):
            f.create_group(name).create_dataset("global_descriptor", data=row)
    return path


def test_descriptor_files_read_as_sources(tmp_path):
    rows = np.arange(12, dtype=np.float32).reshape(4, 3)
    np.save(tmp_path / "d.npy", rows)
    src = open_source(tmp_path / "d.npy", step=2)
    assert isinstance(src, DescriptorSource) and not src.has_images and src.dim == 3
    assert src.names() == ["000000", "000002"] and src.exact_total() == 4
    frames = list(src)
    np.testing.assert_array_equal(frames[1].image, rows[2])
    # hloc: names kept (nested groups are folders), in natural order as a folder's
    names = ["db/img10.jpg", "db/img2.jpg", "db/img1.jpg", "db/img3.jpg"]
    _h5(tmp_path / "g.h5", names, rows)
    got_names, got = read_descriptors(tmp_path / "g.h5")
    assert got_names == ["db/img1.jpg", "db/img2.jpg", "db/img3.jpg", "db/img10.jpg"]
    np.testing.assert_array_equal(got, rows[[2, 1, 3, 0]])


@pytest.fixture(scope="module")
def described(scene_on_disk, tmp_path_factory):
    """The rendered day and night traverses, and their pixel descriptors as .npy and as hloc .h5."""
    import cv2

    import encoders

    s = scene_on_disk("two_seasons", (48, 32), 60)
    root = tmp_path_factory.mktemp("described")
    enc = encoders.get("projection", descriptor="pixel")
    out = {"folders": [s[n] for n in s["names"][:2]]}
    for role, folder in zip(("db", "q"), out["folders"], strict=True):
        files = sorted(folder.glob("*.png"))
        d = enc.describe([cv2.imread(str(f)) for f in files])
        np.save(root / f"{role}.npy", d)
        out[role + "_npy"] = root / f"{role}.npy"
        out[role + "_h5"] = _h5(root / f"{role}.h5", [f"{folder.name}/{f.name}" for f in files], d)
    return out


def _metrics(out):
    ms = json.loads((out / "metrics.json").read_text())["methods"]
    drop = ("seconds", "similarity_file", "pr_curve")
    return {m: {k: v for k, v in e.items() if k not in drop} for m, e in ms.items()}


@pytest.mark.slow
def test_the_same_descriptors_as_npy_as_h5_and_from_the_images_give_the_same_metrics(described, tmp_path, capsys):
    common = ["--tolerance", 3, "--no-progress"]
    runs = {"npy": [described["db_npy"], described["q_npy"]], "h5": [described["db_h5"], described["q_h5"]],
            "images": [*described["folders"], "--encoder", "projection", "--encoder-conf", "descriptor=pixel",
                       "--encoder-conf", "standardise=fit", "--methods", "rshosm-seq,delta,seqslam-desc,pairwise",
                       "--method-conf", "pairwise.on=descriptor"]}
    for name, argv in runs.items():
        assert main([str(a) for a in ["compare", *argv, "--out", tmp_path / name, *common]]) == 0, \
            capsys.readouterr().err
    got = {name: _metrics(tmp_path / name) for name in runs}
    assert list(got["npy"]) == ["rshosm-seq", "delta", "seqslam-desc", "pairwise"]  # the descriptors preset
    assert got["npy"] == got["h5"] == got["images"]
    assert got["npy"]["rshosm-seq"]["ap"] > got["npy"]["pairwise"]["ap"]
    assert (tmp_path / "npy" / "report.html").is_file()


def _refused(argv, capsys, tmp_path, *words):
    out = tmp_path / "o"
    assert main([str(a) for a in [*argv, "--out", out, "--tolerance", 2, "--no-progress"]]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and all(w in err for w in words), err
    assert not out.exists()


@pytest.mark.slow
def test_bad_descriptor_files_are_refused_in_one_line_writing_nothing(described, tmp_path, capsys):
    good = np.load(described["q_npy"])
    cases = {"nan.npy": good.copy(), "flat.npy": good[0], "cube.npy": good[:, :, None], "empty.npy": good[:0],
             "short.npy": good[:, :100]}
    cases["nan.npy"][7, 3] = np.nan
    for name, a in cases.items():
        np.save(tmp_path / name, a)
    db = described["db_npy"]
    _refused(["compare", db, tmp_path / "nan.npy"], capsys, tmp_path, "nan.npy", "NaN or inf", "000007")
    _refused(["compare", db, tmp_path / "flat.npy"], capsys, tmp_path, "flat.npy", "N x D")
    _refused(["compare", db, tmp_path / "cube.npy"], capsys, tmp_path, "cube.npy", "N x D")
    _refused(["compare", db, tmp_path / "empty.npy"], capsys, tmp_path, "empty.npy", "N x D")
    _refused(["compare", db, tmp_path / "short.npy"], capsys, tmp_path, "different lengths", "short.npy")
    np.save(tmp_path / "pickled.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    _refused(["compare", db, tmp_path / "pickled.npy"], capsys, tmp_path, "pickled.npy", "not a .npy of numbers")
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f.create_dataset("keypoints", data=np.zeros((3, 2)))
    _refused(["compare", db, tmp_path / "other.h5"], capsys, tmp_path, "other.h5", "no global_descriptor")
    _h5(tmp_path / "ragged.h5", ["a", "b"], [np.zeros(4), np.zeros(5)])
    _refused(["compare", db, tmp_path / "ragged.h5"], capsys, tmp_path, "ragged.h5", "unequal length")
    # what cannot read descriptors, or be read beside them
    folder = described["folders"][1]
    _refused(["compare", db, folder], capsys, tmp_path, "holds descriptors", str(folder))
    _refused(["compare", db, described["q_npy"], "--encoder", "pixel"], capsys, tmp_path, "--encoder descriptors")
    _refused(["compare", db, described["q_npy"], "--methods", "seqslam"], capsys, tmp_path, "seqslam reads the images")
    _refused(["compare", db, described["q_npy"], "--verify", 3], capsys, tmp_path, "--verify", "no images")


@pytest.mark.slow
def test_learn_localize_and_loops_take_descriptor_files(described, tmp_path, capsys):
    db, q = described["db_npy"], described["q_npy"]
    assert main([str(a) for a in ["learn", db, "--out", tmp_path / "map.npz", "--no-progress"]]) == 0
    capsys.readouterr()
    argv = ["localize", tmp_path / "map.npz", q, "--out", tmp_path / "loc", "--tolerance", 3]
    assert main([str(a) for a in argv]) == 0
    assert len(capsys.readouterr().out.splitlines()) == 60  # one JSON line a frame
    m = json.loads((tmp_path / "loc" / "metrics.json").read_text())
    assert m["params"]["encoder"] == "descriptors" and m["methods"]["rshosm-seq"]["frames"] == 60
    assert main([str(a) for a in ["loops", db, "--out", tmp_path / "loops", "--no-progress"]]) == 0
    assert json.loads((tmp_path / "loops" / "metrics.json").read_text())["params"]["encoder"] == "descriptors"
    capsys.readouterr()
    assert main([str(a) for a in ["loops", db, "--geometry", "on", "--out", tmp_path / "g", "--no-progress"]]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--geometry on" in err and "no images" in err and not (tmp_path / "g").exists()


@pytest.mark.slow
def test_images_beside_a_descriptor_file_name_its_frames_and_show_on_the_page(described, tmp_path, capsys):
    import shutil

    pair = []
    for role, folder in zip(("db", "q"), described["folders"], strict=True):
        shutil.copy(described[role + "_npy"], tmp_path / f"{role}.npy")
        (tmp_path / role).symlink_to(folder)  # db.npy beside db/: its images, one a row
        pair.append(tmp_path / f"{role}.npy")
    assert DescriptorSource(pair[0]).names() == sorted(p.name for p in described["folders"][0].glob("*.png"))
    argv = ["compare", *pair, "--tolerance", 3, "--out", tmp_path / "o", "--no-progress"]
    assert main([str(a) for a in argv]) == 0, capsys.readouterr().err
    assert (tmp_path / "o" / "report.html").read_text().count("data:image/jpeg") > 100  # the frames, shown
    np.save(tmp_path / "short.npy", np.load(pair[1])[:50])
    (tmp_path / "short").symlink_to(described["folders"][1])
    with pytest.raises(ValueError, match="50 descriptors, but the folder beside it"):
        DescriptorSource(tmp_path / "short.npy")
