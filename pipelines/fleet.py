"""A fleet: many query traverses against one map, in parallel on Dask (``vpr match DB Q1 Q2 ...``).

The database is encoded and learned once, in this process
(:class:`pipelines.runs.MatchMap`), and goes to the cluster once, as the one
task that unpacks it; each query traverse is one task that writes
``OUT/<query name>/`` exactly as ``vpr match DB QUERY`` would. ``workers=0``
runs them here, ``workers=N`` on a local cluster, ``scheduler=ADDRESS`` on a
running one. A task killed with its worker runs again elsewhere; its files are
written atomically, so the results are the serial run's.
"""
from __future__ import annotations

import contextlib
import pickle
import sys
import time
import uuid
import warnings
from pathlib import Path

from pipelines.outputs import metrics_table, versions
from pipelines.runs import MatchMap, RunOptions, check_match, compare_query, extract_run, prepare_run
from vpr import io

__all__ = ["run_fleet", "query_folders"]


def query_folders(q_srcs) -> list[str]:
    """The output folder name of each query traverse: its source's name (refused when two share one)."""
    names = [s.name for s in q_srcs]
    seen: dict = {}
    for s, n in zip(q_srcs, names, strict=True):
        if n in seen:
            raise ValueError(f"two query traverses are both named {n!r} ({seen[n]} and {s.path}): their outputs "
                             "would share OUT/" + n + "; rename one")
        seen[n] = s.path
    return names


def _clean_partial(folder: Path) -> None:
    """Remove the temporaries a killed attempt left in ``folder`` (atomic writes: ``.NAME.RANDOM.SUFFIX``)."""
    if folder.is_dir():
        for p in folder.rglob(".*"):
            if p.is_file() and p.name != ".metrics.lock" and p.name.count(".") >= 3:
                with contextlib.suppress(OSError):
                    p.unlink()


def _query_task(the_map: MatchMap, query: str, q_src, opts: RunOptions, command: str, argv, gt) -> dict:
    """One query traverse on a worker: its folder's report (``metrics.json`` content); ``gt``: its ground truth."""
    import warnings

    _clean_partial(Path(opts.out))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a worker has no terminal; what matters is in metrics.json
        return compare_query(the_map, query, q_src, opts, command, argv=argv, gt=gt)


def _unpack(payload: bytes) -> MatchMap:
    return pickle.loads(payload)


