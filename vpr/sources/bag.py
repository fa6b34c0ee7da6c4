"""A ROS bag as a frame source: the images of one camera topic, and the positions of a GPS or odometry topic."""
from __future__ import annotations

import hashlib
import warnings
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from vpr.imageproc import depth_bits

from .base import Frame, Source, check_fps, check_positive_int, natural_key, stat_token
from .salvage import scan_mcap, scan_ros1

__all__ = ["BagSource", "is_bag", "ENCODINGS", "DEPTH_ENCODINGS", "IMAGE_TYPES", "POSITION_TYPES",
           "decode_image_msg", "depth_of"]

#: Message types read as frames.
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
#: Message types read as positions (:meth:`BagSource.trajectory`).
POSITION_TYPES = ("sensor_msgs/msg/NavSatFix", "nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped",
                  "geometry_msgs/msg/PoseWithCovarianceStamped")

#: ``sensor_msgs/Image`` encodings read, and how they become BGR (cv_bridge's conventions).
ENCODINGS = {
    "bgr8": None, "8uc3": None, "rgb8": cv2.COLOR_RGB2BGR, "bgra8": cv2.COLOR_BGRA2BGR, "8uc4": cv2.COLOR_BGRA2BGR,
    "rgba8": cv2.COLOR_RGBA2BGR, "mono8": None, "8uc1": None, "mono16": None, "16uc1": None,
    "bayer_rggb8": cv2.COLOR_BayerBG2BGR, "bayer_bggr8": cv2.COLOR_BayerRG2BGR,
    "bayer_gbrg8": cv2.COLOR_BayerGR2BGR, "bayer_grbg8": cv2.COLOR_BayerGB2BGR,
    "yuv422": cv2.COLOR_YUV2BGR_UYVY, "uyvy": cv2.COLOR_YUV2BGR_UYVY, "yuv422_yuy2": cv2.COLOR_YUV2BGR_YUY2,
    "yuyv": cv2.COLOR_YUV2BGR_YUY2, "32fc1": None,
}
_CHANNELS = {"bgr8": 3, "8uc3": 3, "rgb8": 3, "bgra8": 4, "8uc4": 4, "rgba8": 4, "yuv422": 2, "uyvy": 2,
             "yuv422_yuy2": 2, "yuyv": 2}

_STORAGE = (".db3", ".mcap")


def is_bag(path) -> bool:
    """Whether ``path`` is a ROS bag: a ``.bag`` (or ``.bag.active``), ``.mcap`` or ``.db3`` file, or a folder with
    ``metadata.yaml`` or ``.db3`` / ``.mcap`` files (a ROS 2 recording killed before it wrote its metadata)."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").is_file() or any(f.suffix.lower() in _STORAGE for f in p.iterdir())
    return p.suffix.lower() in (".bag", *_STORAGE) or p.name.lower().endswith(".bag.active")


def _storage_files(path: Path) -> list[Path]:
    """The files a reader opens: the bag itself, a ROS 2 folder, or the storage files of a folder without
    ``metadata.yaml`` (said with a warning: its message counts and time span are read from the files)."""
    if not path.is_dir() or (path / "metadata.yaml").is_file():
        return [path]
    files = sorted((f for f in path.iterdir() if f.suffix.lower() in _STORAGE), key=lambda f: natural_key(f.name))
    warnings.warn(f"{path}: no metadata.yaml (a ROS 2 recording killed before it wrote it); read its "
                  f"{len(files)} storage file{'s' if len(files) > 1 else ''} ({', '.join(f.name for f in files)})",
                  UserWarning, stacklevel=4)
    return files


def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)  # for bags without their own message definitions (ROS 2)


def _stamp_name(topic: str, t_ns: int) -> str:
    return f"{topic}@{t_ns // 1_000_000_000}.{t_ns % 1_000_000_000:09d}"


def _short(msgtype: str) -> str:
    return msgtype.replace("/msg/", "/")


def _listing(topics: dict[str, tuple[str, int]]) -> str:
    return ", ".join(f"{t} ({_short(typ)}, {n})" for t, (typ, n) in sorted(topics.items())) or "none"


#: Encodings and compressed formats of depth images: a depth topic is not taken unless it is named.
DEPTH_ENCODINGS = ("16uc1", "32fc1")


def depth_of(msg, msgtype: str) -> str | None:
    """The encoding or format of a depth image message (``"16UC1"``, ``"compressedDepth"``), else None."""
    if msgtype.endswith("CompressedImage"):
        return "compressedDepth" if "compresseddepth" in str(msg.format).lower() else None
    enc = str(msg.encoding)
    return enc if enc.lower() in DEPTH_ENCODINGS else None


def _unread_format(reason: str) -> bool:
    """Whether a decoding failure is of the topic's format (every frame would fail) rather than of one frame."""
    return "encoding" in reason or "format" in reason


