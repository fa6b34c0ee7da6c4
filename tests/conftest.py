"""Shared fixtures: the compiled kernels, rendered scenes in memory and on disk.

The suite runs on both cores (``-n 2``, pytest-xdist: each worker builds its
own session fixtures). ``-m "not slow"`` leaves out the command-line, fault, signal, browser and Dask
integration tests (marked ``slow``): the inner loop of a developer.
"""
from __future__ import annotations

import signal
from pathlib import Path

import numpy as np
import pytest


@pytest.fixture(scope="session", autouse=True)
def interrupt_handlers():
    """Ctrl-C raises KeyboardInterrupt here and in the commands the tests start, however the suite was started.

    A shell starts a background job (``nohup ... &``, some CI runners) with
    SIGINT ignored, and Python then installs no handler: an ignored signal is
    inherited by every child process, and the tests that stop a run with
    Ctrl-C would see nothing happen. A handled signal is reset to the default
    in a child, where Python installs its own.
    """
    saved = signal.getsignal(signal.SIGINT)
    if saved is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, saved)


@pytest.fixture(scope="session", autouse=True)
def compiled_kernels():
    """Compile (or load from numba's cache) every kernel once, before the first test.

    Otherwise whichever test first touches a kernel is charged with its
    compilation (tens of seconds on a fresh install), which hides the real
    slow tests.
    """
    from vpr import methods, sdr
    from vpr.seqslam import seqslam_topk
    from vpr.shosm import loop_evidence

    for name in methods.available():
        methods.get(name).warm_up()
    x = sdr.random_sdrs(40, 256, 10, seed=0)
    loop_evidence(x, exclude=5, n_inputs=256)
    a = np.zeros((4, 2), np.float32)
    for candidates in (None, "pairwise"):
        seqslam_topk(a, a, top_k=1, ds=2, R=2, candidates=candidates)
    seqslam_topk(sdr.random_sdrs(8, 64, 4, seed=0), sdr.random_sdrs(8, 64, 4, seed=1), top_k=1, ds=2, R=2)


@pytest.fixture(scope="session")
def rendered():
    """``rendered(spec, size, n_frames, traverses=None)``: a :class:`vpr.render.Scene`, rendered once per session."""
    from vpr.render import render_scene

    cache: dict = {}

    def get(spec: str = "two_seasons", size=(64, 48), n_frames=None, traverses=None):
        key = (spec, tuple(size), n_frames, tuple(traverses or ()))
        if key not in cache:
            cache[key] = render_scene(spec, size=tuple(size), n_frames=n_frames, traverses=traverses)
        return cache[key]

    return get


@pytest.fixture(scope="session")
def scene_on_disk(tmp_path_factory):
    """``scene_on_disk(spec, size, n_frames)``: a scene written by ``vpr render`` once per session.

    Returns ``{"dir", "gt" (ground_truth.csv), "names" (traverse names), NAME: folder of each traverse}``.
    Tests must not write into these folders (their outputs go to their own ``tmp_path``).
    """
    from vpr.render import write_scene

    cache: dict = {}

    def get(spec: str = "two_seasons", size=(64, 48), n_frames: int = 40):
        key = (spec, tuple(size), n_frames)
        if key not in cache:
            out = tmp_path_factory.mktemp(f"{spec}-{size[0]}x{size[1]}-{n_frames}")
            res = write_scene(spec, out, size=tuple(size), n_frames=n_frames, progress=False)
            folders = {name: Path(t["folder"]) for name, t in res["traverses"].items()}
            cache[key] = {"dir": out, "gt": out / "ground_truth.csv", "names": list(folders), **folders}
        return cache[key]

    return get
