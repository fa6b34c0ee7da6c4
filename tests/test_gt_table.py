"""Every command x every ground-truth form x every input route, scored against one oracle of the right frame.

Each run writes ``matches.csv`` with each query frame's true database frame (``true_db``, the middle of its true
frames: here the only one); it must be the oracle's frame (:mod:`tests.gt_routes`) for every frame, whatever the
command, the route the frames came by and the form the truth was given in. A route that cannot carry a form (UTM in
file names that a video does not have) is left out, said by :func:`tests.gt_routes.applies`.
"""
from __future__ import annotations

import csv
import io
import json
import warnings

import numpy as np
import pytest

from pipelines.cli import main
from tests import gt_routes as g

pytestmark = pytest.mark.slow


@pytest.fixture(autouse=True)
def no_figures(monkeypatch):
    """The figures are not what this table checks (``test_plots``, ``test_report`` do): not drawn, to keep it short."""
    monkeypatch.setattr("vpr.plots.plot_similarity", lambda *a, **k: None)
    monkeypatch.setattr("vpr.plots.plot_pr", lambda *a, **k: None)

DBQ_COMMANDS = ("match", "localize", "learn+localize")


def _run(argv, capsys, stdin=None, monkeypatch=None) -> str:
    if stdin is not None:
        monkeypatch.setattr("sys.stdin", io.StringIO(stdin))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        code = main([str(a) for a in argv] + ["--no-progress"])
    err = capsys.readouterr().err
    assert code == 0, err
    return err


def _truth(out, method) -> list[int]:
    with open(out / method / "matches.csv", newline="") as fh:
        rows = sorted(csv.DictReader(fh), key=lambda r: int(r["query"]))
    return [int(r["true_db"]) for r in rows]


def _with_match(out, method) -> int:
    return json.loads((out / "metrics.json").read_text())["methods"][method]["recall_at_n"]["queries_with_true_match"]


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """``scenes(route, offset, utm)``: the database and the query written as ``route`` (cached): {"db": args,
    "query": args, "names": {role: frame names}, "traverse": {role: source name}}."""
    cache = {}

    def get(route: str, offset: int = g.OFFSET, utm: bool = False):
        key = (route, offset, utm)
        if key not in cache:
            root = tmp_path_factory.mktemp(f"{route}-{offset}{'-utm' if utm else ''}")
            got = {}
            for role in ("db", "query"):
                got[role] = g.write_route(route, root, role, g.images(role, offset), g.positions(role, offset),
                                          utm=utm)
            if route == "h5-prefix":  # one file for both, told apart by hloc's prefixes
                got["db"] = [*got["db"], "--db-prefix", "db/"]
                got["query"] = [*got["query"], "--query-prefix", "query/"]
            from vpr.sources import open_source

            srcs = {}
            for role in ("db", "query"):
                prefix = got[role][2] if route == "h5-prefix" else None
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    src = open_source(got[role][0], prefix=prefix)
                srcs[role] = {"names": src.names(), "traverse": src.name}
            cache[key] = {**got, "srcs": srcs, "root": root}
        return cache[key]

    return get


def _preset(route: str) -> list[str]:
    return ["--preset", "fast"] if route in g.IMAGE_ROUTES else []


def _split(form: str, gt: list) -> tuple[list, list]:
    """A form's arguments for ``vpr learn`` (the database's positions, kept in the map) and for ``vpr localize`` (the
    query's), where one run would give both."""
    if form in ("positions", "tum", "kitti"):
        return ["--gt", gt[1]], ["--gt", gt[2], *gt[3:]]
    if form in ("positions-combined", "names"):
        return ["--gt", gt[1]], gt
    if form == "gt-topic":
        return ["--gt-topic", gt[1]], gt
    return [], gt


def _dbq(command, route, form, scenes, tmp_path, capsys):
    offset = 0 if form == "tolerance" else g.OFFSET  # frame-aligned traverses
    s = scenes(route, offset, utm=form == "names")
    gt = g.db_query_gt(form, tmp_path, route, s["srcs"], offset)
    db, q = s["db"], s["query"]
    out = tmp_path / "o"
    prefix_db, prefix_q = db[1:], q[1:]  # --db-prefix / --query-prefix of one .h5
    if command == "match":
        _run(["match", db[0], q[0], *prefix_db, *prefix_q, "--out", out, "--method", "pairwise", *_preset(route),
              *gt], capsys)
        method = "pairwise"
    elif command == "localize":
        _run(["localize", db[0], q[0], *prefix_db, *prefix_q, "--out", out, *_preset(route), *gt], capsys)
        method = "rshosm-seq"
    else:
        learn_gt, query_gt = _split(form, gt)
        _run(["learn", db[0], *prefix_db, "--out", tmp_path / "map.npz", *_preset(route), *learn_gt], capsys)
        _run(["localize", tmp_path / "map.npz", q[0], *prefix_q, "--out", out, *query_gt], capsys)
        method = "rshosm-seq"
    return out, method, g.oracle(offset)


