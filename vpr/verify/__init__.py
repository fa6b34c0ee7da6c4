"""Geometric verification of place-recognition candidates.

For every query, the ``N`` database images it is most similar to (according
to a similarity matrix ``S``, database x query, higher = more similar) are
checked geometrically: ORB keypoints are matched (OpenCV brute force,
Hamming distance, Lowe's ratio test and a mutual-nearest-neighbour check) and
a two-view model -- a fundamental matrix or a homography -- is fitted with
pycolmap's LO-RANSAC. The number of RANSAC inliers re-ranks the candidates
and gates acceptance: a query is accepted only if its best candidate has at
least ``min_inliers`` inliers.

Coordinate frames
-----------------
ORB needs images of a few hundred pixels to find keypoints, while VPR
systems often work with tiny thumbnails (e.g. 64 x 32). Images whose
shorter side is below ``min_side`` are therefore upscaled before detection.
:class:`Keypoints` keeps keypoints in the *original* image's pixel
coordinates, plus the upscaling factor. RANSAC's ``max_error`` is measured in
the *detection* frame (the upscaled image), so the same threshold means the
same thing for thumbnails and for full-size frames; for images that were not
upscaled the two frames coincide.

Modules: :mod:`~vpr.verify.features` (ORB keypoints, matching),
:mod:`~vpr.verify.twoview` (RANSAC), :mod:`~vpr.verify.rerank` (candidates,
re-ranking), :mod:`~vpr.verify.verifier` (:class:`Verifier`) and
:mod:`~vpr.verify.opinion` (:class:`GeometricOpinion`, a decider of loop closures).

Determinism
-----------
ORB and brute-force matching are deterministic. pycolmap's
``RANSACOptions.random_seed`` is set from ``seed`` and RANSAC runs on one
thread, so inlier counts are reproducible for a given seed (``seed=None``
draws a fresh random seed per call instead).
"""
from .features import Keypoints, extract_features, match_features
from .opinion import GeometricOpinion, OpinionConf, second_opinion
from .rerank import rerank, top_candidates
from .twoview import MODELS, two_view_inliers
from .verifier import Verifier, VerifyResult

__all__ = ["Keypoints", "VerifyResult", "Verifier", "MODELS", "extract_features", "match_features",
           "two_view_inliers", "top_candidates", "rerank", "GeometricOpinion", "OpinionConf",
           "second_opinion"]
