"""What can be read of a recording that was killed or cut short: its complete messages, in time order."""
from __future__ import annotations

import bz2
import struct
from pathlib import Path

__all__ = ["scan_ros1", "scan_mcap"]

_OP_MSG, _OP_CHUNK, _OP_CONN = 0x02, 0x05, 0x07


def _fields(header: bytes) -> dict[str, bytes]:
    out, i = {}, 0
    while i + 4 <= len(header):
        (n,) = struct.unpack_from("<I", header, i)
        name, _, value = header[i + 4:i + 4 + n].partition(b"=")
        out[name.decode("ascii", "replace")] = value
        i += 4 + n
    return out


def _records(buf: bytes, start: int = 0):
    """(fields, data, complete) of the records of ``buf`` from ``start``.

    The last record may be cut short: it comes with the data there is and ``complete`` False (an uncompressed chunk is
    still read up to its last complete record), and nothing follows it.
    """
    i = start
    while i + 4 <= len(buf):
        (hl,) = struct.unpack_from("<I", buf, i)
        if i + 8 + hl > len(buf):
            return
        header = buf[i + 4:i + 4 + hl]
        (dl,) = struct.unpack_from("<I", buf, i + 4 + hl)
        end = i + 8 + hl + dl
        yield _fields(header), buf[i + 8 + hl:end], end <= len(buf)
        if end > len(buf):
            return
        i = end


def scan_ros1(path: Path):
    """Connections and messages of a ROS 1 bag read record by record (no index): (connections, messages).

    ``connections``: id -> (topic, msgtype); ``messages``: (connection id, time ns, raw bytes), in file order. Chunks
    compressed with bz2 or lz4 are read whole or not at all; an uncompressed chunk up to its last complete record.
    """
    raw = path.read_bytes()
    magic = b"#ROSBAG V2.0\n"
    if not raw.startswith(magic):
        raise ValueError("not a ROS 1 bag (no '#ROSBAG V2.0' header)")
    conns: dict[int, tuple[str, str]] = {}
    msgs: list[tuple[int, int, bytes]] = []

    def take(records):
        for f, data, complete in records:
            op = f.get("op", b"\0")[0]
            if not complete and op != _OP_CHUNK:
                return
            if op == _OP_CONN:
                c = _fields(data)
                typ = c.get("type", b"").decode()
                pkg, _, name = typ.partition("/")
                conns[struct.unpack("<I", f["conn"])[0]] = (f.get("topic", b"").decode(), f"{pkg}/msg/{name}")
            elif op == _OP_MSG:
                sec, nsec = struct.unpack("<II", f["time"])
                msgs.append((struct.unpack("<I", f["conn"])[0], sec * 1_000_000_000 + nsec, data))
            elif op == _OP_CHUNK:
                comp = f.get("compression", b"none").decode()
                if comp == "none":
                    take(_records(data))
                else:
                    if not complete:  # a cut compressed chunk: nothing of it is readable
                        return
                    try:
                        if comp == "bz2":
                            inner = bz2.decompress(data)
                        else:
                            from lz4.frame import decompress  # rosbags' own dependency

                            inner = decompress(data)
                    except Exception:  # a cut compressed chunk: nothing of it is readable
                        continue
                    take(_records(inner))

    take(_records(raw, len(magic)))
    msgs.sort(key=lambda m: m[1])  # time order, as an indexed bag is read
    return conns, msgs


# ---------------------------------------------------------------------------- MCAP
_MCAP_MAGIC = b"\x89MCAP0\r\n"
_SCHEMA, _CHANNEL, _MESSAGE, _CHUNK = 0x03, 0x04, 0x05, 0x06


def _string(buf: bytes, i: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, i)
    return buf[i + 4:i + 4 + n].decode("utf-8", "replace"), i + 4 + n


def _mcap_records(buf: bytes, start: int = 0):
    """(opcode, content, complete) of the records of ``buf`` from ``start``; the last may be cut short."""
    i = start
    while i + 9 <= len(buf):
        op = buf[i]
        (n,) = struct.unpack_from("<Q", buf, i + 1)
        end = i + 9 + n
        yield op, buf[i + 9:end], end <= len(buf)
        if end > len(buf):
            return
        i = end


def _decompress(data: bytes, compression: str) -> bytes:
    if compression == "":
        return data
    if compression == "lz4":
        from lz4.frame import decompress  # rosbags' own dependency

        return decompress(data)
    if compression == "zstd":
        import zstandard  # rosbags reads zstd chunks with it too

        return zstandard.ZstdDecompressor().decompressobj().decompress(data)
    raise ValueError(f"chunk compression {compression!r}")


def scan_mcap(path: Path):
    """Channels and messages of an MCAP file read record by record (no summary): (connections, messages)."""
    raw = Path(path).read_bytes()
    if not raw.startswith(_MCAP_MAGIC):
        raise ValueError("not an MCAP file (no MCAP magic at its start)")
    schemas: dict[int, str] = {}
    conns: dict[int, tuple[str, str]] = {}
    msgs: list[tuple[int, int, bytes]] = []

    def take(records) -> None:
        for op, c, complete in records:
            if not complete and op != _CHUNK:
                return
            if op == _SCHEMA:
                (sid,) = struct.unpack_from("<H", c, 0)
                schemas[sid], _ = _string(c, 2)
            elif op == _CHANNEL:
                cid, sid = struct.unpack_from("<HH", c, 0)
                topic, _ = _string(c, 4)
                conns[cid] = (topic, schemas.get(sid, "?"))
            elif op == _MESSAGE:
                cid, _, log_time = struct.unpack_from("<HIQ", c, 0)
                msgs.append((cid, log_time, bytes(c[22:])))
            elif op == _CHUNK and len(c) >= 28:
                compression, i = _string(c, 28)
                if i + 8 > len(c):
                    return
                (n,) = struct.unpack_from("<Q", c, i)
                data = c[i + 8:i + 8 + n]
                if complete and len(data) == n:
                    try:
                        take(_mcap_records(_decompress(data, compression)))
                    except Exception:  # a damaged or unknown chunk: nothing of it is readable
                        continue
                else:
                    if compression == "":  # cut short: its complete records
                        take(_mcap_records(data))
                    return

    take(_mcap_records(raw, len(_MCAP_MAGIC)))
    msgs.sort(key=lambda m: m[1])
    return conns, msgs
