"""sensor_msgs/PointCloud2 <-> numpy structured arrays.

Decoding builds a record dtype straight from the message's ``fields`` list
(offsets, ``itemsize = point_step``) and views ``data`` through it, so a
cloud costs no copy unless rows carry padding (``row_step > width *
point_step``), in which case the padding has to be squeezed out.
"""
from __future__ import annotations

from collections.abc import Iterable
from typing import Any, NamedTuple

import numpy as np

from ...core.errors import DataError

__all__ = [
    "DATATYPES",
    "XYZIRC_FIELDS",
    "XYZI_FIELDS",
    "Field",
    "PointCloud2Error",
    "decode_pointcloud2",
    "encode_pointcloud2",
    "fields_dtype",
    "make_cloud",
]

# sensor_msgs/PointField datatype constants -> numpy base codes
DATATYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
_CODES = {v: k for k, v in DATATYPES.items()}


class PointCloud2Error(DataError, ValueError):
    """PointCloud2 layout inconsistent with its data."""


class Field(NamedTuple):
    name: str
    offset: int
    datatype: int
    count: int = 1


# Autoware's PointXYZIRC (autoware_point_types), 16 bytes/point.
XYZIRC_FIELDS = (Field("x", 0, 7), Field("y", 4, 7), Field("z", 8, 7),
                 Field("intensity", 12, 2), Field("return_type", 13, 2),
                 Field("channel", 14, 4))
# pcl::PointXYZI: float intensity, padded to 32 bytes by PCL (point_step=32).
XYZI_FIELDS = (Field("x", 0, 7), Field("y", 4, 7), Field("z", 8, 7),
               Field("intensity", 16, 7))


def fields_dtype(fields: Iterable[Any], point_step: int, is_bigendian: bool = False,
                 where: str = "PointCloud2") -> np.dtype:
    """Record dtype (itemsize = point_step) from PointField-like objects."""
    order = ">" if is_bigendian else "<"
    names, formats, offsets = [], [], []
    for f in fields:
        name, offset, datatype = str(f.name), int(f.offset), int(f.datatype)
        count = max(int(f.count), 1)  # some drivers publish count=0 meaning 1
        if datatype not in DATATYPES:
            raise PointCloud2Error(f"{where}: field {name!r} has unknown datatype {datatype} "
                                   f"(expected 1..8 = INT8..FLOAT64)")
        code = order + DATATYPES[datatype]
        size = np.dtype(code).itemsize * count
        if offset < 0 or offset + size > point_step:
            raise PointCloud2Error(f"{where}: field {name!r} at offset {offset} size {size} "
                                   f"exceeds point_step {point_step}")
        if name in names:
            raise PointCloud2Error(f"{where}: duplicate field name {name!r}")
        names.append(name)
        formats.append(code if count == 1 else (code, (count,)))
        offsets.append(offset)
    try:
        return np.dtype({"names": names, "formats": formats, "offsets": offsets,
                         "itemsize": point_step})
    except ValueError as exc:  # overlapping fields
        raise PointCloud2Error(f"{where}: invalid field layout: {exc}") from None


_DTYPES: dict[tuple, np.dtype] = {}  # a topic's clouds all share one layout


def _layout_dtype(fields: Any, point_step: int, is_bigendian: bool, where: str) -> np.dtype:
    """fields_dtype, built once per layout: it costs more than viewing a small cloud."""
    try:
        key = (point_step, is_bigendian, *((f.name, f.offset, f.datatype, f.count) for f in fields))
        dtype = _DTYPES.get(key)
    except TypeError:  # unhashable field values: no cache
        return fields_dtype(fields, point_step, is_bigendian, where)
    if dtype is None:
        dtype = fields_dtype(fields, point_step, is_bigendian, where)
        if len(_DTYPES) < 256:
            _DTYPES[key] = dtype
    return dtype