#: Compressed formats OpenCV has no decoder for, and what to do instead.
_UNREAD_FORMATS = {"qoi": "QOI has no decoder in OpenCV; republish with image_transport's jpeg or png"}


def decode_image_msg(msg, msgtype: str) -> tuple[np.ndarray | None, str]:
    """A BGR (or grey / 16-bit, which :func:`vpr.imageproc.to_bgr` converts) image of one message, or the reason."""
    data = np.frombuffer(bytes(msg.data), np.uint8) if not isinstance(msg.data, np.ndarray) else msg.data
    if msgtype.endswith("CompressedImage"):
        fmt = str(msg.format)
        if data.size == 0:
            return None, f"empty compressed image ({fmt or 'no format'}, 0 bytes)"
        low = fmt.lower()
        unread = next((why for key, why in _UNREAD_FORMATS.items() if key in low), None)
        if unread:
            return None, f"compressed format {fmt!r} is not read: {unread}"
        flags = cv2.IMREAD_COLOR
        if "compresseddepth" in low:  # compressed_depth_image_transport: a 12-byte header, then a 16-bit PNG
            if "png" not in low:
                return None, f"compressed format {fmt!r} is not read (compressedDepth is read as PNG only)"
            data, flags = data[12:], cv2.IMREAD_ANYDEPTH
        try:
            img = cv2.imdecode(np.ascontiguousarray(data, np.uint8), flags)
        except cv2.error:
            img = None
        return (img, "") if img is not None else (None, f"compressed image ({fmt}) could not be decoded")
    enc = str(msg.encoding).lower()
    if enc not in ENCODINGS:
        return None, f"image encoding {msg.encoding!r} is not read (read: {', '.join(sorted(ENCODINGS))})"
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if h < 1 or w < 1 or data.size < h * step:
        return None, f"a {w} x {h} image of {data.size} bytes (step {step}): truncated"
    rows = np.asarray(data[: h * step], np.uint8).reshape(h, step)
    if enc in ("mono16", "16uc1"):
        img = rows[:, : 2 * w].copy().view(">u2" if msg.is_bigendian else "<u2").astype(np.uint16)
    elif enc == "32fc1":  # depth in metres, read only when its topic is named: 0..65.535 m as 16-bit millimetres
        m = rows[:, : 4 * w].copy().view(">f4" if msg.is_bigendian else "<f4")
        img = np.clip(np.nan_to_num(m, nan=0.0, posinf=0.0, neginf=0.0) * 1000.0, 0, 65535).astype(np.uint16)
    else:
        img = rows[:, : w * _CHANNELS.get(enc, 1)].reshape(h, w, -1) if enc in _CHANNELS else rows[:, :w]
        code = ENCODINGS[enc]
        img = cv2.cvtColor(np.ascontiguousarray(img), code) if code is not None else np.ascontiguousarray(img)
    return img, ""


