"""SeqSLAM (Milford & Wyeth, ICRA 2012) as in Sünderhauf's OpenSeqSLAM, vectorised."""
from .dense import (
    SeqSlamConf,
    SeqSLAMResult,
    check_sequence_params,
    match_images,
    pixel_descriptors,
    seqslam,
    trajectory_offsets,
)
from .difference import difference_matrix, enhance_contrast
from .topk import seqslam_topk

__all__ = ["SeqSLAMResult", "SeqSlamConf", "difference_matrix", "enhance_contrast", "trajectory_offsets", "seqslam",
           "match_images", "pixel_descriptors", "seqslam_topk", "check_sequence_params"]
