"""No input file runs code; inputs that would give wrong metrics are refused or warned about.

Tiny renders keep the command-line cases fast.
"""
import os
import pickle

import numpy as np
import pytest

from pipelines.cli import main
from tests.cli import one_error_line as _one_error_line
from tests.cli import run as _run
from vpr.groundtruth.formats import db_query_matrix
from vpr.io import load_npy

N_FRAMES = 20


class _Payload:
    """Unpickling this runs ``touch MARKER``: what a crafted ground-truth file would do."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return os.system, (f"touch {self.marker}",)


@pytest.fixture(scope="module")
def scene(scene_on_disk):
    return scene_on_disk("two_seasons", (48, 32), N_FRAMES)


@pytest.fixture(scope="module")
def folders(scene):
    return scene[scene["names"][0]], scene[scene["names"][1]]


#: The quickest run that still reads, encodes, matches and evaluates
FAST = ["--preset", "fast", "--methods", "pairwise"]






# ------------------------------------------------------------ 1. no file runs code
def test_a_bare_pickle_named_npy_does_not_run(folders, tmp_path, capsys):
    marker = tmp_path / "PWNED"
    evil = tmp_path / "evil.npy"
    evil.write_bytes(pickle.dumps(_Payload(marker)))
    code, _, err = _run(["compare", *folders, "--out", tmp_path / "out", "--gt", evil], capsys)
    _one_error_line(code, err, "evil.npy", "not a readable")
    assert not marker.exists()
    assert not (tmp_path / "out").exists()


def test_a_payload_inside_a_real_npy_does_not_run(folders, tmp_path, capsys):
    marker = tmp_path / "PWNED"
    arr = np.empty((2, 2), dtype=object)
    arr[0] = [0, [0]]
    arr[1] = [1, _Payload(marker)]
    np.save(tmp_path / "ground_truth_new.npy", arr, allow_pickle=True)
    code, _, err = _run(["match", *folders, "--out", tmp_path / "out", "--gt", tmp_path / "ground_truth_new.npy"],
                        capsys)
    _one_error_line(code, err, "ground_truth_new.npy", "posix.system")
    assert not marker.exists()


def test_text_named_npy_is_one_error_line(folders, tmp_path, capsys):
    (tmp_path / "gt.npy").write_text("query,db\n0,0\n")
    code, _, err = _run(["compare", *folders, "--out", tmp_path / "out", "--gt", tmp_path / "gt.npy"], capsys)
    _one_error_line(code, err, "gt.npy", "no NumPy .npy header")


def test_vpr_bench_rows_with_numpy_scalars_and_arrays_are_still_read(tmp_path):
    rows = np.empty((3, 2), dtype=object)
    rows[0] = [np.int64(0), np.array([0, 1])]
    rows[1] = [1, [2]]
    rows[2] = [np.int32(2), []]
    np.save(tmp_path / "ground_truth_new.npy", rows, allow_pickle=True)
    gt = db_query_matrix(tmp_path / "ground_truth_new.npy", 4, 3)
    assert gt.sum() == 3 and gt[0, 0] and gt[1, 0] and gt[2, 1]


def test_load_npy_reads_numbers_as_numpy_does(tmp_path):
    a = np.arange(12, dtype=np.float32).reshape(3, 4)
    np.save(tmp_path / "a.npy", a)
    np.testing.assert_array_equal(load_npy(tmp_path / "a.npy"), a)
    with pytest.raises(ValueError, match="a.npy: not a readable"):
        (tmp_path / "a.npy").write_bytes((tmp_path / "a.npy").read_bytes()[:60])
        load_npy(tmp_path / "a.npy")


def test_no_product_module_unpickles_with_numpy():
    """``allow_pickle=True`` would let a file run code: the product reads .npy only through ``load_npy``."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    hits = []
    for pkg in ("vpr", "encoders", "pipelines"):
        for dirpath, _, files in os.walk(os.path.join(root, pkg)):
            for f in files:
                if f.endswith(".py"):
                    text = open(os.path.join(dirpath, f), encoding="utf-8").read()
                    if "allow_pickle=True" in text or "pickle.load(" in text:
                        hits.append(os.path.join(dirpath, f))
    assert not hits, hits


