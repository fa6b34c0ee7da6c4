"""Ground truth: which database frame shows the same place as which query frame."""
from .files import (
    gt_from_position_files,
    load_loop_pairs,
    load_pairs_csv,
    load_positions_csv,
    load_tolerance_csv,
    load_traverse_positions,
    positions_of_frames,
)
from .formats import db_query_matrix, loop_matrix
from .matrices import (
    any_true,
    frame_rows,
    gt_from_frames,
    gt_from_labels,
    gt_from_positions,
    gt_from_tolerance,
    loop_closure_gt,
    loop_closure_mask,
    loop_pairs,
)
from .positions import (
    RATE_RATIO,
    Positions,
    check_rates,
    check_reversed,
    check_speeds,
    frame_positions,
    input_spec,
    prepare_positions,
    runs_backwards,
    same_rate,
    same_sampling,
    speed_step,
)
from .spec import (
    NAMES_RADIUS,
    GroundTruthSpec,
    aligned_frames,
    build_gt,
    build_loop_gt,
    build_stream_gt,
    check_loop_gt_files,
    check_radius,
    check_tolerance,
    sampling_step,
    tolerance_text,
)

__all__ = ["NAMES_RADIUS", "gt_from_labels", "gt_from_frames", "gt_from_tolerance", "gt_from_positions",
           "loop_closure_mask", "loop_closure_gt", "loop_pairs", "load_pairs_csv", "load_tolerance_csv",
           "load_loop_pairs", "load_positions_csv", "gt_from_position_files", "load_traverse_positions",
           "positions_of_frames",
           "db_query_matrix", "loop_matrix", "GroundTruthSpec", "build_gt", "build_loop_gt", "build_stream_gt",
           "check_loop_gt_files", "prepare_positions", "input_spec", "frame_positions", "Positions", "same_sampling",
           "same_rate",
           "check_rates", "check_reversed", "runs_backwards", "check_speeds", "speed_step", "RATE_RATIO", "any_true",
           "frame_rows", "sampling_step", "tolerance_text", "check_tolerance", "check_radius", "aligned_frames"]
