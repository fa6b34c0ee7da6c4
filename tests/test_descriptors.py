"""Global descriptors computed elsewhere as an input: .npy (N x D) and hloc's global-feature .h5."""
import json
import warnings

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
    got_names, got, order = read_descriptors(tmp_path / "g.h5")
    assert got_names == ["db/img1.jpg", "db/img2.jpg", "db/img3.jpg", "db/img10.jpg"] and order == "names"
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


def _h5_ordered(path, names, rows, track_order: bool):
    with h5py.File(path, "w", track_order=track_order) as f:
        for name, row in zip(names, rows, strict=True):
            f.create_group(name, track_order=track_order).create_dataset("global_descriptor", data=row)
    return path


def test_an_h5_keeps_its_frames_in_the_order_it_was_written_or_says_the_name_order(tmp_path):
    rows = np.arange(20, dtype=np.float32).reshape(5, 4)
    names = [f"q/img_{k}.jpg" for k in range(5)]
    shuffled = [3, 0, 4, 1, 2]
    # hloc's own files keep no order: the frames in the natural order of their names, said in one line
    _h5_ordered(tmp_path / "hloc.h5", [names[k] for k in shuffled], rows[shuffled], track_order=False)
    with pytest.warns(UserWarning, match="keeps no order of its frames.*natural order of their names"):
        src = DescriptorSource(tmp_path / "hloc.h5")
    assert src.names() == names and src.order == "names"
    np.testing.assert_array_equal(np.stack([f.image for f in src]), rows)
    # written keeping the order (track_order=True): the frames in the order they were written, whatever their names
    _h5_ordered(tmp_path / "kept.h5", [names[k] for k in shuffled], rows[shuffled], track_order=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        src = DescriptorSource(tmp_path / "kept.h5")
    assert src.names() == [names[k] for k in shuffled] and src.order == "file"


def test_frame_names_that_carry_no_order_are_refused_for_the_sequence_methods(tmp_path):
    from vpr.sources import check_ordered

    hashed = [f"db/{h}.jpg" for h in ("3fa9c2e1", "0b17d5aa", "c4e6f019", "91d2b3c7")]
    _h5_ordered(tmp_path / "hash.h5", hashed, np.eye(4, dtype=np.float32), track_order=False)
    src = DescriptorSource(tmp_path / "hash.h5")
    assert src.order is None
    with pytest.raises(ValueError, match="carry no order.*rshosm-seq reads the frames as a sequence.*track_order"):
        check_ordered([src], ["database"], ["rshosm-seq"])
    check_ordered([src], ["database"], [])  # single frames (pairwise): any order
    _h5_ordered(tmp_path / "hash_kept.h5", hashed, np.eye(4, dtype=np.float32), track_order=True)
    assert DescriptorSource(tmp_path / "hash_kept.h5").order == "file"


@pytest.mark.parametrize("names,ordered", [
    (["img_1.jpg", "img_2.jpg", "img_10.jpg"], True),
    (["1403636579763555584.png", "1403636579813555456.png"], True),  # EuRoC's nanosecond stamps
    (["2019-03-01_10-22-33.jpg", "2019-03-01_10-22-34.jpg"], True),
    (["frame0099.png", "frame0100.png", "frame0101.png"], True),
    (["3fa9c2e1.jpg", "0b17d5aa.jpg", "c4e6f019.jpg"], False),
    (["@0543256.96@4178906.70@10@S@.jpg", "@0543290.11@4178850.02@10@S@.jpg"], False),  # places, not an order
])
def test_which_names_carry_an_order(names, ordered):
    from vpr.sources import names_carry_order

    assert names_carry_order(names) is ordered


def test_one_h5_holds_the_database_and_the_queries_by_hlocs_prefixes(tmp_path):
    rows = np.arange(24, dtype=np.float32).reshape(6, 4)
    names = ["db/a1.jpg", "db/a2.jpg", "db/a3.jpg", "query/b1.jpg", "query/b2.jpg", "query/b3.jpg"]
    _h5(tmp_path / "global-feats.h5", names, rows)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        db = open_source(tmp_path / "global-feats.h5", prefix="db/")
        q = open_source(tmp_path / "global-feats.h5", prefix="query/")
    assert db.names() == names[:3] and q.names() == names[3:] and db.name != q.name
    np.testing.assert_array_equal(np.stack([f.image for f in q]), rows[3:])
    with pytest.raises(ValueError, match="no frame name begins with 'queries/'"):
        open_source(tmp_path / "global-feats.h5", prefix="queries/")
    np.save(tmp_path / "d.npy", rows)
    with pytest.raises(ValueError, match="--db-prefix applies to an hloc .h5"):
        open_source(tmp_path / "d.npy", prefix="db/", prefix_flag="--db-prefix")


def test_an_n_x_d_dataset_of_descriptors_at_the_root_is_read_and_anything_else_named(tmp_path):
    rows = np.arange(24, dtype=np.float32).reshape(6, 4)
    with h5py.File(tmp_path / "root.h5", "w") as f:
        f.create_dataset("global_descriptor", data=rows)
    names, got, order = read_descriptors(tmp_path / "root.h5")
    assert names == [f"{k:06d}" for k in range(6)] and order == "file"
    np.testing.assert_array_equal(got, rows)
    with h5py.File(tmp_path / "two.h5", "w") as f:
        f.create_dataset("descriptors", data=rows)
        f.create_dataset("features", data=rows)
    with pytest.raises(ValueError, match=r"several N x D datasets of descriptors \(found /descriptors \(6, 4\)"):
        read_descriptors(tmp_path / "two.h5")


def test_an_empty_or_damaged_npy_is_refused_naming_it(tmp_path):
    (tmp_path / "empty.npy").write_bytes(b"")
    with pytest.raises(ValueError, match="empty.npy: an empty file"):
        read_descriptors(tmp_path / "empty.npy")
    good = tmp_path / "good.npy"
    np.save(good, np.zeros((3, 4), np.float32))
    (tmp_path / "cut.npy").write_bytes(good.read_bytes()[:90])
    with pytest.raises(ValueError, match=r"cut.npy: not a .npy of numbers \("):
        read_descriptors(tmp_path / "cut.npy")
    import pickle

    (tmp_path / "pickled.npy").write_bytes(pickle.dumps({"a": 1}))  # never run, and said in whole words
    with pytest.raises(ValueError, match=r"pickled.npy: not a .npy of numbers \(.*`allow_pickle=` keyword argument"):
        read_descriptors(tmp_path / "pickled.npy")


@pytest.mark.slow
def test_a_shuffled_hloc_file_gives_the_ordered_files_answers_and_a_hashed_one_is_refused(described, tmp_path,
                                                                                          capsys):
    q = np.load(described["q_npy"])
    names = [f"query/img_{k}.jpg" for k in range(len(q))]
    order = np.random.default_rng(0).permutation(len(q))
    _h5_ordered(tmp_path / "shuffled.h5", [names[k] for k in order], q[order], track_order=False)
    runs = {"npy": described["q_npy"], "shuffled": tmp_path / "shuffled.h5"}
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        for name, query in runs.items():
            argv = ["match", described["db_npy"], query, "--out", tmp_path / name, "--tolerance", 3, "--no-progress"]
            assert main([str(a) for a in argv]) == 0, capsys.readouterr().err
    assert sum("natural order of their names" in str(w.message) for w in said) == 1
    assert _metrics(tmp_path / "npy") == _metrics(tmp_path / "shuffled")
    hashed = [f"query/{k * 7919 % 100003:x}{k}.jpg" for k in range(len(q))]
    _h5_ordered(tmp_path / "hash.h5", hashed, q, track_order=False)
    argv = ["match", described["db_npy"], tmp_path / "hash.h5", "--out", tmp_path / "h", "--tolerance", 3,
            "--no-progress"]
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "carry no order" in err and not (tmp_path / "h").exists()
