"""A fleet of query traverses against one map: the same answers serially, on a local
cluster and on a real scheduler whose worker is killed mid-run."""
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from pipelines.runs import RunOptions, run_compare, run_fleet
from vpr.groundtruth import GroundTruthSpec

ROOT = Path(__file__).resolve().parents[1]
METHODS = ["rshosm-seq", "pairwise"]


@pytest.fixture(scope="module")
def fleet_data(scene_on_disk, tmp_path_factory):
    s = scene_on_disk("two_seasons", (48, 32), 30)
    day, night = s[s["names"][0]], s[s["names"][1]]
    extra = tmp_path_factory.mktemp("fleet") / "night_again"
    shutil.copytree(night, extra)  # a third query traverse with a name of its own
    return {"db": day, "queries": [night, day, extra], "gt": s["gt"]}


def _opts(out, gt=None, **kw):
    return RunOptions(out=Path(out), methods=tuple(METHODS), encoder="pixel",
                      encoder_conf={"k": 60, "standardise": "fit"}, gt=gt or GroundTruthSpec(), progress=False, **kw)


def _results(folder: Path) -> dict:
    """What a run answered (similarity, matches, metrics without timings), per method."""
    m = json.loads((folder / "metrics.json").read_text())["methods"]
    return {name: (np.load(folder / name / "similarity.npy") if (folder / name / "similarity.npy").is_file()
                   else None, (folder / name / "matches.csv").read_text(),
                   {k: v for k, v in m[name].items() if k not in ("seconds",)}) for name in METHODS}


def _same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        assert (a[k][0] is None and b[k][0] is None) or np.array_equal(a[k][0], b[k][0]), k
        assert a[k][1:] == b[k][1:], k


@pytest.mark.slow
def test_serial_fleet_equals_one_run_per_query(fleet_data, tmp_path):
    gt = GroundTruthSpec(files=(str(fleet_data["gt"]),), radius=3.0, soft=10.0)
    queries = fleet_data["queries"][:2]  # both traverses of the scene's ground truth
    summary = run_fleet(fleet_data["db"], queries, _opts(tmp_path / "fleet", gt, workers=0))
    assert list(summary["queries"]) == [Path(q).name for q in queries]
    for q in queries:
        name = Path(q).name
        run_compare(fleet_data["db"], q, _opts(tmp_path / "single" / name, gt))
        _same(_results(tmp_path / "fleet" / name), _results(tmp_path / "single" / name))
        assert summary["queries"][name]["rshosm-seq"]["ap"] == pytest.approx(
            json.loads((tmp_path / "single" / name / "metrics.json").read_text())["methods"]["rshosm-seq"]["ap"])
    assert summary["params"]["shipped"]["map_bytes"] > 0


def test_fleet_refusals(fleet_data, tmp_path):
    night = fleet_data["queries"][0]
    with pytest.raises(ValueError, match="both named"):
        run_fleet(fleet_data["db"], [night, night], _opts(tmp_path / "o", workers=0))
    # one query with --workers splits its match instead (tests/test_split.py)


@pytest.mark.slow
def test_local_cluster_fleet_equals_serial(fleet_data, tmp_path):
    run_fleet(fleet_data["db"], fleet_data["queries"], _opts(tmp_path / "serial", workers=0))
    summary = run_fleet(fleet_data["db"], fleet_data["queries"], _opts(tmp_path / "dask", workers=2))
    assert summary["params"]["shipped"]["task_bytes"] < summary["params"]["shipped"]["map_bytes"]
    for q in fleet_data["queries"]:
        _same(_results(tmp_path / "dask" / Path(q).name), _results(tmp_path / "serial" / Path(q).name))
    assert not list((tmp_path / "dask").glob(".dask-scratch-*"))




@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::UserWarning")
def test_killed_worker_query_is_rerun_and_results_are_identical(fleet_data, tmp_path):
    from tests.dask_cluster import busy_cluster, kill_a_busy_worker, run_in_thread, slowed_task

    run_fleet(fleet_data["db"], fleet_data["queries"], _opts(tmp_path / "serial", workers=0))
    slow = slowed_task("pipelines.runs", "_query_task", 1.5)
    with busy_cluster(tmp_path, slow) as (address, workers, log, busy_dir):
        killed = kill_a_busy_worker(workers, busy_dir)
        opts = _opts(tmp_path / "dask", scheduler=address)
        run_in_thread(lambda: run_fleet(fleet_data["db"], fleet_data["queries"], opts), 240, log)
        assert killed, "no worker was killed while it held a query"
        for q in fleet_data["queries"]:
            _same(_results(tmp_path / "dask" / Path(q).name), _results(tmp_path / "serial" / Path(q).name))
            leftovers = [p for p in (tmp_path / "dask" / Path(q).name).rglob(".*") if not p.name.endswith(".lock")]
            assert leftovers == []
