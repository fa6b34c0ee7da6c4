"""Nordland benchmark pipeline on a small synthetic two-season dataset (no download needed)."""
import json

import cv2
import numpy as np
import pytest

from pipelines import nordland
from pipelines.nordland import benchmark, data


def _make_dataset(root, n=60, seed=0, winter_noise=60.0):
    """Smooth random places; 'winter' is darker, lower-contrast, noisy and shifted by 2 px."""
    rng = np.random.default_rng(seed)
    for season in ("summer", "winter"):
        (root / season).mkdir(parents=True)
    for i in range(n):
        base = cv2.GaussianBlur(rng.uniform(0, 255, (32, 64)).astype(np.float32), (0, 0), 2.0)
        base = (base - base.mean()) / (base.std() + 1e-6) * 50 + 128
        summer = np.clip(base, 0, 255)
        winter = 0.6 * np.roll(base, 2, axis=1) + 60 + rng.normal(0, winter_noise, base.shape)
        name = f"images-{(i + 1) * 10:05d}.png"
        for season, img in (("summer", summer), ("winter", np.clip(winter, 0, 255))):
            cv2.imwrite(str(root / season / name), np.repeat(img.astype(np.uint8)[:, :, None], 3, axis=2))
    return root


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return _make_dataset(tmp_path_factory.mktemp("nordland"))


def test_missing_dataset_names_where_it_looked(tmp_path, capsys):
    with pytest.raises(data.DatasetError, match=str(tmp_path / "nowhere" / "summer")):
        data.find_dataset(tmp_path / "nowhere")
    code = nordland.main(["--subset", "358", "--out", str(tmp_path / "o"), "--data", str(tmp_path / "nowhere")])
    assert code == 2 and "not found" in capsys.readouterr().err


def test_dataset_found_through_the_environment(tmp_path, monkeypatch, dataset):
    (tmp_path / "sets").mkdir()
    (tmp_path / "sets" / data.DATASET_NAME).symlink_to(dataset)
    monkeypatch.setenv(data.DATASETS_ENV, str(tmp_path / "sets"))
    assert data.find_dataset() == tmp_path / "sets" / data.DATASET_NAME
    assert data.find_dataset(dataset) == dataset  # --data wins
    monkeypatch.setenv(data.DATASETS_ENV, str(tmp_path / "empty"))
    roots = data.candidate_roots()
    assert roots[0] == tmp_path / "empty" / data.DATASET_NAME
    if not all((r / "summer").is_dir() and (r / "winter").is_dir() for r in roots[1:]):
        with pytest.raises(data.DatasetError, match=f"{tmp_path / 'empty'}.*VPR_DATASETS is set"):
            data.find_dataset()


def test_frame_lists_subset_and_alignment(tmp_path, dataset):
    names = data.frame_names(dataset, "full")
    assert len(names) == 60 and names == sorted(names)
    assert data.frame_names(dataset, "358") == names[::10]
    bad = _make_dataset(tmp_path / "bad", n=3)
    (bad / "winter" / "images-00010.png").rename(bad / "winter" / "images-99999.png")
    with pytest.raises(data.DatasetError, match="aligned"):
        data.frame_names(bad, "full")
    with pytest.raises(data.DatasetError, match="subset"):
        data.frame_names(dataset, "100")


def test_unreadable_image_is_named(tmp_path):
    bad = _make_dataset(tmp_path / "bad", n=2)
    (bad / "summer" / "images-00010.png").write_bytes(b"not a png")
    with pytest.raises(data.DatasetError, match="images-00010.png"):
        data.pixel_descriptors(bad, "summer", data.frame_names(bad, "full"))


def test_descriptor_cache_is_used_and_keyed_by_frames(tmp_path, dataset):
    names = data.frame_names(dataset, "full")
    a = data.pixel_descriptors(dataset, "summer", names, tmp_path)
    files = list(tmp_path.glob("pixel_summer_*.npy"))
    assert a.shape == (60, 2048) and len(files) == 1
    # a planted cache is returned as it is: proof that the cache, not the images, was read
    np.save(files[0], np.zeros_like(a))
    assert not data.pixel_descriptors(dataset, "summer", names, tmp_path).any()
    b = data.pixel_descriptors(dataset, "summer", names[:30], tmp_path)
    np.testing.assert_array_equal(b, a[:30])


def test_per_traverse_standardisation_fits_each_traverse_on_itself():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(50, 2048)).astype(np.float32)
    a1, b1 = benchmark.encode_sdrs(x, x + 5.0, k=40)   # a global offset of one season is removed
    assert (a1 != b1).nnz == 0
    a2, b2 = benchmark.encode_sdrs(x, x + 5.0, k=40, standardise="none")
    assert (a2 != b2).nnz > 0
    assert np.all(np.diff(a1.indptr) == 40)


def test_benchmark_end_to_end(tmp_path, dataset, capsys):
    out = tmp_path / "out"
    code = nordland.main(["--subset", "full", "--out", str(out), "--data", str(dataset), "--k", "200",
                          "--no-progress"])
    assert code == 0
    printed = capsys.readouterr().out
    doc = json.loads((out / "metrics.json").read_text())
    assert (out / "pr.png").stat().st_size > 0 and (out / "table.md").read_text() in printed
    assert doc["frames"] == 60 and set(doc["methods"]) == set(nordland.METHOD_SPECS)
    for label, m in doc["methods"].items():
        for key in ("auc_pr", "recall_at_100p", "recall_at_1"):
            assert 0.0 <= m[key] <= 1.0, (label, key)
        assert m["seconds"] >= 0 and m["conf"]
    assert doc["peak_rss_mb"] > 0
    auc = {label: m["auc_pr"] for label, m in doc["methods"].items()}
    # the sequence methods beat both single-frame baselines on the noisy "winter"
    assert auc["rSHOSM-seq"] > auc["pairwise (SDR overlap)"] + 0.2
    assert auc["SeqSLAM (pixel)"] > auc["pairwise (pixel, SAD)"]
    assert doc["methods"]["rSHOSM-seq"]["conf"]["threshold"] == 0.75
    # the tolerance's unit is said, kept in metrics.json and on the page
    assert "ground truth in frames kept: tolerance 1: 1 frame kept = 1 input frame true" in printed
    assert doc["ground_truth"]["tolerance_unit"] == "frames kept" and doc["ground_truth"]["frame_step"] == 1
    page = (out / "report.html").read_text()
    assert "1 frame kept = 1 input frame" in page and "rSHOSM-seq" in page and "report.html" in printed


def test_vpr_cli_registration(tmp_path, dataset):
    import argparse

    ap = argparse.ArgumentParser()
    nordland.add_arguments(ap, "nordland")
    # the full subset: every 10th of 60 frames is shorter than SeqSLAM's sequences (ds 10), which is refused
    args = ap.parse_args(["--subset", "full", "--out", str(tmp_path / "o"), "--data", str(dataset),
                          "--no-progress", "--k", "40"])
    assert nordland.run_command(args) == 0
    assert json.loads((tmp_path / "o" / "metrics.json").read_text())["frames"] == 60
