"""Nordland summer vs winter benchmark: ``python -m pipelines.nordland --subset 358|full --out DIR``.

Summer is the database, winter the query; a query frame i matches database
frame j when |i - j| <= 1 (hard), pairs with 1 < |i - j| <= 3 are ignored
(soft). Methods: :data:`vpr.presets.NORDLAND_METHODS` (single frames, the
classic sequence baseline, the paper's memory and our extension), all on the
same frames. Writes ``metrics.json``, ``pr.png`` and
``table.md`` to ``--out`` and prints the table. The dataset is ``--data``,
else ``$VPR_DATASETS/nordland_trimmed``, else (source checkout only)
``../shared/datasets/nordland_trimmed`` next to the repository. The variant
study of ``research/docs/experiments.md`` is ``python -m research.studies.nordland_variants``.
"""
from __future__ import annotations

import argparse
import sys

from pipelines.args import add_common_arguments

from .benchmark import METHOD_SPECS, markdown_table, run_benchmark
from .data import DATASET_NAME, DATASETS_ENV, SUBSETS, DatasetError

__all__ = ["COMMANDS", "add_arguments", "run_command", "run_benchmark", "METHOD_SPECS", "markdown_table", "main"]

COMMANDS = {"nordland": "Nordland summer vs winter benchmark (needs the dataset)"}


def add_arguments(parser: argparse.ArgumentParser, command: str = "nordland") -> None:
    """Options of ``vpr nordland`` / ``python -m pipelines.nordland``."""
    parser.add_argument("--subset", choices=sorted(SUBSETS), default="358",
                        help="358: every 10th frame (OpenSeqSLAM's demo subset); full: all 3,576")
    parser.add_argument("--out", required=True, help="output folder (metrics.json, pr.png, table.md, cache/)")
    parser.add_argument("--data", default=None,
                        help=f"dataset folder holding summer/ and winter/ (default: ${DATASETS_ENV}/{DATASET_NAME},"
                             f" then ../shared/datasets/{DATASET_NAME} in a source checkout)")
    parser.add_argument("--k", type=int, default=200, help="active bits of the 2048-bit SDRs (default 200)")
    parser.add_argument("--threshold", type=float, default=None,
                        help="minicolumn threshold of both rSHOSM methods (default: each method's own)")
    add_common_arguments(parser)


def run_command(args) -> int:
    """Run :func:`run_benchmark` with the parsed ``args``; print the table; return the exit status."""
    try:
        doc = run_benchmark(args.subset, args.out, data=args.data, k=args.k, threshold=args.threshold,
                            progress=not args.no_progress)
    except (DatasetError, ValueError) as e:
        print(f"vpr nordland: {e}", file=sys.stderr)
        return 2
    metrics = {label: m for label, m in doc["methods"].items()}
    print(markdown_table(metrics, f"Nordland summer vs winter, {doc['frames']} frames (subset {doc['subset']})"),
          end="")
    truth = doc["ground_truth"]
    print(f"ground truth in frames kept: {truth['tolerance_text']} true; {truth['gt_soft_text']} ignored")
    print(f"peak memory {doc['peak_rss_mb']:.0f} MB, total {doc['total_seconds']:.1f} s; wrote {args.out}/report.html "
          "(open it: the table and the plot), metrics.json, table.md")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m pipelines.nordland", description=__doc__.splitlines()[0])
    add_arguments(ap)
    return run_command(ap.parse_args(argv))