class BagSource(Source):
    """The images of one topic of a ROS bag (``.bag``, ``.db3``, ``.mcap`` or a ROS 2 folder; ``docs/internals.md``).

    ``topic``: default the bag's only image topic; ``fps``, ``step``, ``max_frames`` as for a video (``fps`` by the
    messages' times). A missing path raises FileNotFoundError; an unreadable bag, an unknown or non-image topic (the
    image topics listed) or an encoding not read ValueError.
    """

    kind = "bag"
    carries = frozenset({"stamps", "positions"})
    sequential = True
    options = frozenset({"fps", "step", "max_frames", "topic"})

    @classmethod
    def accepts(cls, path: Path) -> bool:
        return is_bag(path)

    def __init__(self, path, topic: str | None = None, fps=None, step=None, max_frames=None):
        super().__init__(path)
        if fps is not None and step is not None:
            raise ValueError("give either fps or step, not both")
        if fps is not None and not (isinstance(fps, (int, float)) and not isinstance(fps, bool) and fps > 0
                                    and np.isfinite(fps)):
            raise ValueError(f"fps must be a positive number, got {fps!r}")
        self.fps = None if fps is None else float(fps)
        self.step = check_positive_int(step, "step")
        self.max_frames = check_positive_int(max_frames, "max_frames")
        if not self.path.exists():
            raise FileNotFoundError(f"no such bag: {self.path}")
        self._files = _storage_files(self.path)
        self._scan: tuple | None = None
        topics = self._topics()
        images = {t: (typ, n) for t, (typ, n) in topics.items() if typ in IMAGE_TYPES}
        if topic is None:
            topic = self._camera_topic(topics, images)
        elif topic not in topics:
            raise ValueError(f"{self.path}: no topic {topic!r}; topics: {_listing(topics)}")
        elif topic not in images:
            raise ValueError(f"{self.path}: topic {topic} holds {_short(topics[topic][0])}, not images (image topics: "
                             f"{', '.join(sorted(images)) or 'none'})")
        self.topic = topic
        self.msgtype = topics[topic][0]
        self._times = np.asarray([t for t, _ in self._raw(topic, data=False)], np.int64)
        if self._times.size == 0:
            raise ValueError(f"{self.path}: topic {topic} has no messages")
        first = next(self._messages(topic))[1]
        img, reason = decode_image_msg(first, self.msgtype)
        if img is None and _unread_format(reason):
            raise ValueError(f"{self.path}: topic {topic}: {reason}")
        if img is not None and img.dtype == np.uint16:
            self._bits = depth_bits(img)
        span = (self._times[-1] - self._times[0]) / 1e9
        check_fps(self.path, self.fps, (self._times.size - 1) / span if span > 0 else None)
        self._sel = self._select()
        self._only: np.ndarray | None = None

    def _camera_topic(self, topics, images) -> str:
        """The bag's only image topic that is not depth (:func:`depth_of`), or a refusal listing what there is."""
        if not images:
            raise ValueError(f"{self.path}: no image topic (sensor_msgs/Image or CompressedImage); topics: "
                             f"{_listing(topics)}")
        depth = {}
        for t in images:
            first = next(self._messages(t), None)
            kind = depth_of(first[1], images[t][0]) if first is not None else None
            if kind:
                depth[t] = kind
        cameras = sorted(set(images) - set(depth))
        if len(cameras) == 1:
            return cameras[0]
        if not cameras:
            listing = ", ".join(f"{t} ({k})" for t, k in sorted(depth.items()))
            raise ValueError(f"{self.path}: its only image topics hold depth ({listing}), not an appearance camera; "
                             "name one with --topic to read it anyway")
        listing = ", ".join(f"{t} ({images[t][1]} messages)" for t in cameras)
        raise ValueError(f"{self.path}: {len(cameras)} image topics ({listing}); name one with --topic")

    # ------------------------------------------------------------- reading
    def _reader(self):
        from rosbags.highlevel import AnyReader

        return AnyReader(self._files, default_typestore=_typestore())

    def _topics(self) -> dict[str, tuple[str, int]]:
        from rosbags.highlevel import AnyReaderError

        try:
            with self._reader() as r:
                out: dict[str, tuple[str, int]] = {}
                for c in r.connections:
                    typ, n = out.get(c.topic, (c.msgtype, 0))
                    out[c.topic] = (typ, n + c.msgcount)
                return out
        except (AnyReaderError, OSError, ValueError, KeyError) as e:
            return self._salvage(e)

    def _salvage(self, error) -> dict[str, tuple[str, int]]:
        """Read what is complete of a recording the readers refuse (:mod:`vpr.sources.salvage`), with a warning."""
        ros1 = self._ros1()
        if not (ros1 or all(f.suffix.lower() == ".mcap" for f in self._files)):
            raise ValueError(f"{self.path}: not a readable ROS bag ({error})") from None
        conns: dict[int, tuple[str, str]] = {}
        msgs: list[tuple[int, int, bytes]] = []
        for k, f in enumerate(self._files):  # connection ids of each file apart
            try:
                c, m = (scan_ros1 if ros1 else scan_mcap)(f)
            except ValueError as e2:
                raise ValueError(f"{self.path}: not a readable ROS bag ({e2})") from None
            conns.update({(k << 32) + cid: v for cid, v in c.items()})
            msgs += [((k << 32) + cid, t, raw) for cid, t, raw in m]
        msgs.sort(key=lambda m: m[1])
        self._scan = (conns, msgs)
        self.salvaged = {"damage": str(error), "messages_read": len(msgs)}
        warnings.warn(f"{self.path}: damaged or cut short ({error}); read its {len(msgs)} complete messages",
                      UserWarning, stacklevel=4)
        counts: dict[str, tuple[str, int]] = {}
        for cid, _, _ in msgs:
            t, typ = conns.get(cid, ("?", "?"))
            counts[t] = (typ, counts.get(t, (typ, 0))[1] + 1)
        return counts

    def _ros1(self) -> bool:
        return self.path.is_file() and self.path.name.lower().endswith((".bag", ".bag.active"))

    def _raw(self, topic: str, data: bool = True, start: int | None = None, stop: int | None = None):
        """(time ns, raw bytes or None) of ``topic``'s messages in time order, within [start, stop)."""
        if self._scan is not None:
            conns, msgs = self._scan
            ids = {cid for cid, (t, _) in conns.items() if t == topic}
            for cid, t, raw in msgs:
                if cid in ids and (start is None or t >= start) and (stop is None or t < stop):
                    yield t, raw if data else None
            return
        with self._reader() as r:
            cons = [c for c in r.connections if c.topic == topic]
            for _, t, raw in r.messages(connections=cons, start=start, stop=stop):
                yield t, raw if data else None

    def _messages(self, topic: str, start: int | None = None, stop: int | None = None):
        """(time ns, message) of ``topic``, deserialised."""
        if self._scan is not None:
            typ = next(typ for t, (typ, _) in self._topics_cache().items() if t == topic)
            if self._ros1():
                ts = _ros1_typestore()
                for t, raw in self._raw(topic, True, start, stop):
                    yield t, ts.deserialize_ros1(raw, typ)
            else:
                ts = _typestore()
                for t, raw in self._raw(topic, True, start, stop):
                    yield t, ts.deserialize_cdr(raw, typ)
            return
        with self._reader() as r:
            cons = [c for c in r.connections if c.topic == topic]
            for c, t, raw in r.messages(connections=cons, start=start, stop=stop):
                yield t, r.deserialize(raw, c.msgtype)

    def _topics_cache(self) -> dict[str, tuple[str, int]]:
        conns, _ = self._scan
        return {t: (typ, 0) for t, typ in conns.values()}

    # ----------------------------------------------------------- selection
    def _select(self) -> np.ndarray:
        """Message numbers to attempt (before :meth:`restrict`)."""
        n = self._times.size
        if self.fps is not None:
            from .video import sample_by_time

            sel = np.asarray(sample_by_time(self._times / 1e9, self.fps), np.int64)
        else:
            sel = np.arange(0, n, self.step or 1)
        return sel[: self.max_frames] if self.max_frames else sel

    def _selected(self) -> np.ndarray:
        return self._sel if self._only is None else self._sel[np.isin(self._sel, self._only)]

    def restrict(self, indices) -> None:
        """Attempt only the frames numbered ``indices`` among those selected (positions every N metres, ...)."""
        self._only = np.asarray(sorted(set(int(i) for i in indices)), np.int64)

    def indices(self) -> list[int]:
        return self._selected().tolist()

    def names(self) -> list[str]:
        return [_stamp_name(self.topic, int(self._times[i])) for i in self._selected()]

    def stamps(self) -> np.ndarray:
        """The selected frames' times, seconds (the bag's clock)."""
        return self._times[self._selected()] / 1e9

    def all_stamps(self) -> np.ndarray:
        """Every message's time on the topic, seconds (indexed by frame number)."""
        return self._times / 1e9

    def exact_total(self) -> int:
        return int(self._times.size)

    def key(self) -> str:
        h = hashlib.sha256()
        files = [self.path] if self.path.is_file() else sorted(p for p in self.path.iterdir() if p.is_file())
        for f in files:
            h.update(stat_token(f.resolve()).encode("utf-8", "surrogateescape"))
        h.update(f"|{self.topic}|fps={self.fps}|step={self.step}|max={self.max_frames}|"
                 f"{self._selected().tobytes().hex() if self._only is not None else ''}".encode())
        return f"bag:{h.hexdigest()}"

    def _frames(self, wanted: np.ndarray) -> Iterator[Frame]:
        if wanted.size == 0:
            return
        want = set(wanted.tolist())
        t0, t1 = int(self._times[wanted[0]]), int(self._times[wanted[-1]]) + 1
        k0 = int(np.searchsorted(self._times, t0, side="left"))  # message number of the first in the window
        for k, (t, msg) in enumerate(self._messages(self.topic, t0, t1), start=k0):
            if k not in want:
                continue
            img, reason = decode_image_msg(msg, self.msgtype)
            name = _stamp_name(self.topic, t)
            if img is None:
                self._skip(name, reason)
                continue
            try:
                img = self._bgr(img, name)
            except ValueError as e:
                self._skip(name, str(e))
                continue
            yield Frame(k, name, img)

    # ----------------------------------------------------------- positions
    def trajectory(self, topic: str) -> tuple[np.ndarray, np.ndarray, str]:
        """(times s, positions (n, 2), kind) of a position topic (:data:`POSITION_TYPES`).

        ``kind`` ``"latlon"``: NavSatFix (messages without a fix left out); ``"metres"``: odometry or pose x, y. An
        unknown topic (position topics listed), another type or no usable position raise ValueError.
        """
        topics = self._topics_cache() if self._scan is not None else self._topics()
        if topic not in topics or topics[topic][0] not in POSITION_TYPES:
            have = sorted(t for t, (typ, _) in topics.items() if typ in POSITION_TYPES)
            what = (f"no topic {topic!r}" if topic not in topics
                    else f"topic {topic} holds {_short(topics[topic][0])}, not positions")
            raise ValueError(f"{self.path}: --gt-topic: {what} (read: NavSatFix, Odometry, PoseStamped, "
                             f"PoseWithCovarianceStamped); position topics here: {', '.join(have) or 'none'}")
        typ = topics[topic][0]
        t, a, b = [], [], []
        for stamp, msg in self._messages(topic):
            if typ.endswith("NavSatFix"):
                lat, lon = float(msg.latitude), float(msg.longitude)
                if int(msg.status.status) < 0 or not (np.isfinite(lat) and np.isfinite(lon)) or lat == lon == 0.0:
                    continue
                a.append(float(msg.latitude))
                b.append(float(msg.longitude))
            else:
                pose = msg.pose.pose if typ.endswith(("Odometry", "PoseWithCovarianceStamped")) else msg.pose
                a.append(float(pose.position.x))
                b.append(float(pose.position.y))
            t.append(stamp)
        if not t:
            raise ValueError(f"{self.path}: topic {topic} has no usable position (no fix?)")
        order = np.argsort(np.asarray(t), kind="stable")
        t = np.asarray(t, np.int64)[order] / 1e9
        a, b = np.asarray(a)[order], np.asarray(b)[order]
        return t, np.stack([a, b], axis=1), "latlon" if typ.endswith("NavSatFix") else "metres"


def _ros1_typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC)
