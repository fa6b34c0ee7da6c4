"""Tests of the procedural renderer (vpr.render): specs, renders, ground truth, output files."""
from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipelines.cli import main as cli_main
from vpr.imageproc import seqslam_preprocess
from vpr.render import builtin_spec_path, builtin_specs, gt_matrix, load_spec, loop_pairs, render_scene, write_scene
from vpr.render.engine import plan_traverse
from vpr.render.world import build_world, route_polyline

SMALL = (64, 48)
BUILTINS = ["two_seasons", "loop_revisits", "aliased_corridor", "speed_change"]


def _desc(images):
    d = np.stack([seqslam_preprocess(im).ravel() for im in images])
    return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)


@pytest.fixture(scope="module")
def two_seasons(rendered):
    return rendered("two_seasons", SMALL, 50)


@pytest.fixture(scope="module")
def loop_scene(rendered):
    return rendered("loop_revisits", SMALL, 120)


# ----------------------------------------------------------------------------- specs

def test_builtin_specs_exist_and_resolve():
    names = builtin_specs()
    for n in BUILTINS:
        assert n in names
        p = builtin_spec_path(n)
        assert p.is_file() and p.suffix == ".json"
        s = load_spec(n)
        assert s == load_spec(p) == load_spec(json.loads(p.read_text()))
        assert s["name"] == n and s["traverses"]
        for t in s["traverses"]:
            assert set(t["conditions"]) >= {"time", "season", "weather", "gain", "gamma", "noise", "blur", "fog"}
    two = load_spec("two_seasons")
    conds = [(t["conditions"]["season"], t["conditions"]["time"]) for t in two["traverses"]]
    assert ("summer", "day") in conds and ("winter", "night") in conds
    assert load_spec("loop_revisits")["world"]["loop"] and load_spec("loop_revisits")["traverses"][0]["laps"] > 1
    assert load_spec("aliased_corridor")["world"]["kind"] == "corridor"
    assert load_spec("aliased_corridor")["world"]["aliasing"]
    sc = load_spec("speed_change")["traverses"]
    assert sc[0]["conditions"] == sc[1]["conditions"] and sc[0]["speed"] != sc[1]["speed"]


def test_unknown_builtin_lists_available():
    with pytest.raises(FileNotFoundError, match="two_seasons"):
        builtin_spec_path("no_such_scene")
    with pytest.raises(FileNotFoundError):
        load_spec("no_such_scene")


def _write(tmp_path, obj, name="bad.json"):
    p = tmp_path / name
    p.write_text(json.dumps(obj) if not isinstance(obj, str) else obj)
    return p


@pytest.mark.parametrize("mutate, key", [
    (lambda s: s["world"].update(colour=1), "world.colour"),
    (lambda s: s.update(extra=1), "extra"),
    (lambda s: s["traverses"][0]["conditions"].update(sesaon="winter"), "conditions.sesaon"),
    (lambda s: s["traverses"][0]["speed"].update(mean=-2.0), "speed.mean"),
    (lambda s: s["traverses"][0]["speed"].update(mean="fast"), "speed.mean"),
    (lambda s: s["traverses"][0]["speed"].update(profile=[[10, -1.0]]), "speed.profile"),
    (lambda s: s["camera"].update(size=[8, 48]), "camera.size"),
    (lambda s: s["camera"].update(size=[64, "48"]), "camera.size"),
    (lambda s: s["camera"].update(fps=0), "camera.fps"),
    (lambda s: s["world"].update(seed=1.5), "world.seed"),
    (lambda s: s["world"].update(loop="yes"), "world.loop"),
    (lambda s: s["traverses"][0]["conditions"].update(time="noon"), "conditions.time"),
    (lambda s: s["traverses"][0].update(laps=2), "laps"),
    (lambda s: s.update(traverses=[]), "traverses"),
    (lambda s: s["traverses"][0]["conditions"].update(lane=7.0), "conditions.lane"),
    (lambda s: s["world"].update(half_width=2.0), "world.half_width"),
])
def test_bad_spec_names_key_and_file(tmp_path, mutate, key):
    s = json.loads(builtin_spec_path("two_seasons").read_text())
    mutate(s)
    p = _write(tmp_path, s)
    with pytest.raises(ValueError) as e:
        load_spec(p)
    assert key in str(e.value) and "bad.json" in str(e.value)


