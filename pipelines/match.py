"""``vpr match`` and ``vpr compare`` on the command line: arguments in, a run, the table out.

``match`` runs one method (the preset's headline), ``compare`` several
(:func:`pipelines.runs.run_compare`: one query traverse, or several as a fleet
on Dask). What they write is :mod:`pipelines.outputs`.
"""
from __future__ import annotations

import argparse
import sys

from pipelines.args import (
    add_common_arguments,
    add_field_files_arguments,
    add_gt_arguments,
    add_prefix_arguments,
    add_query_speed_argument,
    add_recall_at_argument,
    add_run_arguments,
    field_files,
    options_from_args,
    parse_recall_at,
)

__all__ = ["COMMANDS", "add_arguments", "run_command"]

COMMANDS = {
    "match": "match a query traverse against a database traverse (folders, videos, lists)",
    "compare": "run several methods on the same database/query and tabulate their metrics",
}


def add_arguments(ap: argparse.ArgumentParser, command: str) -> None:
    ap.add_argument("db", metavar="DB", help="database traverse: image folder, video, image list, ROS bag, or "
                    "descriptors computed elsewhere (.npy of N x D, hloc's global-feature .h5)")
    ap.add_argument("query", metavar="QUERY", nargs="+",
                    help="query traverse(s), of the same kinds as DB; several: a fleet, one folder OUT/<query name> "
                         "each, on Dask (--workers, --scheduler)")
    add_run_arguments(ap, "methods" if command == "compare" else "first method")
    add_prefix_arguments(ap)
    add_gt_arguments(ap)
    fleet = ap.add_argument_group("Dask: several query traverses (a fleet), or one split in blocks")
    fleet.add_argument("--workers", type=int, metavar="N",
                       help="run the query traverses on a local Dask cluster of N processes (default: the "
                            "cores); 0 runs them one after the other in this process. One QUERY: its match is "
                            "split in blocks of query frames across the workers")
    fleet.add_argument("--scheduler", metavar="ADDRESS",
                       help="run the query traverses (one QUERY: the blocks of its match) on a running Dask "
                            "cluster, e.g. tcp://host:8786")
    ap.add_argument("--verify", type=int, default=0, metavar="N",
                    help="geometric verification of each query's N best candidates (ORB + pycolmap)")
    ap.add_argument("--min-inliers", type=int, default=15, help="inliers needed to accept a verified match")
    add_field_files_arguments(ap)
    add_recall_at_argument(ap)
    add_query_speed_argument(ap)
    add_common_arguments(ap)


def own_options(args) -> dict:
    """The options of ``match`` and ``compare`` beside every run's: Recall@N's N and the field's files."""
    return {"recall_at": parse_recall_at(args), **field_files(args)}


def run_command(args) -> int:
    from pipelines.runs import run_compare, run_fleet
    from vpr.report import metrics_table

    own = own_options(args)
    opts = options_from_args(args, **own)
    if len(args.query) > 1:  # a fleet: one table per query traverse
        def said(name, done, total):
            print(f"vpr {args.command}: query {name} done ({done} of {total})", file=sys.stderr, flush=True)

        report = run_fleet(args.db, args.query, opts, args.command, progress=said)
        tables, wrote = report["queries"], "metrics.json and a folder per query (each with its report.html)"
    else:
        report = run_compare(args.db, args.query[0], opts, args.command)
        tables, wrote = {None: report["methods"]}, "report.html (open it: the table, the plots and the frames side " \
            "by side), metrics.json"
    print("\n\n".join(("" if name is None else f"query {name}:\n")
                       + metrics_table(table, "match", report["params"].get("ground_truth"))
                       for name, table in tables.items()))
    print(f"wrote {args.out}/{wrote}")
    return 0
