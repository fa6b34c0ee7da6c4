"""Geometric verification of place-recognition candidates."""
from .features import Keypoints, extract_features, match_features, own_distances
from .opinion import GeometricOpinion, OpinionConf, opinion_around, second_opinion
from .rerank import rerank, top_candidates
from .twoview import MODELS, two_view_inliers
from .verifier import Verifier, VerifyResult

__all__ = ["Keypoints", "VerifyResult", "Verifier", "MODELS", "extract_features", "match_features", "own_distances",
           "two_view_inliers", "top_candidates", "rerank", "GeometricOpinion", "OpinionConf", "second_opinion",
           "opinion_around"]