def test_bad_json_and_missing_file(tmp_path):
    with pytest.raises(ValueError, match="broken.json"):
        load_spec(_write(tmp_path, "{not json", "broken.json"))
    with pytest.raises(FileNotFoundError, match="missing.json"):
        load_spec(tmp_path / "missing.json")
    with pytest.raises(ValueError, match="spec"):
        load_spec(42)


def test_bad_overrides():
    with pytest.raises(ValueError, match="16"):
        render_scene("two_seasons", size=(15, 48), n_frames=2)
    with pytest.raises(ValueError, match="n_frames"):
        render_scene("two_seasons", size=SMALL, n_frames=0)
    with pytest.raises(ValueError, match="nope"):
        render_scene("two_seasons", size=SMALL, n_frames=2, traverses=["nope"])


# ----------------------------------------------------------------------------- rendering

def test_render_shapes_and_ground_truth(two_seasons):
    assert [t.name for t in two_seasons.traverses] == ["summer_day", "winter_night"]
    for t in two_seasons.traverses:
        assert t.images.shape == (50, 48, 64, 3) and t.images.dtype == np.uint8
        assert t.route_pos.shape == (50,) and t.xy.shape == (50, 2)
        assert np.all(np.diff(t.route_pos) >= 0)
        assert t.route_pos[0] == pytest.approx(0.0) and t.route_pos[-1] == pytest.approx(500.0)
        # metric positions follow the route: steps in xy match steps along the route
        step_xy = np.linalg.norm(np.diff(t.xy, axis=0), axis=1)
        step_s = np.diff(t.route_pos)
        assert np.allclose(step_xy, step_s, atol=0.5 + 0.05 * step_s.max())
        assert t.loop_length is None and np.array_equal(t.place_pos, t.route_pos)


def test_render_is_deterministic_and_seeded():
    a = render_scene("two_seasons", size=SMALL, n_frames=6, traverses=["summer_day"])
    b = render_scene("two_seasons", size=SMALL, n_frames=6, traverses=["summer_day"])
    c = render_scene("two_seasons", size=SMALL, n_frames=6, traverses=["summer_day"], seed=99)
    assert np.array_equal(a.traverses[0].images, b.traverses[0].images)
    assert np.array_equal(a.traverses[0].xy, b.traverses[0].xy)
    assert np.abs(a.traverses[0].images.astype(int) - c.traverses[0].images).mean() > 10


def test_frames_look_like_a_street(two_seasons):
    day, night = two_seasons["summer_day"].images, two_seasons["winter_night"].images
    g = day.mean(axis=(0, 3))
    # bright sky above the horizon in the middle, darker road below, on average
    assert g[:8, 24:40].mean() > g[-8:, 24:40].mean() + 40
    assert night.mean() < 0.6 * day.mean()
    # images are smooth (neighbouring pixels correlate), not noise
    d = day.astype(float)
    assert np.abs(np.diff(d, axis=2)).mean() < 0.3 * np.abs(d - d[:, ::-1, ::-1]).mean()
    # every frame has structure
    assert (day.reshape(50, -1).std(1) > 15).all()


def test_consecutive_frames_overlap_and_places_differ():
    t = render_scene("speed_change", size=SMALL, n_frames=200, traverses=["slow"]).traverses[0]
    D = _desc(t.images)
    S = D @ D.T
    moving = np.diff(t.route_pos) > 0.5  # about 2 m apart
    near = S[np.arange(199), np.arange(1, 200)][moving].mean()
    far = S[np.abs(t.route_pos[:, None] - t.route_pos[None, :]) > 80].mean()
    assert near > far + 0.12


