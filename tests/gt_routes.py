"""One oracle of the right frame, written as every input route and every ground-truth form of the field.

A scene of places 2 m apart along a line: the database passes places ``0 .. N_DB - 1``, the query places
``offset .. offset + N_Q - 1`` (0.3 m beside them), 10 frames a second. :func:`oracle` says which database frame
shows each query frame; a loop stream is the database then the query, one run (:func:`loop_oracle`). Every route
(:data:`ROUTES`: a folder, an image list, a video, a ROS bag, a ``.npy``, an hloc ``.h5``, one ``.h5`` for both)
writes the same frames, and every form (:data:`FORMS`) writes the same truth, from the oracle and the route's own
frame names and times only. A command scores right when its ground truth pairs each frame with the oracle's frame.
"""
from __future__ import annotations

import csv
from pathlib import Path

import cv2
import numpy as np

N_DB, N_Q = 30, 20
OFFSET = 5  # the query revisits places OFFSET .. OFFSET + N_Q - 1
SPACING = 2.0  # metres between places; a radius of 1 m holds one database frame
RADIUS = 1.0
SIZE = (32, 16)  # width, height
DT = 0.1  # seconds between frames (a video's first at 0 s, a bag's at tests.bags.T0)

#: the routes of a database x query run and of a loop stream
ROUTES = ("folder", "list", "video", "bag", "npy", "h5", "h5-prefix")
LOOP_ROUTES = ("folder", "list", "video", "bag", "npy", "h5")
IMAGE_ROUTES = ("folder", "list", "video", "bag")


def oracle(offset: int = OFFSET, n_q: int = N_Q) -> np.ndarray:
    """The database frame that shows each query frame."""
    return offset + np.arange(n_q)


def loop_oracle(offset: int = OFFSET) -> np.ndarray:
    """The earlier frame that each frame of the stream (the database, then the query) revisits, -1 for none."""
    return np.r_[np.full(N_DB, -1), oracle(offset)]


def places(role: str, offset: int = OFFSET) -> np.ndarray:
    return np.arange(N_DB) if role == "db" else oracle(offset)


def positions(role: str, offset: int = OFFSET) -> np.ndarray:
    """Each frame's (x, y) in metres."""
    p = places(role, offset).astype(np.float64)
    return np.stack([p * SPACING, np.full(p.size, 0.0 if role == "db" else 0.3)], axis=1)