# ------------------------------------------------------------ 2. wrong metrics with no word
def test_positions_header_in_another_order_is_read_by_name(tmp_path):
    from vpr.groundtruth import gt_from_position_files

    xy = [(0, 0), (10, 0), (20, 0), (30, 0)]
    (tmp_path / "a.csv").write_text("frame,x,y\n" + "".join(f"{i},{x},{y}\n" for i, (x, y) in enumerate(xy)))
    (tmp_path / "b.csv").write_text("x,y,frame\n" + "".join(f"{x},{y},{i}\n" for i, (x, y) in enumerate(xy)))
    (tmp_path / "c.csv").write_text("Easting,Northing,Name\n"
                                    + "".join(f"{x},{y},{i}\n" for i, (x, y) in enumerate(xy)))
    want = gt_from_position_files(tmp_path / "a.csv", tmp_path / "a.csv", 1.0)
    np.testing.assert_array_equal(gt_from_position_files(tmp_path / "a.csv", tmp_path / "b.csv", 1.0), want)
    np.testing.assert_array_equal(gt_from_position_files(tmp_path / "c.csv", tmp_path / "b.csv", 1.0), want)
    (tmp_path / "d.csv").write_text("lat,lon,frame\n0,0,0\n")
    with pytest.raises(ValueError, match=r"d.csv:1: unknown header 'lat,lon,frame'"):
        gt_from_position_files(tmp_path / "a.csv", tmp_path / "d.csv", 1.0)


def _png(path, value):
    import cv2

    rng = np.random.default_rng(value)
    cv2.imwrite(str(path), rng.integers(0, 255, (24, 32, 3), dtype=np.uint8))


def test_other_formats_and_dangling_links_keep_frame_numbers(tmp_path):
    import cv2

    from vpr.sources import FrameSkippedWarning, IgnoredFilesWarning, open_source

    for i in range(6):
        _png(tmp_path / f"{i:03d}.png", i)
    (tmp_path / "002.png").unlink()
    img = np.random.default_rng(2).integers(0, 255, (24, 32, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "002.webp"), img)          # read: OpenCV decodes WebP
    (tmp_path / "004.png").unlink()
    (tmp_path / "004.png").symlink_to(tmp_path / "gone.png")  # dangling: skipped, keeps its number
    (tmp_path / "003.png").unlink()
    (tmp_path / "003.heic").write_bytes(b"ftypheic" * 8)  # a format not read: skipped, keeps its number
    (tmp_path / "notes.txt").write_text("not a frame")
    with pytest.warns(IgnoredFilesWarning, match="1 files that are not images ignored .*notes.txt"):
        src = open_source(tmp_path)
    assert src.indices() == [0, 1, 2, 3, 4, 5]
    with pytest.warns(FrameSkippedWarning) as rec:
        frames = list(src)
    assert [f.index for f in frames] == [0, 1, 2, 5]
    assert [f.name for f in frames] == ["000.png", "001.png", "002.webp", "005.png"]
    reasons = dict(src.skipped)
    assert reasons["004.png"] == "dangling symbolic link" and "003.heic" in reasons
    assert len(rec) == 2


def _vfr_video(path, stamps_ms):
    import fractions

    import av

    with av.open(str(path), "w") as c:
        s = c.add_stream("mpeg4", rate=10)
        s.width, s.height, s.pix_fmt = 64, 48, "yuv420p"
        s.codec_context.time_base = s.time_base = fractions.Fraction(1, 1000)
        for i, ms in enumerate(stamps_ms):
            f = av.VideoFrame.from_ndarray(np.full((48, 64, 3), (i * 7) % 255, np.uint8), format="bgr24")
            f.pts, f.time_base = ms, fractions.Fraction(1, 1000)
            for pkt in s.encode(f):
                c.mux(pkt)
        for pkt in s.encode():
            c.mux(pkt)
    return path


