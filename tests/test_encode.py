"""``vpr encode`` on Dask: frame ranges, a cache that extract() reads, byte-identical parallel runs,
and a worker killed mid-run (a real ``dask scheduler`` and ``dask worker`` processes on 127.0.0.1)."""
import argparse
from pathlib import Path

import cv2
import numpy as np
import pytest

import encoders
from pipelines.encode import add_arguments, encode_sources, run_command
from pipelines.extract import cache_path, extract, load_cache
from vpr.sources import ListSource, open_source

N_FRAMES = 36
ROOT = Path(__file__).resolve().parents[1]
CONF = {"standardise": "fit", "k": 50}


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    from vpr.render import render_scene

    out = tmp_path_factory.mktemp("encode")
    scene = render_scene("two_seasons", size=(64, 48), n_frames=N_FRAMES)
    day, night = scene.traverses
    folders = {}
    for t in (day, night):
        folder = out / t.name
        folder.mkdir()
        for i, im in enumerate(t.images):
            cv2.imwrite(str(folder / f"{i:06d}.png"), im)
        folders[t.name] = folder
    (folders[night.name] / "000005.png").write_bytes(b"not a png")  # a skipped frame inside a chunk
    (folders[night.name] / "notes.txt").write_text("ignored")
    video = out / "day.mp4"
    w = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (64, 48))
    for im in day.images:
        w.write(im)
    w.release()
    lst = out / "frames.txt"
    lst.write_text("\n".join(f"{night.name}/{i:06d}.png" for i in range(0, N_FRAMES, 3)) + "\nmissing.png\n")
    return {"day": folders[day.name], "night": folders[night.name], "video": video, "list": lst, "dir": out}


def _frames(it):
    return [(f.index, f.name, f.image) for f in it]


@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("kind", ["night", "video", "list"])
def test_frame_ranges_give_the_frames_of_the_stream(data, kind):
    kw = {"step": 2, "max_frames": 15} if kind == "video" else {}
    src = open_source(data[kind], **kw)
    whole = _frames(src)
    skipped = list(src.skipped)
    assert bool(skipped) == (kind != "video")
    parts, part_skips = [], []
    for a in range(0, len(src.names()) + 4, 4):  # ranges past the end are empty, not errors
        parts += _frames(src.iter_range(a, a + 4))
        part_skips += src.skipped
    assert [(i, nm) for i, nm, _ in parts] == [(i, nm) for i, nm, _ in whole]
    assert all(np.array_equal(p[2], w[2]) for p, w in zip(parts, whole, strict=True))
    assert part_skips == skipped
    if kind == "video":
        assert [i for i, _, _ in whole] == list(range(0, 30, 2))
    with pytest.raises(ValueError, match="stop"):
        list(src.iter_range(5, 2))