def images(role: str, offset: int = OFFSET) -> list[np.ndarray]:
    """Each frame's image: its place's pattern, the query's darker and noisier."""
    out = []
    noise = np.random.default_rng(1 if role == "db" else 2)
    for p in places(role, offset):
        rng = np.random.default_rng(100 + int(p))
        base = cv2.resize(rng.integers(0, 256, (4, 8), dtype=np.uint8), SIZE, interpolation=cv2.INTER_NEAREST)
        img = base.astype(np.float32) * (1.0 if role == "db" else 0.8) + noise.normal(0, 6, base.shape)
        out.append(cv2.cvtColor(np.clip(img, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR))
    return out


def utm_name(xy, k: int) -> str:
    """A file name carrying its UTM position, as the VPR datasets name their images (``...@EAST@NORTH@...``), after
    its frame number (which orders a folder's frames)."""
    return f"{k:03d}@{500000 + xy[0]:.2f}@{4000000 + xy[1]:.2f}@.png"


def frame_names(route: str, role: str, n: int, utm=None) -> list[str]:
    """The frame names the route gives (as a source names them)."""
    if utm is not None:
        return [utm_name(xy, k) for k, xy in enumerate(utm)]
    if route in ("folder", "list"):
        return [f"img_{k:03d}.png" for k in range(n)]
    if route == "h5":
        return [f"{role}/img_{k:03d}.jpg" for k in range(n)]
    if route == "h5-prefix":
        return [f"{'db' if role == 'db' else 'query'}/img_{k:03d}.jpg" for k in range(n)]
    return None  # numbered by the source


def write_route(route: str, root: Path, name: str, imgs, xy, utm: bool = False) -> list[str]:
    """The frames ``imgs`` (at positions ``xy``, :data:`DT` apart) as ``route`` under ``root``, named ``name``;
    returns the arguments that give it to a command. ``utm``: the files named by their positions."""
    root.mkdir(parents=True, exist_ok=True)
    names = frame_names(route, name, len(imgs), xy if utm else None)
    if route in ("folder", "list"):
        folder = root / name
        folder.mkdir(exist_ok=True)
        for n, img in zip(names, imgs, strict=True):
            cv2.imwrite(str(folder / n), img)
        if route == "folder":
            return [str(folder)]
        lst = root / f"{name}.txt"
        lst.write_text("".join(f"{name}/{n}\n" for n in names))
        return [str(lst)]
    if route == "video":
        path = root / f"{name}.avi"
        w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 1.0 / DT, SIZE)
        for img in imgs:
            w.write(img)
        w.release()
        return [str(path)]
    if route == "bag":
        from tests.bags import write_bag

        return [str(write_bag(root / f"{name}.bag", imgs, xy, dt=DT))]
    desc = np.stack([cv2.cvtColor(i, cv2.COLOR_BGR2GRAY).ravel() for i in imgs]).astype(np.float32)
    if route == "npy":
        np.save(root / f"{name}.npy", desc)
        return [str(root / f"{name}.npy")]
    import h5py

    path = root / ("feats.h5" if route == "h5-prefix" else f"{name}.h5")
    with h5py.File(path, "a") as f:  # as hloc writes them: no order kept, names in natural order
        for n, d in zip(names, desc, strict=True):
            f.create_group(n).create_dataset("global_descriptor", data=d)
    return [str(path)]


# ------------------------------------------------------------------ ground-truth forms
def _csv(path: Path, header, rows) -> str:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        if header:
            w.writerow(header)
        w.writerows(rows)
    return str(path)


def _start(route: str) -> float:
    """The time of a route's first frame (a video's 0 s, a bag's its writer's)."""
    from tests.bags import T0

    return T0 if route == "bag" else 0.0


def _tum(path: Path, t, xy) -> str:
    path.write_text("".join(f"{a:.6f} {x:.3f} {y:.3f} 0 0 0 0 1\n" for a, (x, y) in zip(t, xy, strict=True)))
    return str(path)


def _kitti(path: Path, xy) -> str:
    path.write_text("".join(f"1 0 0 {x:.3f} 0 1 0 {y:.3f} 0 0 1 0\n" for x, y in xy))
    return str(path)


def _matrix(path: Path, m: np.ndarray) -> str:
    if path.suffix == ".npy":
        np.save(path, m)
    elif path.suffix == ".mat":
        import scipy.io

        scipy.io.savemat(path, {"GT": m.astype(np.uint8)})
    else:
        cv2.imwrite(str(path), m.astype(np.uint8) * 255)
    return str(path)


#: database x query forms: name -> what it needs of the route (``names``: the route's own file names; ``times``:
#: the frames' times; ``topic``: a bag)
FORMS = ("tolerance", "pairs", "pairs-names", "positions", "positions-combined", "names", "tum", "kitti",
         "gt-topic", "vpr-bench", "gthard", "mat")
#: loop forms
LOOP_FORMS = ("positions", "pairs", "npy", "bmp", "mat", "names", "tum", "kitti", "gt-topic")


def applies(form: str, route: str, loops: bool = False) -> str | None:
    """Why ``form`` cannot be given with ``route`` (None: it can)."""
    if form == "names" and route not in ("folder", "list", "h5"):
        return "UTM positions are read from file names: the route has none of its own"
    if form == "pairs-names" and frame_names(route, "db", 1) is None:
        return "the route's frames have no names of their own"
    if form == "tum" and route not in ("video", "bag"):
        return "a TUM trajectory is matched by time: the route has no times"
    if form == "gt-topic" and route != "bag":
        return "positions from a topic: a bag's"
    if form == "positions-combined" and route == "h5-prefix":
        return "one file's two traverses have no names of their own"
    return None