def test_cross_condition_harder_than_same_condition():
    spec = load_spec("two_seasons")
    rerun = dict(spec["traverses"][0], name="rerun", seed=1234)
    spec["traverses"].append(rerun)
    scene = render_scene(spec, size=SMALL, n_frames=160)
    day, rr, night = scene["summer_day"], scene["rerun"], scene["winter_night"]

    def r1(db, q):
        S = _desc(db.images) @ _desc(q.images).T
        G = gt_matrix(db, q, 6.0)
        has = G.any(0)
        return G[S.argmax(0), np.arange(S.shape[1])][has].mean()

    same, cross = r1(day, rr), r1(day, night)
    assert same > 0.8
    assert 0.1 < cross < same


def test_conditions_change_appearance_not_geometry():
    base = load_spec("two_seasons")
    t0 = base["traverses"][0]
    variants = {"fog": {"weather": "fog"}, "rain": {"weather": "rain"}, "dusk": {"time": "dusk"},
                "autumn": {"season": "autumn"}, "blur": {"blur": 20.0}, "noise": {"noise": 20.0}}
    spec = json.loads(json.dumps(base))
    spec["traverses"] = [dict(t0, name="ref")]
    for n, c in variants.items():
        spec["traverses"].append(dict(t0, name=n, conditions=dict(t0["conditions"], **c)))
    for t in spec["traverses"]:
        for k in ("fog", "rain", "gain", "gamma", "noise", "lit_windows"):
            if k not in variants.get(t["name"], {}):
                t["conditions"].pop(k)  # let the presets of the changed time/weather apply
    sc = render_scene(spec, size=SMALL, n_frames=4)
    ref = sc["ref"]
    for n in variants:
        t = sc[n]
        assert np.array_equal(t.xy, ref.xy)
        assert np.abs(t.images.astype(int) - ref.images).mean() > 2, n
    # fog washes out contrast
    assert sc["fog"].images.std() < ref.images.std()
    # blur removes high frequencies
    lap = [cv2.Laplacian(cv2.cvtColor(im, cv2.COLOR_BGR2GRAY), cv2.CV_32F).var() for im in (sc["blur"].images[0],
                                                                                          ref.images[0])]
    assert lap[0] < 0.5 * lap[1]


def test_corridor_renders_with_ceiling():
    t = render_scene("aliased_corridor", size=SMALL, n_frames=5, traverses=["lights_on"]).traverses[0]
    assert t.images.shape == (5, 48, 64, 3)
    g = t.images.mean(axis=(0, 3))
    # lit ceiling (top) brighter than the far end of the corridor (centre)
    assert g[:6].mean() > g[20:26, 28:36].mean()


# ----------------------------------------------------------------------------- aliasing, loops, speed

def test_aliasing_repeats_walls_and_objects():
    spec = load_spec("aliased_corridor")
    w = build_world(spec["world"], 10.0, 10.0, spec["camera"]["max_depth"])
    for al in spec["world"]["aliasing"]:
        n = int(al["length"] * 10)
        cs, cd = int(round((al["source"] - w.zlo) * 10)), int(round((al["target"] - w.zlo) * 10))
        for side in range(2):
            assert np.array_equal(w.wall_alb[side][:, cs:cs + n], w.wall_alb[side][:, cd:cd + n])
        z = w.objects["z"]
        src = np.sort(z[(z >= al["source"]) & (z < al["source"] + al["length"])] - al["source"])
        dst = np.sort(z[(z >= al["target"]) & (z < al["target"] + al["length"])] - al["target"])
        assert len(src) and np.allclose(src, dst)
    # a place that is not aliased differs
    assert not np.array_equal(w.wall_alb[0][:, 1600:1900], w.wall_alb[0][:, 300:600])