def test_variable_frame_rate_video_is_sampled_by_timestamps(tmp_path):
    from vpr.sources import open_source

    # 4 s at 10 fps, then 48 s at 1 fps: --fps 1 keeps one frame per second throughout
    stamps = [i * 100 for i in range(40)] + [4000 + i * 1000 for i in range(48)]
    src = open_source(_vfr_video(tmp_path / "vfr.mkv", stamps), fps=1)
    idx = src.indices()
    assert idx[:5] == [0, 10, 20, 30, 40]
    assert len(idx) == 52
    times = np.asarray(stamps)[idx] / 1000
    assert np.all(np.diff(times) == 1.0)
    assert [f.index for f in src] == idx


@pytest.mark.slow  # command-line integration
def test_ground_truth_that_makes_most_pairs_true_is_warned_about(folders, scene, tmp_path, capsys):
    with pytest.warns(UserWarning, match="--tolerance 1000 counts frames kept and spans more than a tenth of"):
        code, out, err = _run(["compare", *folders, "--out", tmp_path / "out", "--tolerance", "1000", *FAST], capsys)
    assert code == 0, err
    with pytest.warns(UserWarning, match=r"--radius 1e\+308: 100 % of all frame pairs"):
        code, out, err = _run(["loops", folders[0], "--out", tmp_path / "loops", "--gt", scene["gt"], "--radius",
                               "1e308", "--exclude", "5", "--preset", "fast", "--method", "pairwise"], capsys)
    assert code == 0, err


def test_a_matrix_of_fractions_is_refused(folders, tmp_path, capsys):
    np.save(tmp_path / "gt.npy", np.full((N_FRAMES, N_FRAMES), 0.3))
    code, _, err = _run(["compare", *folders, "--out", tmp_path / "out", "--gt", tmp_path / "gt.npy", *FAST], capsys)
    _one_error_line(code, err, "gt.npy", "0/1", "0.3")
    assert not (tmp_path / "out").exists()


def test_a_loop_matrix_of_another_stream_is_refused(folders, tmp_path, capsys):
    gt = np.zeros((84, 84), bool)
    gt[50, 10] = gt[60, 15] = True
    np.save(tmp_path / "loops.npy", gt)
    code, _, err = _run(["loops", folders[0], "--out", tmp_path / "out", "--gt", tmp_path / "loops.npy",
                         "--exclude", "5", "--preset", "fast"], capsys)
    _one_error_line(code, err, "loops.npy", "84 x 84", f"stream of {N_FRAMES} frames")
    np.save(tmp_path / "big.npy", np.eye(N_FRAMES + 4, N_FRAMES, dtype=bool))
    code, _, err = _run(["compare", *folders, "--out", tmp_path / "out", "--gt", tmp_path / "big.npy", *FAST],
                        capsys)
    _one_error_line(code, err, "big.npy", f"the database has {N_FRAMES} frames")


def test_the_table_says_the_soft_band_is_ignored_and_matches_csv_is_lf(folders, scene, tmp_path, capsys):
    code, out, err = _run(["compare", *folders, "--out", tmp_path / "out", "--gt", scene["gt"], "--radius", "2",
                           "--gt-soft", "30", *FAST], capsys)
    assert code == 0, err
    legend = [line for line in out.splitlines() if line.startswith("R@1, AP, R@100P and P(acc) ignore")]
    assert len(legend) == 1 and "pairwise " in legend[0]
    metrics = __import__("json").loads((tmp_path / "out" / "metrics.json").read_text())
    n_soft = metrics["methods"]["pairwise"]["best_in_soft"]
    assert legend[0].endswith(f"pairwise {n_soft}")
    raw = (tmp_path / "out" / "pairwise" / "matches.csv").read_bytes()
    assert b"\r" not in raw and raw.count(b"\n") == N_FRAMES + 1