def db_query_gt(form: str, root: Path, route: str, srcs: dict, offset: int = OFFSET) -> list[str]:
    """The ground-truth arguments of ``form`` for a database x query run of ``route`` (``srcs``: role -> the names
    of its frames, and the traverse names the route gives them)."""
    truth = oracle(offset)
    xy = {r: positions(r, offset) for r in ("db", "query")}
    radius = ["--radius", RADIUS]
    if form == "tolerance":
        return ["--tolerance", 0]
    if form == "pairs":
        return ["--gt", _csv(root / "pairs.csv", ["query", "db"], [(j, d) for j, d in enumerate(truth)])]
    if form == "pairs-names":
        db, q = srcs["db"]["names"], srcs["query"]["names"]
        return ["--gt", _csv(root / "pairs.csv", ["query", "db"], [(q[j], db[d]) for j, d in enumerate(truth)])]
    if form == "positions":
        return ["--gt", *(_csv(root / f"{r}.csv", ["frame", "x", "y"], [(k, *p) for k, p in enumerate(xy[r])])
                          for r in ("db", "query")), *radius]
    if form == "positions-combined":
        rows = [(srcs[r]["traverse"], k, *p) for r in ("db", "query") for k, p in enumerate(xy[r])]
        return ["--gt", _csv(root / "both.csv", ["traverse", "frame", "x", "y"], rows), *radius]
    if form == "names":
        return ["--gt", "names", *radius]
    if form == "tum":
        starts = {r: _start(route) for r in xy}
        return ["--gt", *(_tum(root / f"{r}.tum", starts[r] + DT * np.arange(len(xy[r])), xy[r]) for r in xy),
                *radius]
    if form == "kitti":
        return ["--gt", *(_kitti(root / f"{r}.kitti.txt", xy[r]) for r in xy), *radius]
    if form == "gt-topic":
        return ["--gt-topic", "/odom", *radius]
    m = np.zeros((N_DB, len(truth)), bool)
    m[truth, np.arange(len(truth))] = True
    if form == "vpr-bench":
        rows = np.empty((len(truth), 2), dtype=object)
        for j, d in enumerate(truth):
            rows[j, 0], rows[j, 1] = j, [int(d)]
        np.save(root / "ground_truth_new.npy", rows, allow_pickle=True)
        return ["--gt", str(root / "ground_truth_new.npy")]
    return ["--gt", _matrix(root / ("GThard.npy" if form == "gthard" else "gt.mat"), m)]


def loop_gt(form: str, root: Path, route: str, names=None, offset: int = OFFSET) -> list[str]:
    """The ground-truth arguments of ``form`` for the loop stream of ``route`` (``names``: its frames' names)."""
    truth = loop_oracle(offset)
    xy = np.r_[positions("db", offset), positions("query", offset)]
    radius = ["--radius", RADIUS]
    if form == "positions":
        return ["--gt", _csv(root / "pos.csv", ["frame", "x", "y"], [(k, *p) for k, p in enumerate(xy)]), *radius]
    if form == "pairs":
        rows = [(t, e) for t, e in enumerate(truth) if e >= 0]
        return ["--gt", _csv(root / "loops.csv", ["frame", "earlier"], rows)]
    if form == "names":
        return ["--gt", "names", *radius]
    if form == "tum":
        start = _start(route)
        return ["--gt", _tum(root / "run.tum", start + DT * np.arange(len(xy)), xy), *radius]
    if form == "kitti":
        return ["--gt", _kitti(root / "run.kitti.txt", xy), *radius]
    if form == "gt-topic":
        return ["--gt-topic", "/odom", *radius]
    m = np.zeros((truth.size, truth.size), bool)
    t = np.flatnonzero(truth >= 0)
    m[t, truth[t]] = True  # row = frame, column = earlier frame (RTAB-Map's loop_gt.bmp)
    return ["--gt", _matrix(root / f"loop_gt.{form}", m)]


def loop_applies(form: str, route: str) -> str | None:
    return applies(form, route) if form in ("names", "tum", "gt-topic") else None