CASES = [(c, r, "positions") for c in DBQ_COMMANDS for r in g.ROUTES]  # each input's own positions file
CASES += [(c, "folder", f) for c in DBQ_COMMANDS for f in g.FORMS if f != "positions" and not g.applies(f, "folder")]
CASES += [(c, r, f) for c in DBQ_COMMANDS for r in ("video", "bag") for f in ("tum", "gt-topic")
          if not g.applies(f, r)]
CASES += [("match", r, f) for r in ("list", "h5", "h5-prefix", "npy") for f in ("names", "pairs-names", "tolerance",
                                                                                  "gthard")
          if not g.applies(f, r)]


@pytest.mark.parametrize("command,route,form", CASES, ids=["-".join(c) for c in CASES])
def test_every_query_frame_is_scored_against_the_oracles_frame(command, route, form, scenes, tmp_path, capsys):
    out, method, truth = _dbq(command, route, form, scenes, tmp_path, capsys)
    assert _truth(out, method) == truth.tolist()
    assert _with_match(out, method) == truth.size


def test_every_form_and_route_is_in_the_table():
    """The table holds every route (each with its own positions, in every command) and every form."""
    assert {r for c, r, f in CASES if f == "positions"} == set(g.ROUTES)
    assert {c for c, r, f in CASES} == set(DBQ_COMMANDS)
    assert {f for c, r, f in CASES} == set(g.FORMS)


@pytest.mark.parametrize("form", ["pairs", "tolerance", "gthard"])
def test_a_query_on_stdin_and_a_resumed_one_are_scored_against_the_oracle(form, scenes, tmp_path, capsys,
                                                                           monkeypatch):
    offset = 0 if form == "tolerance" else g.OFFSET
    s = scenes("folder", offset)
    gt = g.db_query_gt(form, tmp_path, "folder", s["srcs"], offset)
    _run(["learn", s["db"][0], "--out", tmp_path / "map.npz", "--preset", "fast"], capsys)
    paths = sorted(str(p) for p in (s["root"] / "query").glob("*.png"))
    _run(["localize", tmp_path / "map.npz", "-", "--out", tmp_path / "whole", *gt], capsys, "\n".join(paths) + "\n",
         monkeypatch)
    truth = g.oracle(offset).tolist()
    assert _truth(tmp_path / "whole", "rshosm-seq") == truth
    # stopped after fewer frames than the answers lag: every frame read waits in the state, answered on resuming
    err = _run(["localize", tmp_path / "map.npz", "-", "--out", tmp_path / "a", "--state-out", tmp_path / "s.npz",
                *gt], capsys, "\n".join(paths[:5]) + "\n", monkeypatch)
    assert "5 frames wait in the state" in err and not (tmp_path / "a" / "rshosm-seq").exists()
    _run(["localize", tmp_path / "s.npz", "-", "--out", tmp_path / "b", *gt], capsys,
         "\n".join(paths[5:]) + "\n", monkeypatch)
    assert _truth(tmp_path / "b", "rshosm-seq") == truth


# ------------------------------------------------------------------ loop closure
@pytest.fixture(scope="module")
def streams(tmp_path_factory):
    """``streams(route, utm)``: the database then the query as one stream of ``route`` (cached): its arguments,
    and the two as sessions (folders)."""
    cache = {}

    def get(route: str, utm: bool = False):
        key = (route, utm)
        if key not in cache:
            root = tmp_path_factory.mktemp(f"loop-{route}{'-utm' if utm else ''}")
            imgs = g.images("db") + g.images("query")
            xy = np.r_[g.positions("db"), g.positions("query")]
            cache[key] = {"run": g.write_route(route, root, "run", imgs, xy, utm=utm), "root": root}
        return cache[key]

    return get


LOOP_CASES = [("loops", r, "positions") for r in g.LOOP_ROUTES]
LOOP_CASES += [("loops", "folder", f) for f in g.LOOP_FORMS if f != "positions" and not g.loop_applies(f, "folder")]
LOOP_CASES += [("loops", "bag", f) for f in ("tum", "gt-topic")]
LOOP_CASES += [("loops -", "folder", f) for f in ("pairs", "npy", "bmp", "mat")]


@pytest.mark.parametrize("command,route,form", LOOP_CASES, ids=["-".join(c) for c in LOOP_CASES])
def test_every_frame_of_a_stream_is_scored_against_the_oracles_earlier_frame(command, route, form, streams, tmp_path,
                                                                            capsys, monkeypatch):
    s = streams(route, utm=form == "names")
    gt = g.loop_gt(form, tmp_path, route)
    out = tmp_path / "o"
    common = ["--out", out, "--exclude", 10, *_preset(route), *gt]
    if command == "loops":
        _run(["loops", s["run"][0], *common], capsys)
    else:
        paths = sorted(str(p) for p in (s["root"] / "run").glob("*.png"))
        _run(["loops", "-", *common], capsys, "\n".join(paths) + "\n", monkeypatch)
    truth = g.loop_oracle()
    assert _truth(out, "rshosm-seq") == truth.tolist()
    assert _with_match(out, "rshosm-seq") == int((truth >= 0).sum())


