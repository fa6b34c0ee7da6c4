"""Two-view geometry: how many keypoint matches one fundamental matrix or homography explains (pycolmap)."""
from __future__ import annotations

import signal
import threading

import numpy as np

from vpr.checks import check_choice, check_float, check_int
from vpr.interrupts import deferred

from .features import Keypoints, check_keypoints


def _import_pycolmap():
    """pycolmap, without the SIGTERM / SIGINT handlers its logging library installs on import.

    Those print a native stack trace on a plain ``kill`` and bypass Python's own handlers (a command line's clean
    stop): Python's are put back after the import, and a stop that comes before the library installs its own is held
    (:func:`vpr.interrupts.deferred`) and raised once the import is done.
    """
    if threading.current_thread() is not threading.main_thread():
        import pycolmap

        return pycolmap
    stops = (signal.SIGTERM, signal.SIGINT)
    with deferred(stops):
        import pycolmap

        for s in stops:  # Python's handlers (the held ones here) in place of the library's
            signal.signal(s, signal.getsignal(s))
    return pycolmap


pycolmap = _import_pycolmap()

__all__ = ["MODELS", "two_view_inliers", "check_seed"]

#: Two-view models understood by :func:`two_view_inliers`, with the minimum
#: number of matches each needs (fewer give 0 inliers).
MODELS = {"fundamental": 8, "homography": 4}


def check_seed(seed) -> int:
    """A RANSAC seed: an int >= 0, or None (-1 for pycolmap: a fresh random seed per call)."""
    if seed is None:
        return -1
    return check_int(seed, "seed", 0)


def _ransac_options(max_error: float, seed: int, max_trials: int) -> pycolmap.RANSACOptions:
    opts = pycolmap.RANSACOptions()
    opts.max_error = max_error
    opts.random_seed = seed
    # colmap's default (100000 trials) makes a wrong candidate, whose matches are nearly all outliers, expensive; a
    # few thousand trials still find a true pair's model, which has a high inlier ratio.
    opts.max_num_trials = max_trials
    opts.min_num_trials = min(opts.min_num_trials, max_trials)
    opts.num_threads = 1  # determinism
    return opts


def two_view_inliers(f1: Keypoints, f2: Keypoints, matches, model: str = "fundamental",
                     max_error: float = 4.0, seed: int | None = 0, max_trials: int = 2000) -> int:
    """Number of matches consistent with one two-view model (pycolmap LO-RANSAC).

    ``matches``: (M, 2) index pairs into ``f1`` and ``f2`` (:func:`match_features`). ``model``: ``"fundamental"`` (any
    static scene) or ``"homography"`` (planar or distant; stricter). ``max_error``: inlier threshold in pixels of the
    detection frame (``docs/internals.md``); ``seed`` None: not deterministic. Returns 0 with fewer than 8 / 4 matches
    or when the estimation fails.
    """
    f1 = check_keypoints(f1, "f1")
    f2 = check_keypoints(f2, "f2")
    model = check_choice(model, "model", MODELS)
    max_error = check_float(max_error, "max_error", 0.0, open_min=True)
    seed = check_seed(seed)
    max_trials = check_int(max_trials, "max_trials", 1)
    m = np.asarray(matches)
    if m.size == 0:
        return 0
    if m.ndim != 2 or m.shape[1] != 2 or m.dtype.kind not in "iu":
        raise ValueError(f"matches must be an integer (M, 2) array, got shape {m.shape} dtype {m.dtype}")
    if m.min() < 0 or m[:, 0].max() >= len(f1) or m[:, 1].max() >= len(f2):
        raise ValueError(f"matches index outside f1 ({len(f1)} keypoints) or f2 ({len(f2)} keypoints)")
    if len(m) < MODELS[model]:
        return 0
    p1 = np.ascontiguousarray(f1.detection_xy()[m[:, 0]])
    p2 = np.ascontiguousarray(f2.detection_xy()[m[:, 1]])
    opts = _ransac_options(max_error, seed, max_trials)
    if model == "fundamental":
        result = pycolmap.estimate_fundamental_matrix(p1, p2, opts)
    else:
        result = pycolmap.estimate_homography_matrix(p1, p2, opts)
    if result is None:
        return 0
    return int(result["num_inliers"])