def _assert_same_features(a, b):
    fa, fb = a.features, b.features
    assert fa.names == fb.names and a.indices == b.indices and a.skipped == b.skipped
    for x, y in ((fa.desc, fb.desc), (fa.inputs["pixels"], fb.inputs["pixels"])):
        assert (x is None) == (y is None)
        if x is not None:
            assert x.dtype == y.dtype and np.array_equal(x, y)
    assert (fa.sdr is None) == (fb.sdr is None)
    if fa.sdr is not None:
        assert fa.sdr.shape == fb.sdr.shape and (fa.sdr != fb.sdr).nnz == 0


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_serial_encode_is_the_cache_extract_reads_and_writes(data, tmp_path):
    cache = tmp_path / "cache"
    srcs = [open_source(data["night"]), open_source(data["video"], step=2)]
    out = encode_sources(srcs, cache, "pixel", CONF, workers=0, chunk_frames=7, progress=False)
    enc = encoders.get("pixel", **CONF)
    assert [r.path for r in out] == [cache_path(cache, s, enc) for s in srcs]
    assert out[0].n_frames == N_FRAMES - 1 and [s[0] for s in out[0].skipped] == ["000005.png"]
    assert out[1].n_frames == N_FRAMES // 2 and not any(r.cached for r in out)
    for src, res in zip(srcs, out, strict=True):
        # what match reads with --cache: a hit for any subset of the stored parts
        hit = extract(src, encoders.get("pixel", **CONF), inputs=("sdr", "pixels"), cache_dir=cache,
                      progress=False)
        fresh = extract(src, encoders.get("pixel", **CONF), inputs=("sdr", "pixels"), progress=False)
        assert hit.cached and not fresh.cached
        _assert_same_features(hit, fresh)
        assert hit.features.desc is None  # stored, but not asked for
        # extract writing the cache itself (same chunks) gives the same bytes
        own = tmp_path / "own"
        extract(src, encoders.get("pixel", **CONF), inputs=("sdr", "desc", "pixels"),
                cache_dir=own, chunk_frames=7, progress=False)
        assert (own / res.path.name).read_bytes() == res.path.read_bytes()
    # verification needs thumbnails: read from the frames, the rest from the cache
    thumbs = extract(srcs[0], encoders.get("pixel", **CONF), cache_dir=cache, thumbs=True, progress=False)
    assert thumbs.cached and len(thumbs.thumbs) == N_FRAMES - 1 and thumbs.thumbs[0].shape == (48, 64)
    again = encode_sources(srcs, cache, "pixel", CONF, workers=0, progress=False)
    assert all(r.cached for r in again)


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_fit_uses_the_whole_traverse_not_a_chunk(data, tmp_path):
    src = open_source(data["day"])
    encode_sources([src], tmp_path, "pixel", CONF, workers=0, chunk_frames=5, progress=False)
    got = load_cache(cache_path(tmp_path, src, encoders.get("pixel", **CONF)))
    enc = encoders.get("pixel", **CONF)
    desc = enc.describe([f.image for f in src])
    want = enc.fit_descriptors(desc).encode_descriptors(desc)
    assert np.array_equal(got.features.desc, desc) and (got.features.sdr != want).nnz == 0
    chunk_fit = encoders.get("pixel", **CONF).fit_descriptors(desc[:5]).encode_descriptors(desc)
    assert (chunk_fit != want).nnz > 0  # so the check above can tell the two apart


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_missing_parts_are_added_and_other_encoders_work(data, tmp_path):
    src = ListSource(data["list"])
    (res,) = encode_sources([src], tmp_path, "orb", {"mode": "grid"}, workers=0, parts=["sdr"], chunk_frames=4,
                            progress=False)
    assert [s[0] for s in res.skipped] == ["missing.png"] and res.n_frames == N_FRAMES // 3
    enc = encoders.get("orb", mode="grid")
    ex = extract(src, enc, inputs=("sdr", "desc"), cache_dir=tmp_path, progress=False)
    assert not ex.cached  # desc was not stored: encoded again with the union of both
    stored = load_cache(res.path)
    assert stored.features.desc is not None and stored.features.sdr is not None
    assert (stored.features.sdr != ex.features.sdr).nnz == 0
    assert extract(src, enc, inputs=("sdr", "desc"), cache_dir=tmp_path, progress=False).cached


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_an_input_equal_to_another_is_stored_once(data, tmp_path):
    src = open_source(data["day"])
    ex = extract(src, encoders.get("pixel", **CONF), inputs=("sdr", "desc", "pixels"), cache_dir=tmp_path,
                 progress=False)
    path = cache_path(tmp_path, src, encoders.get("pixel", **CONF))
    with np.load(path) as z:
        stored = set(z.files)
    got = load_cache(path).features
    same = np.array_equal(ex.features.desc, ex.features.inputs["pixels"])
    assert same  # the pixel encoder's descriptor is its pixels: the case this stores once
    assert "desc" in stored and "pixels" not in stored
    assert np.array_equal(got.desc, ex.features.desc) and np.array_equal(got.inputs["pixels"], got.desc)
    with pytest.raises(ValueError, match="read-only"):
        got.inputs["pixels"][0, 0] = 1.0


def test_bad_arguments_raise(data, tmp_path):
    with pytest.raises(ValueError, match="either workers"):
        encode_sources([data["day"]], tmp_path, workers=2, scheduler="tcp://127.0.0.1:1")
    with pytest.raises(ValueError, match="workers"):
        encode_sources([data["day"]], tmp_path, workers=-1)
    with pytest.raises(ValueError, match="unknown part"):
        encode_sources([data["day"]], tmp_path, workers=0, parts=["sdr", "colour"])
    with pytest.raises(ValueError, match="chunk_frames"):
        encode_sources([data["day"]], tmp_path, workers=0, chunk_frames=0)
    with pytest.raises(ValueError, match="unknown pixel encoder option"):
        encode_sources([data["day"]], tmp_path, workers=0, encoder_conf={"nope": 1})


