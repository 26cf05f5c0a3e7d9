"""The readable part of a damaged ROS1 bag: every complete message before the damage.

A bag whose recording was cut off (recorder killed, disk full, a copy that stopped) has no
index, or an index past its end, and rosbags refuses it as a whole. Its chunks are still there
in order, each a self-contained run of connection and message records (ROS bag format 2.0:
``<header_len><header><data_len><data>``, header fields ``<len>name=value``), so this walks the
file from the start and keeps every complete message up to the first record that is cut or
unreadable. An uncompressed chunk that is itself cut keeps its complete records; a compressed
one is decompressed whole or not at all.
"""

from __future__ import annotations

import bz2
import struct
from dataclasses import dataclass
from pathlib import Path

from lz4.frame import decompress as lz4_decompress  # rosbags' own dependency

from groundfloor.errors import InputError

MAGIC = b"#ROSBAG V2.0\n"
OP_MSGDATA, OP_BAGHEADER, OP_CHUNK, OP_CONNECTION = 0x02, 0x03, 0x05, 0x07
_U32 = struct.Struct("<I")


@dataclass(frozen=True)
class SalvagedMessage:
    """One complete message found in a damaged bag."""

    topic: str
    msgtype: str  # rosbags form, e.g. "geometry_msgs/msg/PointStamped"
    md5sum: str
    msgdef: str
    t_bag_ns: int
    raw: bytes


@dataclass(frozen=True)
class Salvage:
    """What could be read from a damaged bag, and where and why reading stopped."""

    messages: list[SalvagedMessage]
    stopped_at_byte: int
    size_bytes: int
    reason: str  # where and why reading stopped; empty when the file ended cleanly (no index)


def _fields(header: bytes) -> dict[str, bytes]:
    """Return the ``name=value`` fields of a record header."""
    out, pos = {}, 0
    while pos + 4 <= len(header):
        (n,) = _U32.unpack_from(header, pos)
        name, _, value = header[pos + 4:pos + 4 + n].partition(b"=")
        out[name.decode(errors="replace")] = value
        pos += 4 + n
    return out


def _record(buf: bytes, pos: int) -> tuple[dict[str, bytes], int, int] | None:
    """Return ``(header fields, data start, data end)`` of the record at ``pos``, or None if its
    header is cut. ``data end`` may lie past the buffer when the data is cut."""
    if pos + 4 > len(buf):
        return None
    (n_head,) = _U32.unpack_from(buf, pos)
    if pos + 8 + n_head > len(buf):
        return None
    fields = _fields(buf[pos + 4:pos + 4 + n_head])
    (n_data,) = _U32.unpack_from(buf, pos + 4 + n_head)
    start = pos + 8 + n_head
    return fields, start, start + n_data


def _msgtype(ros1_type: str) -> str:
    pkg, _, name = ros1_type.partition("/")
    return ros1_type if "/msg/" in ros1_type else f"{pkg}/msg/{name}"


def _records(buf: bytes, conns: dict, out: list, topics: set[str]) -> int:
    """Parse connection and message records of ``buf`` (a chunk's data) into ``conns``/``out``;
    return the position after the last complete record."""
    pos = 0
    while (rec := _record(buf, pos)) is not None and rec[2] <= len(buf):
        fields, start, end = rec
        op = fields.get("op", b"\xff")[0]
        if op == OP_CONNECTION:
            info = _fields(buf[start:end])
            conns[_U32.unpack(fields["conn"])[0]] = (
                fields["topic"].decode(), _msgtype(info.get("type", b"").decode()),
                info.get("md5sum", b"").decode(), info.get("message_definition", b"").decode())
        elif op == OP_MSGDATA:
            conn = conns.get(_U32.unpack(fields["conn"])[0])
            if conn is not None and conn[0] in topics:
                sec, nsec = struct.unpack("<II", fields["time"])
                out.append(SalvagedMessage(*conn, sec * 1_000_000_000 + nsec, bytes(buf[start:end])))
        pos = end
    return pos


def salvage_ros1(path: str | Path, topics: set[str]) -> Salvage:
    """Return the complete messages of ``topics`` in a damaged ROS1 bag, in file order.

    Raises
    ------
    InputError
        If the file is not a ROS1 bag at all (names the file).
    """
    path = Path(path)
    buf = path.read_bytes()
    if not buf.startswith(MAGIC):
        raise InputError(f"{path}: not a ROS1 bag (no '#ROSBAG V2.0' line)")
    conns, out = {}, []
    pos, reason = len(MAGIC), ""
    while pos < len(buf):
        rec = _record(buf, pos)
        if rec is None:
            reason = f"a record header is cut at byte {pos}"
            break
        fields, start, end = rec
        op = fields.get("op", b"\xff")[0]
        if op == OP_CHUNK and end > len(buf):
            if fields.get("compression") == b"none":
                _records(buf[start:], conns, out, topics)
            reason = f"a chunk is cut at byte {len(buf)} (it needs {end})"
            break
        if end > len(buf):
            reason = f"a record is cut at byte {len(buf)} (it needs {end})"
            break
        if op == OP_CHUNK:
            compression = fields.get("compression", b"none")
            try:
                data = {b"none": lambda b: b, b"bz2": bz2.decompress,
                        b"lz4": lz4_decompress}[compression](buf[start:end])
            except (KeyError, OSError, ValueError, RuntimeError) as exc:
                reason = f"chunk at byte {pos} unreadable ({compression.decode()}: {exc})"
                break
            _records(data, conns, out, topics)
        elif op in (OP_CONNECTION, OP_MSGDATA):
            _records(buf[pos:end], conns, out, topics)
        pos = end
    return Salvage(messages=out, stopped_at_byte=pos, size_bytes=len(buf), reason=reason)