def run_fleet(db, queries, method_names: list[str], opts: RunOptions, command: str = "match",
              workers: int | None = None, scheduler: str | None = None, progress=None) -> dict:
    """Match every query traverse of ``queries`` against ``db``; return the summary written to ``OUT/metrics.json``.

    Parameters
    ----------
    db : the database traverse (folder, video or image list).
    queries : list of query traverses (two or more, distinct names).
    method_names, opts, command : as :func:`pipelines.runs.run_compare`; ``opts.out`` is the fleet's
        folder, each query writes ``opts.out/<query name>``.
    workers, scheduler : where the queries run (module docstring); not both.
    progress : optional callable ``(query name, done, total)`` after each query.
    """
    from pipelines.cluster import check_workers

    n_workers = check_workers(workers, scheduler)
    out = Path(opts.out)
    queries = [str(q) for q in queries]
    if len(queries) < 2:
        raise ValueError("a fleet needs two or more query traverses (one query: vpr match DB QUERY)")
    runners, encoder, srcs, positions = prepare_run(out, [db, *queries], ["database", *["query"] * len(queries)],
                                                     method_names, opts)
    db_src, q_srcs = srcs[0], srcs[1:]
    names = query_folders(q_srcs)
    # every query's ground truth and sizes, before any work (built once, here, and sent with its task)
    q_xy = positions[1:] if positions is not None else [None] * len(q_srcs)
    gts = [check_match(runners, opts, db_src, q_src, None if xy is None else (positions[0], xy))
           for q_src, xy in zip(q_srcs, q_xy, strict=True)]
    # ---- the work starts here
    t0 = time.perf_counter()
    (db_ex,) = extract_run([db_src], ["database"], encoder, runners, opts)
    the_map = MatchMap(str(db), db_src, db_ex, encoder.name, dict(encoder.conf),
                       {m: r.fit(db_ex.features) for m, r in runners.items()})
    t_map = time.perf_counter() - t0
    argv = sys.argv[1:]
    jobs = [(n, q, s, RunOptions(**{**opts.__dict__, "out": out / n, "progress": False}), g)
            for n, q, s, g in zip(names, queries, q_srcs, gts, strict=True)]
    reports: dict = {}
    shipped = {"map_bytes": len(pickle.dumps(the_map, protocol=pickle.HIGHEST_PROTOCOL))}
    if n_workers == 0:
        for k, (n, q, s, o, g) in enumerate(jobs):
            reports[n] = _query_task(the_map, q, s, o, command, argv, g)
            if progress:
                progress(n, k + 1, len(jobs))
    else:
        reports = _run_on_dask(the_map, jobs, command, argv, None if n_workers is None else min(n_workers, len(jobs)),
                               scheduler, out, progress, shipped)
    summary = {
        "queries": {n: reports[n]["methods"] for n, *_ in jobs},
        "params": {"command": command, "db": str(db), "queries": dict(zip(names, queries, strict=True)),
                   "preset": opts.preset, "encoder": encoder.name, "encoder_conf": encoder.conf,
                   "methods": list(runners), "n_db": len(db_ex.features),
                   "n_query": {n: reports[n]["params"]["n_query"] for n, *_ in jobs},
                   "workers": n_workers, "scheduler": scheduler, "map_seconds": t_map,
                   "seconds": time.perf_counter() - t0, "shipped": shipped,
                   "ground_truth": opts.gt.describe()},
        "versions": versions(),
    }
    io.save_json(out / "metrics.json", summary)
    return summary


def _run_on_dask(the_map, jobs, command, argv, n_workers, scheduler, out: Path, progress, shipped) -> dict:
    from distributed import as_completed

    from pipelines.cluster import dask_client

    run = uuid.uuid4().hex[:8]
    reports = {}
    with dask_client(n_workers, scheduler, out / f".dask-scratch-{run}" if scheduler is None else None) as client:
        client.wait_for_workers(1, timeout=60)
        # the map goes to the cluster once, as the one task that unpacks it: every query task on a worker reads
        # that worker's copy, not one shipped with each task. Not scattered: the cluster may drop replicas of
        # scattered data, and data scattered to a worker that dies is lost; a task's result is recomputed.
        payload = pickle.dumps(the_map, protocol=pickle.HIGHEST_PROTOCOL)
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Large object")  # on purpose: the map, once
            warnings.filterwarnings("ignore", message="Sending large graph")
            shared = client.submit(_unpack, payload, key=f"vpr-map-{run}", pure=False)
        shipped["task_bytes"] = max(len(pickle.dumps((q, s, o, command, argv, g), protocol=pickle.HIGHEST_PROTOCOL))
                                    for _, q, s, o, g in jobs)
        futures = {client.submit(_query_task, shared, q, s, o, command, argv, g, key=f"vpr-query-{run}-{n}",
                                 pure=False, retries=2): n for n, q, s, o, g in jobs}
        try:
            for k, fut in enumerate(as_completed(list(futures))):
                reports[futures[fut]] = fut.result()
                fut.release()
                if progress:
                    progress(futures[fut], k + 1, len(futures))
        except BaseException:
            client.cancel(list(futures))
            raise
    return reports


def summary_table(summary: dict) -> str:
    """The printed table of a fleet: one block per query traverse."""
    blocks = []
    for name, table in summary["queries"].items():
        blocks.append(f"query {name}:\n" + metrics_table(table))
    return "\n\n".join(blocks)