def _serial_bytes(paths, tmp_path, **kw):
    out = encode_sources(paths, tmp_path / "serial", "pixel", CONF, workers=0, progress=False, **kw)
    return {r.path.name: r.path.read_bytes() for r in out}


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::UserWarning")
def test_local_cluster_run_command_equals_serial(data, tmp_path, capsys):
    ap = argparse.ArgumentParser()
    add_arguments(ap, "encode")
    cache = tmp_path / "dask"
    args = ap.parse_args([str(data["day"]), str(data["night"]), "--cache", str(cache), "--workers", "2",
                          "--chunk-frames", "5", "--encoder", "pixel", "--encoder-conf", "standardise=fit",
                          "--encoder-conf", "k=50", "--no-progress"])
    assert run_command(args) == 0
    assert "35 frames" in capsys.readouterr().out
    want = _serial_bytes([data["day"], data["night"]], tmp_path)
    assert {p.name: p.read_bytes() for p in cache.glob("*.npz")} == want


# ---------------------------------------------------------------- a real cluster, one worker killed
SLOW = """
import os
import time
from pathlib import Path

from encoders.pixel import PixelEncoder


def _slow(self, images):
    # test only: each chunk lasts long enough to kill its worker while it holds it, and says so in a file
    busy = Path(os.environ["VPR_TEST_BUSY_DIR"]) / f"{os.getpid()}.busy"
    busy.touch()
    time.sleep(0.4)
    out = PixelEncoder.unslowed_describe(self, images)
    busy.unlink()
    return out


# dask imports (and reloads) a preload file more than once: wrap the original only once
if not hasattr(PixelEncoder, "unslowed_describe"):
    PixelEncoder.unslowed_describe = PixelEncoder.describe
    PixelEncoder.describe = _slow
"""


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::UserWarning")
def test_killed_worker_chunks_are_retried_and_output_is_identical(data, tmp_path):
    from tests.dask_cluster import busy_cluster, run_in_thread

    with busy_cluster(tmp_path, SLOW) as (address, workers, log, busy_dir):
        killed = []

        def kill_busy_worker(i, start, stop, done, total):
            busy = sorted(busy_dir.glob("*.busy"))
            if not killed and busy:
                pid = int(busy[0].stem)
                name = next(n for n, p in workers.items() if p.pid == pid)
                workers[name].kill()  # SIGKILL: no goodbye to the scheduler
                workers[name].wait(timeout=10)
                killed.append((name, done, total))

        out = run_in_thread(lambda: encode_sources([data["night"]], tmp_path / "dask", "pixel", CONF,
                                                   scheduler=address, chunk_frames=3, progress=kill_busy_worker),
                            120, log)
        assert killed and killed[0][1] < killed[0][2], "no worker was killed while it held chunks"
        assert workers[killed[0][0]].poll() is not None
        got = {r.path.name: r.path.read_bytes() for r in out}
        assert got == _serial_bytes([data["night"]], tmp_path)


@pytest.mark.slow
def test_descriptor_files_encode_to_the_cache_vpr_compare_writes(tmp_path, capsys):
    """``vpr encode`` of descriptor files: their sparsifier and preset, in chunks, byte for byte the cache file
    ``vpr compare`` writes of them (and reads back); image parts refused."""
    from pipelines.cli import main

    rng = np.random.default_rng(0)
    db = rng.normal(size=(40, 32)).astype(np.float32)
    np.save(tmp_path / "db.npy", db)
    np.save(tmp_path / "q.npy", db + 0.2 * rng.normal(size=db.shape).astype(np.float32))
    files = [str(tmp_path / "db.npy"), str(tmp_path / "q.npy")]
    assert main(["encode", *files, "--cache", str(tmp_path / "enc"), "--workers", "0", "--chunk-frames", "16",
                 "--no-progress"]) == 0
    made = {p.name: p.read_bytes() for p in (tmp_path / "enc").iterdir()}
    assert len(made) == 2 and all("-descriptors-" in n for n in made)
    argv = ["compare", *files, "--tolerance", "1", "--no-progress"]  # the preset's methods: the SDRs and the rows
    assert main([*argv, "--cache", str(tmp_path / "run"), "--out", str(tmp_path / "o1")]) == 0
    assert {p.name: p.read_bytes() for p in (tmp_path / "run").iterdir()} == made
    assert main([*argv, "--cache", str(tmp_path / "enc"), "--out", str(tmp_path / "o2")]) == 0  # read, not rewritten
    assert {p.name: p.read_bytes() for p in (tmp_path / "enc").iterdir()} == made
    capsys.readouterr()
    assert main(["encode", *files, "--cache", str(tmp_path / "bad"), "--parts", "sdr,pixels", "--workers", "0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--parts pixels" in err and not (tmp_path / "bad").exists()