def decode_pointcloud2(msg: Any, where: str = "PointCloud2") -> np.ndarray:
    """Structured (height*width,) array viewing ``msg.data`` (copy only if rows are padded).

    ``msg`` is anything with the PointCloud2 attributes (a rosbags message
    works).  ``where`` prefixes error messages (e.g. "bag.db3 /topic msg #12").
    """
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    dtype = _layout_dtype(msg.fields, point_step, bool(msg.is_bigendian), where)
    data = msg.data
    buf = data if isinstance(data, np.ndarray) else np.frombuffer(data, dtype=np.uint8)
    buf = buf.reshape(-1).view(np.uint8)
    n = height * width
    if n and point_step <= 0:
        raise PointCloud2Error(f"{where}: point_step {point_step} must be positive")
    if n and row_step < width * point_step:
        raise PointCloud2Error(f"{where}: row_step {row_step} < width {width} x point_step {point_step} "
                               f"= {width * point_step}: a row's points do not fit in a row")
    # Extra bytes are refused as firmly as missing ones: they mean height, width or
    # row_step is wrong, so the points read would not be the points sent.
    expected = height * row_step
    if buf.size != expected:
        found = f"data has {buf.size} bytes, the layout needs {expected} (height {height} x row_step {row_step})"
        if buf.size > expected and row_step and (buf.size - expected) % row_step == 0:
            found += f": {(buf.size - expected) // row_step} row(s) more than height {height}"
        else:
            found += f": {abs(buf.size - expected)} bytes {'too many' if buf.size > expected else 'missing'}"
        raise PointCloud2Error(f"{where}: {found}")
    if n == 0:
        return np.empty(0, dtype=dtype)
    if row_step == width * point_step or height == 1:
        return buf[: n * point_step].view(dtype)
    rows = np.ndarray((height, width), dtype=dtype, buffer=buf,
                      strides=(row_step, point_step))
    return rows.reshape(n)  # copies: padded rows cannot be viewed as one flat run


def _normalise(array: np.ndarray) -> np.ndarray:
    """Little-endian, contiguous copy of ``array`` if needed (same field offsets)."""
    array = np.ascontiguousarray(array.reshape(-1))
    if any(array.dtype.fields[n][0].base.byteorder == ">" for n in array.dtype.names):
        array = array.astype(array.dtype.newbyteorder("<"))
    return array


def cloud_fields(dtype: np.dtype) -> list[Field]:
    """PointField descriptions of a structured dtype."""
    out = []
    for name in dtype.names:
        ft, offset = dtype.fields[name][:2]
        base, shape = ft.subdtype if ft.subdtype else (ft, ())
        code = base.str[1:]
        if code not in _CODES:
            raise PointCloud2Error(f"field {name!r}: dtype {ft} has no PointField datatype")
        out.append(Field(name, int(offset), _CODES[code], int(np.prod(shape)) if shape else 1))
    return out


def encode_pointcloud2(array: np.ndarray, frame_id: str, stamp_ns: int, typestore=None,
                       height: int = 1, is_dense: bool = True):
    """Build a rosbags ``sensor_msgs/msg/PointCloud2`` from a structured array.

    The array's own layout (offsets, itemsize, i.e. any padding) is kept, so
    encode/decode round-trips byte for byte.
    """
    if typestore is None:
        from rosbags.typesys import Stores, get_typestore
        typestore = get_typestore(Stores.ROS2_HUMBLE)
    array = np.asarray(array)
    if array.dtype.names is None:
        raise PointCloud2Error("encode_pointcloud2 needs a structured array")
    array = _normalise(array)
    if array.size % height:
        raise PointCloud2Error(f"{array.size} points do not split into {height} rows")
    width = array.size // height
    T = typestore.types
    fields = [T["sensor_msgs/msg/PointField"](name=f.name, offset=f.offset,
                                              datatype=f.datatype, count=f.count)
              for f in cloud_fields(array.dtype)]
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    header = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec),
                                      frame_id=frame_id)
    step = array.dtype.itemsize
    return T["sensor_msgs/msg/PointCloud2"](
        header=header, height=height, width=width, fields=fields, is_bigendian=False,
        point_step=step, row_step=step * width, data=array.view(np.uint8).reshape(-1),
        is_dense=is_dense)


def make_cloud(n: int, fields: Iterable[Field] = XYZIRC_FIELDS, point_step: int | None = None,
               rng: np.random.Generator | None = None) -> np.ndarray:
    """Random cloud with the given PointField layout (for tests and benchmarks)."""
    fields = list(fields)
    if point_step is None:
        point_step = max(f.offset + np.dtype(DATATYPES[f.datatype]).itemsize * max(f.count, 1)
                         for f in fields)
    dtype = fields_dtype(fields, point_step)
    rng = rng or np.random.default_rng(0)
    out = np.zeros(n, dtype=dtype)
    for name in dtype.names:
        col = out[name]
        if col.dtype.kind == "f":
            col[...] = rng.uniform(-50, 50, col.shape)
        else:
            info = np.iinfo(col.dtype)
            col[...] = rng.integers(max(info.min, -1000), min(info.max, 1000), col.shape,
                                    endpoint=True)
    return out