def test_aliased_places_look_alike():
    t = render_scene("aliased_corridor", size=SMALL, n_frames=200, traverses=["lights_on"]).traverses[0]
    D = _desc(t.images)
    S = D @ D.T
    hits = []
    for p in np.arange(21.0, 46.0, 3.0):
        i = int(np.argmin(np.abs(t.place_pos - p)))
        s = np.where(np.abs(t.place_pos - p) > 5.0, S[i], -np.inf)
        best = t.place_pos[int(np.argmax(s))]
        hits.append(min(abs(best - p - 50.0), abs(best - p - 100.0)) < 5.0)
    # the best match of a place elsewhere on the route is one of its copies
    assert np.mean(hits) >= 0.7


def test_loop_revisits_ground_truth(loop_scene):
    t = loop_scene.traverses[0]
    L = t.loop_length
    assert L == pytest.approx(300.0)
    assert t.route_pos[-1] == pytest.approx(3 * L)
    assert np.allclose(t.place_pos, np.mod(t.route_pos, L))
    P = loop_pairs(t, radius=5.0)
    assert P.shape == (120, 120) and (P == P.T).all() and not P.diagonal().any()
    i, j = np.nonzero(P)
    assert len(i) > 50
    laps = np.abs(t.route_pos[i] - t.route_pos[j]) / L
    assert np.allclose(laps, np.round(laps), atol=0.1) and (np.round(laps) >= 1).all()
    # same xy at the same place of another lap (up to the lateral offset)
    k = np.argmin(np.abs(t.route_pos - 50.0))
    k2 = np.argmin(np.abs(t.route_pos - 350.0))
    assert np.linalg.norm(t.xy[k] - t.xy[k2]) < 3.0
    assert not loop_pairs(t, radius=5.0, exclude=4 * L).any()


def test_loop_closure_is_recognisable(loop_scene):
    t = loop_scene.traverses[0]
    D = _desc(t.images)
    first = t.route_pos < t.loop_length
    later = t.route_pos >= t.loop_length
    S = D[first] @ D[later].T
    best = np.nonzero(first)[0][S.argmax(0)]
    err = np.abs(t.place_pos[best] - t.place_pos[later])
    err = np.minimum(err, t.loop_length - err)
    assert np.mean(err < 10.0) > 0.7


def test_speed_profile_stops_and_frame_counts():
    spec = load_spec("speed_change")
    slow, fast = spec["traverses"]
    ps = plan_traverse(slow, spec["world"], spec["camera"])
    pf = plan_traverse(fast, spec["world"], spec["camera"])
    assert ps.n > 2 * pf.n
    fps = spec["camera"]["fps"]
    steps = np.diff(ps.route_pos)
    # stops: runs of (almost) zero motion, at least the stop duration long
    still = steps < 0.02
    assert still.sum() >= (3.0 + 2.0) * fps - 4
    at_stop = ps.route_pos[1:][still]
    assert np.any(np.abs(at_stop - 100) < 1.0) and np.any(np.abs(at_stop - 260) < 1.0)
    # the fast traverse speeds up where its profile says so
    sp = np.diff(pf.route_pos) * fps
    mid = (pf.route_pos[1:] > 140) & (pf.route_pos[1:] < 160)
    start = pf.route_pos[1:] < 20
    assert sp[mid].mean() > 1.15 * sp[start].mean()
    # n_frames keeps the path
    p10 = plan_traverse(slow, spec["world"], spec["camera"], n_frames=10)
    assert p10.n == 10 and p10.route_pos[-1] == pytest.approx(400.0)
    assert 400.0 - 2.0 < ps.route_pos[-1] <= 400.0
    with pytest.raises(ValueError):
        plan_traverse(slow, spec["world"], spec["camera"], n_frames=0)


def test_route_polyline_open_and_loop():
    xy = route_polyline(500.0, False, 3)
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    assert np.allclose(seg, 0.5, atol=1e-6)
    # an open route never comes back near itself
    far = np.linalg.norm(xy[:, None] - xy[None, ::10], axis=2)
    s = np.arange(len(xy)) * 0.5
    sep = np.abs(s[:, None] - s[None, ::10]) > 30
    assert far[sep].min() > 10
    lp = route_polyline(300.0, True, 3)
    assert np.linalg.norm(lp[0] - lp[600]) < 1e-6  # closed after 300 m