def test_every_loop_form_and_route_is_in_the_table():
    assert {r for c, r, f in LOOP_CASES if f == "positions"} == set(g.LOOP_ROUTES)
    assert {f for c, r, f in LOOP_CASES} == set(g.LOOP_FORMS)


@pytest.mark.parametrize("combined", [False, True], ids=["a-file-each", "one-file"])
def test_the_sessions_of_a_stream_are_scored_against_the_oracle(combined, scenes, tmp_path, capsys):
    s = scenes("folder")
    sessions = [s["db"][0], s["query"][0]]
    xy = {r: g.positions(r) for r in ("db", "query")}
    if combined:
        rows = [(s["srcs"][r]["traverse"], k, *p) for r in ("db", "query") for k, p in enumerate(xy[r])]
        gt = ["--gt", g._csv(tmp_path / "both.csv", ["traverse", "frame", "x", "y"], rows)]
    else:
        gt = ["--gt", *(g._csv(tmp_path / f"{r}.csv", ["frame", "x", "y"], [(k, *p) for k, p in enumerate(xy[r])])
                        for r in ("db", "query"))]
    out = tmp_path / "o"
    _run(["loops", *sessions, "--out", out, "--exclude", 10, "--preset", "fast", *gt, "--radius", g.RADIUS], capsys)
    assert _truth(out, "rshosm-seq") == g.loop_oracle().tolist()


@pytest.mark.parametrize("route", ["folder", "npy"])
def test_localize_given_the_database_scores_as_the_map_learned_from_it(route, scenes, tmp_path, capsys):
    s = scenes(route)
    gt = g.db_query_gt("positions", tmp_path, route, s["srcs"])
    _run(["localize", s["db"][0], s["query"][0], "--out", tmp_path / "db", *_preset(route), *gt], capsys)
    learn_gt, query_gt = _split("positions", gt)
    _run(["learn", s["db"][0], "--out", tmp_path / "map.npz", *_preset(route), *learn_gt], capsys)
    _run(["localize", tmp_path / "map.npz", s["query"][0], "--out", tmp_path / "map", *query_gt], capsys)

    def scored(out):
        m = json.loads((out / "metrics.json").read_text())["methods"]["rshosm-seq"]
        return {k: v for k, v in m.items() if k not in ("seconds", "latency_ms")}

    assert scored(tmp_path / "db") == scored(tmp_path / "map")
    assert scored(tmp_path / "db")["recall_at_1"] > 0.5
    # the map learned on the way is kept, and scores the same
    _run(["localize", tmp_path / "db" / "map.npz", s["query"][0], "--out", tmp_path / "again", *query_gt], capsys)
    assert scored(tmp_path / "again") == scored(tmp_path / "map")


def test_a_query_far_from_the_map_is_refused_before_any_work(scenes, tmp_path, capsys):
    s = scenes("npy")
    far = g._csv(tmp_path / "far.csv", ["frame", "x", "y"], [(k, x + 5000, y) for k, (x, y) in
                                                                enumerate(g.positions("query"))])
    db_csv = g._csv(tmp_path / "db.csv", ["frame", "x", "y"], [(k, *p) for k, p in enumerate(g.positions("db"))])
    for argv in (["localize", s["db"][0], s["query"][0], "--gt", db_csv, far],
                 ["match", s["db"][0], s["query"][0], "--gt", db_csv, far]):
        code = main([str(a) for a in [*argv, "--radius", g.RADIUS, "--out", tmp_path / "o", "--no-progress"]])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and "no query frame is within 1 of a database frame" in err, err
        assert not (tmp_path / "o").exists()
    _run(["learn", s["db"][0], "--out", tmp_path / "map.npz", "--gt", db_csv], capsys)
    code = main([str(a) for a in ["localize", tmp_path / "map.npz", s["query"][0], "--gt", far, "--radius", g.RADIUS,
                                  "--out", tmp_path / "o", "--no-progress"]])
    err = capsys.readouterr().err
    assert code == 2 and "no query frame is within 1" in err and not (tmp_path / "o").exists()
    # both files given with a map: the map keeps its own positions
    code = main([str(a) for a in ["localize", tmp_path / "map.npz", s["query"][0], "--gt", db_csv, far, "--radius",
                                  g.RADIUS, "--out", tmp_path / "o", "--no-progress"]])
    err = capsys.readouterr().err
    assert code == 2 and "keeps its frames' positions" in err and not (tmp_path / "o").exists()
