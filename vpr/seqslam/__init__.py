"""SeqSLAM (Milford & Wyeth, ICRA 2012) as in Sünderhauf's OpenSeqSLAM, vectorised.

Pipeline, with OpenSeqSLAM's defaults:

1. images -> grey 64 x 32 -> 8 x 8 patch normalisation
   (:func:`vpr.imageproc.seqslam_preprocess`);
2. difference matrix ``D`` (database x query), mean absolute difference of the
   flattened descriptors (:func:`difference_matrix`);
3. local contrast enhancement along the database axis (:func:`enhance_contrast`);
4. trajectory search: for every query and database row, the minimum over a set
   of constant velocities of the summed enhanced differences along a straight
   line through ``ds + 1`` query frames (:func:`seqslam`);
5. uniqueness test: best score divided by the best score outside a window around
   it, accepted when the ratio is at most 0.9.

Any difference matrix can be fed to :func:`seqslam`, e.g. one built from CNN or
random-projection descriptors (``metric="cosine"``).

Beyond a dense ``n_db x n_q`` matrix (20,000 x 20,000 float32 is 1.6 GB),
:func:`seqslam_topk` goes from descriptors (dense, or SDR batches compared
through bit overlaps) by blocks of queries and keeps the top-K per query:
exactly the dense result when it searches every row (time still
``n_db * n_q``), or, with candidate windows, only the rows near candidate
alignments (time about linear; approximate, see its docstring).

Modules: :mod:`~vpr.seqslam.difference` (steps 2-3), :mod:`~vpr.seqslam.dense`
(steps 4-5), :mod:`~vpr.seqslam.topk` (large inputs) and
:mod:`~vpr.seqslam.kernels` (its compiled loops).

Where OpenSeqSLAM leaves a value undefined (the first and last ``ds / 2``
queries, databases shorter than a trajectory) this module defines one; every
such choice is listed in the docstring of :func:`seqslam`.
"""
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