def test_gt_matrix_matches_brute_force(two_seasons):
    a, b = two_seasons.traverses
    G = gt_matrix(a, b, 7.5)
    D = np.linalg.norm(a.xy[:, None] - b.xy[None], axis=2)
    assert G.shape == (50, 50) and G.dtype == bool
    assert np.array_equal(G, D <= 7.5)
    assert np.array_equal(gt_matrix(a.xy, b.xy, 7.5), G)
    with pytest.raises(ValueError, match="radius"):
        gt_matrix(a, b, -1)


# ----------------------------------------------------------------------------- output

def test_write_scene_files(tmp_path):
    out = tmp_path / "render"
    s = write_scene("two_seasons", out, preview=True, video=True, size=SMALL, n_frames=12, progress=False)
    assert set(s["traverses"]) == {"summer_day", "winter_night"}
    for name in s["traverses"]:
        pngs = sorted((out / name).glob("*.png"))
        assert len(pngs) == 12
        img = cv2.imread(str(pngs[3]))
        assert img.shape == (48, 64, 3)
        cap = cv2.VideoCapture(str(out / f"{name}.mp4"))
        assert cap.isOpened() and int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 12
        cap.release()
    with open(out / "ground_truth.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0])[:5] == ["frame", "traverse", "route_pos", "x", "y"]
    assert len(rows) == 24
    scene = json.loads((out / "scene.json").read_text())
    assert scene["camera"]["size"] == [64, 48] and load_spec(scene) == scene
    sheet = cv2.imread(str(out / "contact_sheet.png"))
    assert sheet is not None and sheet.shape[0] > 2 * 48
    # the in-memory API renders the same frames and positions
    mem = render_scene("two_seasons", size=SMALL, n_frames=12)
    assert np.array_equal(cv2.imread(str(out / "winter_night" / "000005.png")), mem["winter_night"].images[5])
    r = [row for row in rows if row["traverse"] == "winter_night"][5]
    assert float(r["x"]) == pytest.approx(mem["winter_night"].xy[5, 0], abs=1e-3)
    # atomic writes leave no temporary files behind
    assert not [p for p in out.rglob(".*")]


def test_render_command(tmp_path, capsys):
    assert cli_main(["render", "loop_revisits", "--out", str(tmp_path / "o"), "--size", "32x24", "--frames", "5",
                     "--quiet"]) == 0
    assert "laps: 5 frames" in capsys.readouterr().out
    assert len(list((tmp_path / "o" / "laps").glob("*.png"))) == 5
    assert cli_main(["render", "loop_revisits", "--out", str(tmp_path / "p"), "--size", "32x24", "--frames", "60",
                     "--quiet"]) == 0
    with open(tmp_path / "p" / "loop_pairs.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    t = render_scene("loop_revisits", size=(32, 24), n_frames=60).traverses[0]
    P = np.triu(loop_pairs(t, 5.0))
    assert len(rows) == P.sum() > 0
    assert all(P[int(r["frame_a"]), int(r["frame_b"])] for r in rows)
    with pytest.raises(SystemExit):
        cli_main(["render", "x", "--out", "o", "--size", "big"])


# ----------------------------------------------------------------------------- property tests

@settings(max_examples=60, deadline=None)
@given(w=st.integers(-5, 100), h=st.integers(-5, 100), mean=st.floats(-5, 30, allow_nan=False))
def test_spec_size_and_speed_validation(w, h, mean):
    spec = {"camera": {"size": [w, h]}, "traverses": [{"name": "a", "speed": {"mean": mean}}]}
    if w < 16 or h < 16:
        with pytest.raises(ValueError, match="camera.size"):
            load_spec(spec)
    elif mean <= 0:
        with pytest.raises(ValueError, match="speed.mean"):
            load_spec(spec)
    else:
        s = load_spec(spec)
        assert s["camera"]["size"] == [w, h] and s["traverses"][0]["speed"]["mean"] == mean
