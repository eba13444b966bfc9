"""A little-endian CDR sensor_msgs/PointCloud2 read without rosbags' generic deserializer.

rosbags builds a deserializer per message type the first time it meets one
(some 20 ms) and walks each message field by field through it; a cloud's
header and layout are a dozen numbers and a few strings, so reading them here
costs a few microseconds and no code generation.  The checks are rosbags' own
(string terminators, sequence lengths, the message's size), and anything this
reader does not take (big-endian CDR, a check failing, a typestore whose
PointCloud2 is not the standard one) is ``None``: the caller then lets rosbags
deserialize the message, which decodes it or raises its error as before.
"""
from __future__ import annotations

import struct
from typing import Any, NamedTuple

import numpy as np

from .pointcloud2 import Field

__all__ = ["CdrCloud", "read_pointcloud2_cdr", "standard_layout"]

_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")
_TWO_U32 = struct.Struct("<II")
_STANDARD = ("sensor_msgs/msg/PointCloud2", "sensor_msgs/msg/PointField", "std_msgs/msg/Header",
             "builtin_interfaces/msg/Time")


class CdrCloud(NamedTuple):
    """The PointCloud2 fields decode_pointcloud2 and Bag.pointclouds read."""

    sec: int
    nanosec: int
    frame_id: str
    height: int
    width: int
    fields: list[Field]
    is_bigendian: bool
    point_step: int
    row_step: int
    data: np.ndarray  # a view over the message's buffer, as rosbags gives it
    is_dense: bool


def standard_layout(typestore: Any, reference: Any) -> bool:
    """Whether ``typestore`` defines PointCloud2 (and what it holds) as ``reference``, a ROS 2 store, does."""
    if typestore is reference:
        return True
    mine, ref = getattr(typestore, "fielddefs", {}), reference.fielddefs
    return all(mine.get(name) == ref[name] for name in _STANDARD)


def _string(d: memoryview, pos: int) -> tuple[str, int]:
    size = _U32.unpack_from(d, pos)[0]
    end = pos + 4 + size
    if size < 1 or end > len(d) or d[end - 1] != 0:
        raise ValueError("bad string")
    return bytes(d[pos + 4:end - 1]).decode(), end


def read_pointcloud2_cdr(raw: Any, max_sequence: int = 2**32 - 1) -> CdrCloud | None:
    """The cloud in serialized message ``raw`` (encapsulation header included), or None."""
    raw = memoryview(raw)
    if len(raw) < 4 or raw[0] != 0 or raw[1] != 1:
        return None  # big-endian (or not CDR): rosbags' business
    d = raw[4:]  # positions and alignment count from after the encapsulation header
    try:
        sec, nanosec = _STAMP.unpack_from(d, 0)
        frame_id, pos = _string(d, 8)
        pos = (pos + 3) & -4
        height, width = _TWO_U32.unpack_from(d, pos)
        count = _U32.unpack_from(d, pos + 8)[0]
        pos += 12
        if pos + count > len(d) or count > max_sequence:
            return None
        fields = []
        for _ in range(count):
            name, pos = _string(d, (pos + 3) & -4)
            pos = (pos + 3) & -4
            offset = _U32.unpack_from(d, pos)[0]
            datatype = d[pos + 4]
            pos = (pos + 5 + 3) & -4
            fields.append(Field(name, offset, datatype, _U32.unpack_from(d, pos)[0]))
            pos += 4
        is_bigendian = bool(d[pos])
        pos = (pos + 1 + 3) & -4
        point_step, row_step = _TWO_U32.unpack_from(d, pos)
        size = _U32.unpack_from(d, pos + 8)[0]
        pos += 12
        if pos + size > len(d) or size > max_sequence:
            return None
        data = np.frombuffer(d, dtype=np.uint8, count=size, offset=pos)
        is_dense = bool(d[pos + size])
    except (struct.error, IndexError, ValueError):  # ValueError includes UnicodeDecodeError
        return None
    if pos + size + 1 + 4 + 3 < len(raw):
        return None  # bytes left over: rosbags calls that a size mismatch
    return CdrCloud(sec, nanosec, frame_id, height, width, fields, is_bigendian, point_step, row_step,
                    data, is_dense)