# ------------------------------------------------------------ 4. refusals before any work
@pytest.mark.parametrize("command", ["compare", "loops"])
def test_an_encoder_that_cannot_fit_is_refused_before_reading(folders, tmp_path, capsys, command):
    srcs = [*folders] if command == "compare" else [folders[0], "--exclude", "5"]
    code, _, err = _run([command, *srcs, "--out", tmp_path / "out", "--encoder-conf", "n_bits=100000000"], capsys)
    line = _one_error_line(code, err, "pixel.n_bits=100000000", "GiB")
    assert "more than this machine's" in line
    assert not (tmp_path / "out").exists()


def test_a_file_name_that_is_not_utf8_is_read_and_written(folders, tmp_path, capsys):
    import shutil

    q = tmp_path / "q"
    shutil.copytree(folders[1], q)
    os.rename(os.fsencode(sorted(q.glob("*.png"))[-1]), os.path.join(os.fsencode(q), b"z_caf\xe9.png"))
    code, _, err = _run(["compare", folders[0], q, "--out", tmp_path / "out", "--tolerance", "2", *FAST], capsys)
    assert code == 0, err
    raw = (tmp_path / "out" / "pairwise" / "matches.csv").read_bytes()
    assert b"caf\xe9.png" in raw


# ------------------------------------------------------------ 5. small things
def test_loop_heatmap_draws_ground_truth_only_where_pairs_are_scored(tmp_path):
    import cv2

    from vpr.groundtruth import loop_closure_mask
    from vpr.plots import plot_similarity

    n = 60
    mask = loop_closure_mask(n, exclude=5)
    S = np.where(mask, np.random.default_rng(0).random((n, n)), -np.inf)
    gt = np.eye(n, dtype=bool) | np.eye(n, k=1, dtype=bool) | np.eye(n, k=-1, dtype=bool)  # a frame and its neighbours
    gt[10, 50] = gt[50, 10] = True  # one real loop

    def reddish(path) -> int:
        img = cv2.imread(str(path)).astype(int)
        b, g, r = img[..., 0], img[..., 1], img[..., 2]
        return int(((r - g > 60) & (r - b > 60)).sum())

    plain = reddish(plot_similarity(S, tmp_path / "a.png", gt_hard=gt, axis_labels=("earlier frame", "frame")))
    masked = reddish(plot_similarity(S, tmp_path / "b.png", gt_hard=gt, mask=mask,
                                     axis_labels=("earlier frame", "frame")))
    assert 0 < masked < plain / 10


def test_compare_help_lists_the_methods(capsys):
    from vpr import methods

    with pytest.raises(SystemExit):
        main(["compare", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    for name in methods.available():
        assert name in out.replace("- ", "-")


def test_an_empty_out_is_refused(folders, capsys):
    code, _, err = _run(["compare", *folders, "--out", "", *FAST], capsys)
    _one_error_line(code, err, "--out: an empty path")
    code, _, err = _run(["localize", folders[0], "-", "--out", "", "--state-out", "x.npz"], capsys)
    _one_error_line(code, err, "--out: an empty path")


def test_window_with_fixed_query_statistics_is_refused(folders, tmp_path, capsys):
    code, _, err = _run(["localize", folders[0], folders[1], "--out", tmp_path / "o", "--window", "5",
                         "--query-standardise", "db"], capsys)
    _one_error_line(code, err, "--window applies to --query-standardise running")


@pytest.mark.parametrize("conf, message", [("seqslam.ds=0", "ds: must be an integer >= 1"),
                                           ("seqslam.ds=40", "ds=40 is a sequence of 41 frames"),
                                           ("rshosm-seq.top_k=0", "top_k")])
def test_method_values_are_refused_in_every_command(folders, tmp_path, capsys, conf, message):
    method = conf.split(".")[0]
    for argv in (["compare", *folders, "--methods", method], ["loops", folders[0], "--method", method,
                                                              "--exclude", "5"]):
        if argv[0] == "loops" and "ds=40" not in conf and method == "seqslam":
            pass
        code, _, err = _run([*argv, "--out", tmp_path / "o", "--preset", "fast", "--method-conf", conf], capsys)
        _one_error_line(code, err, message)
        assert not (tmp_path / "o").exists()
