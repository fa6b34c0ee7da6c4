"""ROS bags written by the tests with rosbags (the library ``vpr`` reads them with): images and positions."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from vpr.groundtruth.trajectories import EARTH_RADIUS

#: Where the tests' GPS puts the origin of a route (latitude, longitude).
ORIGIN = (48.137, 11.575)
T0 = 1_700_000_000.0  # the first frame's time, s


def metres_to_latlon(xy, origin=ORIGIN) -> np.ndarray:
    """The inverse of :func:`vpr.groundtruth.trajectories.latlon_to_metres` about ``origin``."""
    xy = np.asarray(xy, np.float64)
    lat = origin[0] + np.degrees(xy[:, 1] / EARTH_RADIUS)
    lon = origin[1] + np.degrees(xy[:, 0] / (EARTH_RADIUS * np.cos(np.radians(origin[0]))))
    return np.stack([lat, lon], axis=1)


def _time(ts, t: float):
    sec = int(t)
    return ts.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9)))


def _header(ts, t: float, frame_id: str, ros1: bool):
    H = ts.types["std_msgs/msg/Header"]
    return H(seq=0, stamp=_time(ts, t), frame_id=frame_id) if ros1 else H(stamp=_time(ts, t), frame_id=frame_id)


def write_bag(path, images, xy=None, *, ros: int = 1, storage: str = "sqlite3", compressed: bool = False,
              encoding: str = "rgb8", gps: bool = True, odom: bool = True, dt: float = 0.1,
              pos_dt: float | None = None, topic: str = "/camera/image_raw", extra_image_topic: str | None = None,
              pos_start: int = 0, empty=(), no_fix=(), fmt: str = "png", more=None):
    """A bag of ``images`` (BGR) on ``topic`` at ``dt`` s, with NavSatFix (``/gps/fix``) and Odometry (``/odom``)
    of positions ``xy`` (metres; sampled every ``pos_dt`` s, default: with the frames) over the same time span.

    ``ros`` 1: a ``.bag`` file; 2: a bag folder (``storage`` ``"sqlite3"`` or ``"mcap"``); ``pos_start``: the
    positions begin at that frame's time (a GPS that gets its fix late); ``empty``: numbers of the frames written as
    compressed images of 0 bytes (a camera driver's dropped frame); ``no_fix``: numbers of the position samples
    whose NavSatFix has no fix (status -1, as a GPS receiver publishes in a tunnel); ``fmt``: the compressed
    format (``"16UC1; compressedDepth png"``: a 12-byte header and a 16-bit PNG, as compressed_depth_image_transport
    writes); ``more``: {topic: (images, encoding)} written beside, at the same times (a depth camera, a second
    camera). Returns the path.
    """
    from rosbags.typesys import Stores, get_typestore

    ros1 = ros == 1
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    ser = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    path = Path(path)
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        writer = Writer(path, version=9, storage_plugin=plugin)
    Image = ts.types["sensor_msgs/msg/Image"]
    Compressed = ts.types["sensor_msgs/msg/CompressedImage"]
    msgs = []  # (time, connection name, message, type)

    def raw(img, enc, t):
        if enc == "rgb8":
            arr = img[:, :, ::-1]
        elif enc == "mono8":
            arr = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        else:
            arr = img
        arr = np.ascontiguousarray(arr)
        ch = 1 if arr.ndim == 2 else arr.shape[2]
        return Image(header=_header(ts, t, "cam", ros1), height=arr.shape[0], width=arr.shape[1], encoding=enc,
                     is_bigendian=0, step=arr.shape[1] * ch * arr.itemsize, data=arr.view(np.uint8).ravel())

    for i, img in enumerate(images):
        t = T0 + i * dt
        if compressed:
            ok, buf = cv2.imencode(".png", img)
            assert ok
            data = buf.ravel() if "compressedDepth" not in fmt else np.r_[np.zeros(12, np.uint8), buf.ravel()]
            data = np.zeros(0, np.uint8) if i in empty else data
            m = Compressed(header=_header(ts, t, "cam", ros1), format=fmt, data=data)
            msgs.append((t, "img", m, Compressed.__msgtype__))
        else:
            msgs.append((t, "img", raw(img, encoding, t), Image.__msgtype__))
    topics = {"img": topic, "gps": "/gps/fix", "odom": "/odom"}
    for k, (other, (imgs, enc)) in enumerate((more or {}).items()):
        topics[f"more{k}"] = other
        msgs += [(T0 + i * dt, f"more{k}", raw(img, enc, T0 + i * dt), Image.__msgtype__) for i, img in enumerate(imgs)]
    if xy is not None:
        xy = np.asarray(xy, np.float64)
        frame_t = T0 + np.arange(len(images)) * dt
        frame_t, xy = frame_t[pos_start:], xy[pos_start:]
        if pos_dt is None:
            pos_t, pos_xy = frame_t, xy
        else:
            pos_t = np.arange(frame_t[0], frame_t[-1] + 1e-9, pos_dt)
            pos_xy = np.stack([np.interp(pos_t, frame_t, xy[:, d]) for d in range(2)], axis=1)
        latlon = metres_to_latlon(pos_xy)
        Fix, Status = ts.types["sensor_msgs/msg/NavSatFix"], ts.types["sensor_msgs/msg/NavSatStatus"]
        Odom = ts.types["nav_msgs/msg/Odometry"]
        geo = "geometry_msgs/msg/"
        for j, (t, (x, y), (lat, lon)) in enumerate(zip(pos_t, pos_xy, latlon, strict=True)):
            if gps:
                m = Fix(header=_header(ts, t, "gps", ros1), status=Status(status=-1 if j in no_fix else 0, service=1),
                        latitude=lat,
                        longitude=lon, altitude=500.0, position_covariance=np.zeros(9), position_covariance_type=0)
                msgs.append((t, "gps", m, Fix.__msgtype__))
            if odom:
                pose = ts.types[geo + "Pose"](position=ts.types[geo + "Point"](x=x, y=y, z=0.0),
                                             orientation=ts.types[geo + "Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
                twist = ts.types[geo + "Twist"](linear=ts.types[geo + "Vector3"](x=0.0, y=0.0, z=0.0),
                                               angular=ts.types[geo + "Vector3"](x=0.0, y=0.0, z=0.0))
                m = Odom(header=_header(ts, t, "odom", ros1), child_frame_id="base",
                         pose=ts.types[geo + "PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
                         twist=ts.types[geo + "TwistWithCovariance"](twist=twist, covariance=np.zeros(36)))
                msgs.append((t, "odom", m, Odom.__msgtype__))
    with writer as w:
        conns = {}
        for _, key, _, typ in msgs:
            if key not in conns:
                conns[key] = w.add_connection(topics[key], typ, typestore=ts)
        if extra_image_topic:
            conns["extra"] = w.add_connection(extra_image_topic, Image.__msgtype__, typestore=ts)
        for t, key, m, typ in sorted(msgs, key=lambda r: r[0]):
            w.write(conns[key], int(round(t * 1e9)), ser(m, typ))
    return path


def read_folder(folder) -> list[np.ndarray]:
    return [cv2.imread(str(p)) for p in sorted(Path(folder).glob("*.png"))]


def positions_of(gt_csv, traverse) -> np.ndarray:
    """The (x, y) of each frame of ``traverse`` in a rendered scene's ``ground_truth.csv``, in frame order."""
    import csv

    with open(gt_csv) as fh:
        rows = [r for r in csv.DictReader(fh) if r["traverse"] == traverse]
    return np.array([(float(r["x"]), float(r["y"])) for r in sorted(rows, key=lambda r: int(r["frame"]))])
