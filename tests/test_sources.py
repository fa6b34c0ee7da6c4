"""Tests for vpr.sources: folders, lists and videos built in tmp_path."""
from __future__ import annotations

import os
import warnings

import cv2
import numpy as np
import pytest

from vpr.sources import (
    FolderSource,
    Frame,
    FrameSkippedWarning,
    ListSource,
    VideoSource,
    iter_batches,
    load_all,
    natural_key,
    open_source,
)


def _img(value: int, shape=(12, 16, 3), dtype=np.uint8) -> np.ndarray:
    return np.full(shape, value, dtype=dtype)


def _write(path, img) -> None:
    assert cv2.imwrite(str(path), img), path


def _video(path, n=30, fps=30.0, size=(64, 48), fourcc="mp4v"):
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, size)
    assert w.isOpened()
    rng = np.random.default_rng(0)
    for _ in range(n):
        # a different random texture per frame makes frames easy to tell apart after compression
        w.write(rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8))
    w.release()
    return path


def _all_frames(path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    out = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        out.append(img)
    cap.release()
    return out


# ---------------------------------------------------------------- folders

def test_natural_key_orders_numbers_numerically():
    names = ["img10.png", "img2.png", "IMG1.jpg", "img1b.png", "img02.png"]
    assert sorted(names, key=natural_key) == ["IMG1.jpg", "img1b.png", "img02.png", "img2.png", "img10.png"]


def test_folder_natural_sort_and_ignored_count(tmp_path):
    for i in (10, 2, 1, 33):
        _write(tmp_path / f"img{i}.png", _img(i))
    _write(tmp_path / "img5.JPG", _img(5))
    _write(tmp_path / "img7.Tiff", _img(7))
    _write(tmp_path / "img8.bmp", _img(8))
    (tmp_path / "notes.txt").write_text("not an image")
    (tmp_path / "poses.csv").write_text("0,1,2\n")
    _write(tmp_path / ".hidden.png", _img(99))
    (tmp_path / "sub").mkdir()
    _write(tmp_path / "sub" / "img0.png", _img(0))

    src = open_source(tmp_path)
    assert isinstance(src, FolderSource)
    expected = ["img1.png", "img2.png", "img5.JPG", "img7.Tiff", "img8.bmp", "img10.png", "img33.png"]
    assert src.names() == expected
    assert src.indices() == list(range(7))
    assert src.ignored == 2  # hidden files and folders are not counted
    frames = list(src)
    assert [f.name for f in frames] == expected
    assert [f.index for f in frames] == list(range(7))
    values = {f.name: int(f.image[0, 0, 0]) for f in frames if not f.name.endswith(".JPG")}  # JPEG is lossy
    assert values == {"img1.png": 1, "img2.png": 2, "img7.Tiff": 7, "img8.bmp": 8, "img10.png": 10, "img33.png": 33}
    assert src.skipped == []


def test_folder_frames_are_uint8_bgr_from_grey_16bit_and_alpha(tmp_path):
    _write(tmp_path / "a1.png", _img(200, (6, 7)))                           # grey
    _write(tmp_path / "a2.png", _img(60000, (6, 7), np.uint16))              # 16-bit grey
    _write(tmp_path / "a3.png", _img(70, (6, 7, 4)))                         # BGRA
    _write(tmp_path / "a4.tif", _img(65535, (6, 7, 3), np.uint16))           # 16-bit colour
    frames = list(FolderSource(tmp_path))
    assert len(frames) == 4
    for f in frames:
        assert f.image.dtype == np.uint8 and f.image.shape == (6, 7, 3), f.name
    assert [int(f.image.max()) for f in frames] == [200, 60000 >> 8, 70, 255]


def test_corrupt_and_empty_images_are_skipped_with_warning(tmp_path):
    _write(tmp_path / "f1.png", _img(1))
    ok, buf = cv2.imencode(".png", np.random.default_rng(0).integers(0, 255, (40, 50, 3), dtype=np.uint8))
    (tmp_path / "f2.png").write_bytes(buf.tobytes()[: len(buf) // 2])   # truncated PNG
    (tmp_path / "f3.png").write_bytes(b"")                               # zero bytes
    (tmp_path / "f4.jpg").write_bytes(b"this is not a jpeg" * 20)        # garbage
    _write(tmp_path / "f5.png", _img(5))

    src = open_source(tmp_path)
    assert src.names() == ["f1.png", "f2.png", "f3.png", "f4.jpg", "f5.png"]
    with pytest.warns(FrameSkippedWarning) as record:
        frames = list(src)
    assert [(f.index, f.name) for f in frames] == [(0, "f1.png"), (4, "f5.png")]
    assert [name for name, _ in src.skipped] == ["f2.png", "f3.png", "f4.jpg"]
    assert "0 bytes" in dict(src.skipped)["f3.png"]
    messages = " ".join(str(w.message) for w in record)
    for name in ("f2.png", "f3.png", "f4.jpg"):
        assert name in messages
    # a new iteration starts a fresh record
    with pytest.warns(FrameSkippedWarning):
        list(src)
    assert len(src.skipped) == 3


def test_all_frames_unreadable_is_an_error_after_warnings(tmp_path):
    (tmp_path / "a.png").write_bytes(b"")
    (tmp_path / "b.png").write_bytes(b"junk")
    src = open_source(tmp_path)
    with pytest.warns(FrameSkippedWarning), pytest.raises(ValueError, match="no readable frames"):
        list(src)


def test_empty_folder_error_counts_other_files(tmp_path):
    (tmp_path / "readme.md").write_text("x")
    (tmp_path / "data.csv").write_text("x")
    (tmp_path / ".DS_Store").write_text("x")
    with pytest.raises(ValueError, match=r"no images in .* \(2 other files ignored\)"):
        open_source(tmp_path)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match=r"no images in .*empty \(0 other files ignored\)"):
        open_source(empty)


def test_missing_path_and_unknown_kind(tmp_path):
    missing = tmp_path / "nowhere" / "seq"
    with pytest.raises(FileNotFoundError, match="nowhere"):
        open_source(missing)
    odd = tmp_path / "poses.csv"
    odd.write_text("1,2\n")
    with pytest.raises(ValueError, match="unknown source kind"):
        open_source(odd)


def test_folder_step_max_frames_and_fps_rejected(tmp_path):
    for i in range(10):
        _write(tmp_path / f"{i}.png", _img(i))
    src = open_source(tmp_path, step=3, max_frames=3)
    assert src.names() == ["0.png", "3.png", "6.png"]
    assert [(f.index, int(f.image[0, 0, 0])) for f in src] == [(0, 0), (3, 3), (6, 6)]
    with pytest.raises(ValueError, match="fps"):
        open_source(tmp_path, fps=5)
    with pytest.raises(ValueError, match="step"):
        open_source(tmp_path, step=0)
    with pytest.raises(ValueError, match="max_frames"):
        open_source(tmp_path, max_frames=1.5)


def test_folder_key_changes_with_content(tmp_path):
    _write(tmp_path / "a.png", _img(1))
    _write(tmp_path / "b.png", _img(2))
    k1 = FolderSource(tmp_path).key()
    assert FolderSource(tmp_path).key() == k1
    assert FolderSource(tmp_path, step=2).key() != k1
    _write(tmp_path / "b.png", _img(2, (30, 30, 3)))
    st = os.stat(tmp_path / "b.png")
    os.utime(tmp_path / "b.png", ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    assert FolderSource(tmp_path).key() != k1


def test_folder_streams_lazily(tmp_path, monkeypatch):
    for i in range(5):
        _write(tmp_path / f"{i}.png", _img(i))
    decoded = []
    real = cv2.imdecode

    def counting(buf, flags):
        decoded.append(1)
        return real(buf, flags)

    monkeypatch.setattr(cv2, "imdecode", counting)
    src = FolderSource(tmp_path)
    assert decoded == []  # construction and names() decode nothing
    src.names()
    it = iter(src)
    next(it)
    assert len(decoded) == 1


# ---------------------------------------------------------------- list files

def test_list_file_relative_paths_comments_and_missing_entries(tmp_path):
    imgs = tmp_path / "imgs"
    imgs.mkdir()
    for i in range(3):
        _write(imgs / f"p{i}.png", _img(10 + i))
    other = tmp_path / "elsewhere"
    other.mkdir()
    _write(other / "abs.png", _img(50))
    lists = tmp_path / "lists"
    lists.mkdir()
    lst = lists / "run.txt"
    lst.write_text(
        "# query traverse\n"
        "\n"
        "../imgs/p2.png\n"
        "   ../imgs/p0.png   \n"
        "# ../imgs/p1.png\n"
        "../imgs/gone.png\n"
        f"{other / 'abs.png'}\n",
        encoding="utf-8",
    )
    src = open_source(lst)
    assert isinstance(src, ListSource)
    assert src.names() == ["../imgs/p2.png", "../imgs/p0.png", "../imgs/gone.png", str(other / "abs.png")]
    with pytest.warns(FrameSkippedWarning, match="gone.png"):
        frames = list(src)
    assert [(f.index, int(f.image[0, 0, 0])) for f in frames] == [(0, 12), (1, 10), (3, 50)]
    assert src.skipped == [("../imgs/gone.png", "file not found")]


def test_list_file_without_entries_is_an_error(tmp_path):
    lst = tmp_path / "empty.lst"
    lst.write_text("# nothing here\n\n")
    with pytest.raises(ValueError, match="no image paths in .*empty.lst"):
        open_source(lst)


# ---------------------------------------------------------------- videos

def test_frame_reader_reads_a_video_on_rather_than_seeking_again(tmp_path, monkeypatch):
    from vpr.sources import READ_ON, frame_reader

    path = _video(tmp_path / "run.mp4", n=240, fps=30.0)
    reference = _all_frames(path)
    src = open_source(path, step=2)  # frame j is the video's 2 j
    starts = []
    real = src.iter_range
    monkeypatch.setattr(src, "iter_range", lambda a, b: starts.append(a) or real(a, b))
    image = frame_reader([src], [src.indices()])
    # a frame and a path behind it, both moving on (the second opinion's current frame and its earlier frame)
    for j in range(25, 45):
        assert np.array_equal(image(j), reference[2 * j])
        assert np.array_equal(image(j - 20), reference[2 * (j - 20)])
    assert starts == [25, 5]  # one read each, read on
    # a frame behind every read starts one; a frame up to READ_ON ahead of a read is read on from it
    far = 45 + READ_ON + 1
    for j in (0, 44, 3, far):
        assert np.array_equal(image(j), reference[2 * j])
    assert starts == [25, 5, 0, far]  # 44 from the second read (at 25), 3 from the one at 0


def test_images_at_reads_a_video_once_through_the_positions_asked(tmp_path, monkeypatch):
    from vpr.sources import READ_ON, images_at

    path = _video(tmp_path / "run.mp4", n=240, fps=30.0)
    reference = _all_frames(path)
    src = open_source(path, step=2)  # position p is the video's frame 2 p
    starts = []
    real = src.iter_range
    monkeypatch.setattr(src, "iter_range", lambda a, b: starts.append(a) or real(a, b))
    far = 41 + READ_ON + 1  # more than READ_ON past the position read next after 40
    asked = [far, 3, 40, 0, 3, 17]  # in any order, once each
    got = images_at(src, asked)
    assert sorted(got) == sorted(set(asked))
    assert all(np.array_equal(got[p], reference[2 * p]) for p in got)
    assert starts == [0, far]  # one read through 0..40, another where the next is more than READ_ON on


def test_video_step_fps_and_max_frames_select_the_right_frames(tmp_path):
    path = _video(tmp_path / "run.mp4", n=30, fps=30.0)
    reference = _all_frames(path)
    assert len(reference) == 30

    def check(src, expected_indices):
        assert isinstance(src, VideoSource)
        assert src.indices() == expected_indices
        assert src.names() == [f"frame_{i:06d}" for i in expected_indices]
        frames = list(src)
        assert [f.index for f in frames] == expected_indices
        assert [f.name for f in frames] == src.names()
        for f in frames:
            assert f.image.dtype == np.uint8 and f.image.shape == (48, 64, 3)
            assert np.array_equal(f.image, reference[f.index]), f.name
        assert src.skipped == []

    check(open_source(path), list(range(30)))
    check(open_source(path, step=4), [0, 4, 8, 12, 16, 20, 24, 28])
    check(open_source(path, fps=10), list(range(0, 30, 3)))
    # 30 -> 7 fps: sample k at k/7 s, first frame not earlier than that
    check(open_source(path, fps=7), [0, 5, 9, 13, 18, 22, 26])
    check(open_source(path, fps=60), list(range(30)))
    check(open_source(path, step=2, max_frames=4), [0, 2, 4, 6])
    check(open_source(path, fps=15, max_frames=2), [0, 2])


def test_video_argument_errors(tmp_path):
    path = _video(tmp_path / "run.mp4", n=3)
    with pytest.raises(ValueError, match="not both"):
        open_source(path, fps=10, step=2)
    for bad in (0, -1, float("nan"), "10"):
        with pytest.raises(ValueError, match="fps"):
            open_source(path, fps=bad)
    with pytest.raises(ValueError, match="max_frames"):
        open_source(path, max_frames=0)


def test_garbage_video_is_a_clear_error(tmp_path):
    bad = tmp_path / "broken.mp4"
    bad.write_bytes(np.random.default_rng(1).bytes(4096))
    with pytest.raises(ValueError, match="broken.mp4"):
        open_source(bad)
    empty = tmp_path / "empty.avi"
    empty.write_bytes(b"")
    with pytest.raises(ValueError, match="empty.avi"):
        open_source(empty)


def test_truncated_video_ends_with_warning_not_crash(tmp_path):
    path = _video(tmp_path / "full.avi", n=30, fourcc="MJPG")
    data = path.read_bytes()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(data[: len(data) // 2])
    src = open_source(cut)
    assert len(src.names()) == 30  # the container still claims 30 frames
    with pytest.warns(FrameSkippedWarning, match="cut.avi"):
        frames = list(src)
    assert 0 < len(frames) < 30
    assert [f.index for f in frames] == list(range(len(frames)))
    assert src.skipped[0][0] == f"frame_{len(frames):06d}"
    assert len(src.skipped) == 1


class _FailingCapture:
    """Stands in for cv2.VideoCapture: frames decode until ``fail_at``, then retrieve() fails."""

    def __init__(self, n, fail_at):
        self.n, self.fail_at, self.pos = n, fail_at, 0

    def isOpened(self):
        return True

    def get(self, prop):
        return {cv2.CAP_PROP_FPS: 25.0, cv2.CAP_PROP_FRAME_COUNT: float(self.n)}.get(prop, 0.0)

    def grab(self):
        if self.pos >= self.n:
            return False
        self.pos += 1
        return True

    def retrieve(self):
        if self.pos - 1 == self.fail_at:
            return False, None
        return True, np.full((4, 5, 3), self.pos - 1, np.uint8)

    def read(self):
        return (self.retrieve() if self.grab() else (False, None))

    def release(self):
        pass


def test_decode_failure_mid_video_is_recorded(tmp_path, monkeypatch):
    path = tmp_path / "fake.mp4"
    path.write_bytes(b"placeholder")
    monkeypatch.setattr(cv2, "VideoCapture", lambda p: _FailingCapture(10, fail_at=6))
    src = open_source(path, step=2)
    with pytest.warns(FrameSkippedWarning, match="frame_000006"):
        frames = list(src)
    assert [f.index for f in frames] == [0, 2, 4]
    assert [int(f.image[0, 0, 0]) for f in frames] == [0, 2, 4]
    assert src.skipped == [("frame_000006", "frame could not be decoded; stream ended")]


def test_video_key_depends_on_selection(tmp_path):
    path = _video(tmp_path / "run.mp4", n=3)
    k = open_source(path).key()
    assert open_source(path).key() == k
    assert open_source(path, step=2).key() != k
    assert open_source(path, fps=5).key() != k
    assert open_source(path, max_frames=2).key() != k


# ---------------------------------------------------------------- helpers

def test_load_all_and_iter_batches(tmp_path):
    for i in range(7):
        _write(tmp_path / f"im{i}.png", _img(i))
    (tmp_path / "im3.png").write_bytes(b"")
    src = open_source(tmp_path)
    with pytest.warns(FrameSkippedWarning):
        images, names = load_all(src, progress=False)
    assert names == ["im0.png", "im1.png", "im2.png", "im4.png", "im5.png", "im6.png"]
    assert [int(im[0, 0, 0]) for im in images] == [0, 1, 2, 4, 5, 6]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FrameSkippedWarning)
        batches = list(iter_batches(src, 4))
        assert [[f.name for f in b] for b in batches] == [names[:4], names[4:]]
        assert all(isinstance(f, Frame) for b in batches for f in b)
        with pytest.raises(ValueError, match="batch_size"):
            list(iter_batches(src, 0))
        _, names2 = load_all(src, progress=True)
        assert names2 == names


def test_exclude_in_seconds_uses_the_frames_rate(tmp_path):
    from tests.bags import write_bag

    video = _video(tmp_path / "v.mp4", n=60, fps=30.0)
    src = open_source(video, step=3)
    assert src.frames_in("5s") == 50 and src.frames_in("12") == 12 and src.frames_in(7) == 7
    assert open_source(video, fps=5.0).frames_in("2s") == 10
    frames = [np.full((32, 48, 3), 10 * i, np.uint8) for i in range(12)]
    bag = write_bag(tmp_path / "b.bag", frames, gps=False, odom=False, dt=0.1)
    assert open_source(bag).frames_in("2s") == 20 and open_source(bag, step=2).frames_in("2s") == 10
    folder = tmp_path / "imgs"
    folder.mkdir()
    for i in range(3):
        cv2.imwrite(str(folder / f"img{i}.png"), frames[i])
    with pytest.raises(ValueError, match="seconds need the frames' times, and .*imgs"):
        open_source(folder).frames_in("5s")
    for bad in ("x", "0", "0.01s", "-3"):
        with pytest.raises(ValueError, match="--exclude"):
            src.frames_in(bad)


def test_a_folder_read_frame_by_frame_follows_its_selection(tmp_path):
    import pickle

    for i in range(12):
        _write(tmp_path / f"{i:03d}.png", _img(10 * i))
    src = FolderSource(tmp_path, step=2)
    assert [int(f.image[0, 0, 0]) for k in range(6) for f in src.iter_range(k, k + 1)] == [0, 20, 40, 60, 80, 100]
    src.restrict([4, 8])  # one frame per so many metres: the selection changes, and what is read with it
    assert src.indices() == [4, 8] and [int(f.image[0, 0, 0]) for f in src.iter_range(1, 2)] == [80]
    shipped = pickle.loads(pickle.dumps(src))  # a worker's copy builds its own selection
    assert "_selection" not in shipped.__dict__ and shipped.indices() == [4, 8]
