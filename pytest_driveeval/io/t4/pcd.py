"""PCD (Point Cloud Library) and nuScenes/t4 ``.pcd.bin`` point cloud files.

Clouds are returned as numpy structured arrays so that mixed field types
(e.g. float32 xyz next to uint8 intensity and uint16 channel) survive intact.
Fields with ``COUNT > 1`` become subarray fields.  PCL pads records with
fields named ``_``; those bytes are skipped through explicit dtype offsets
rather than exposed.

``binary_compressed`` data is LZF; a small pure-Python decompressor is
included (about 10-50 MB/s, enough for single test sweeps; large datasets
should be stored as ``binary``).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core.errors import DataError

__all__ = [
    "PCDError",
    "PCDHeader",
    "read_pcd",
    "read_pcd_bin",
    "read_pcd_header",
    "write_pcd",
    "xyz",
]

_TYPE_CODES = {("F", 4): "f4", ("F", 8): "f8",
               ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8",
               ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4", ("I", 8): "i8"}
_KIND_TO_TYPE = {"f": "F", "u": "U", "i": "I"}
_DATA_KINDS = ("ascii", "binary", "binary_compressed")
# A header longer than this is not a PCD header; it protects against scanning
# a huge binary file for a DATA line that does not exist.
_MAX_HEADER_LINES = 64


class PCDError(DataError, ValueError):
    """Malformed or truncated PCD / .pcd.bin file."""


@dataclass(frozen=True)
class PCDHeader:
    fields: tuple[str, ...]
    sizes: tuple[int, ...]
    types: tuple[str, ...]
    counts: tuple[int, ...]
    width: int
    height: int
    points: int
    data: str
    viewpoint: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    version: str = "0.7"
    data_offset: int = 0  # byte offset of the payload in the file

    def dtype(self) -> np.dtype:
        """Packed record dtype; ``_`` padding fields are kept out of ``names``."""
        names, formats, offsets = [], [], []
        offset = 0
        for name, size, typ, count in zip(self.fields, self.sizes, self.types, self.counts):
            if name != "_":
                code = "<" + _TYPE_CODES[(typ, size)]
                names.append(name)
                formats.append(code if count == 1 else (code, (count,)))
                offsets.append(offset)
            offset += size * count
        return np.dtype({"names": names, "formats": formats, "offsets": offsets,
                         "itemsize": offset})


def _header_error(path, lineno, msg) -> PCDError:
    return PCDError(f"{path}:{lineno}: bad PCD header: {msg}")


def _parse_header(path: Path, raw: bytes) -> PCDHeader:
    values: dict[str, tuple[int, list[str]]] = {}
    pos = 0
    for lineno in range(1, _MAX_HEADER_LINES + 1):
        end = raw.find(b"\n", pos)
        if end < 0:
            raise _header_error(path, lineno, "no DATA line before end of file")
        line = raw[pos:end].decode("ascii", errors="replace").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *rest = line.split()
        key = key.upper()
        values[key] = (lineno, rest)
        if key == "DATA":
            break
    else:
        raise _header_error(path, _MAX_HEADER_LINES, "no DATA line in header")

    def get(key, default=None):
        if key not in values:
            if default is None:
                raise _header_error(path, lineno, f"missing {key} line")
            return lineno, default
        return values[key]

    fields_line, fields = get("FIELDS")
    if not fields:
        raise _header_error(path, fields_line, "FIELDS is empty")
    n = len(fields)

    def ints(key, default=None):
        ln, toks = get(key, default)
        try:
            out = tuple(int(t) for t in toks)
        except ValueError:
            raise _header_error(path, ln, f"{key} must be whole numbers, one per field") from None
        if len(out) != n:
            raise _header_error(path, ln, f"{key} has {len(out)} entries for {n} FIELDS")
        if any(v <= 0 for v in out):
            raise _header_error(path, ln, f"{key} entries must be positive, got {list(out)}")
        return out

    sizes = ints("SIZE")
    counts = ints("COUNT", ["1"] * n)
    type_line, types = get("TYPE")
    types = tuple(t.upper() for t in types)
    if len(types) != n:
        raise _header_error(path, type_line, f"TYPE has {len(types)} entries for {n} FIELDS")
    for index, (t, s) in enumerate(zip(types, sizes), start=1):
        if (t, s) not in _TYPE_CODES:
            known = ", ".join(sorted({f"{t} {s}" for t, s in _TYPE_CODES}))
            raise _header_error(path, type_line, f"field {index} of {n}: unsupported TYPE for its SIZE "
                                                 f"{s} (TYPE SIZE pairs read: {known})")
    named = [f for f in fields if f != "_"]
    if len(set(named)) != len(named):
        raise _header_error(path, fields_line, "FIELDS names a field twice")

    def one_int(key, default=None):
        ln, toks = get(key, default)
        try:
            (v,) = toks
            v = int(v)
        except ValueError:
            raise _header_error(path, ln, f"{key} must be one whole number") from None
        if v < 0:
            raise _header_error(path, ln, f"{key} must be >= 0, got {v}")
        return v

    width = one_int("WIDTH")
    height = one_int("HEIGHT", ["1"])
    points = one_int("POINTS", [str(width * height)])
    if points != width * height:
        raise _header_error(path, values["POINTS"][0],
                            f"POINTS {points} != WIDTH*HEIGHT {width * height}")
    vp_line, vp = get("VIEWPOINT", ["0", "0", "0", "1", "0", "0", "0"])
    try:
        viewpoint = tuple(float(v) for v in vp)
    except ValueError:
        raise _header_error(path, vp_line, "VIEWPOINT must be 7 numbers") from None
    if len(viewpoint) != 7:
        raise _header_error(path, vp_line, f"VIEWPOINT must be 7 numbers, found {len(viewpoint)}")
    data_line, data = get("DATA")
    if len(data) != 1 or data[0].lower() not in _DATA_KINDS:
        raise _header_error(path, data_line, f"DATA must be one of {', '.join(_DATA_KINDS)}")
    version = values.get("VERSION", (0, ["0.7"]))[1]
    return PCDHeader(tuple(fields), sizes, types, counts, width, height, points,
                     data[0].lower(), viewpoint, version[0] if version else "", pos)


def read_pcd_header(path: str | os.PathLike) -> PCDHeader:
    path = Path(path)
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    return _parse_header(path, head)


def read_pcd(path: str | os.PathLike, *, with_header: bool = False):
    """Read a PCD file into a structured array (``(header, array)`` if asked)."""
    path = Path(path)
    raw = path.read_bytes()
    header = _parse_header(path, raw)
    payload = memoryview(raw)[header.data_offset:]
    if header.data == "binary":
        arr = _decode_binary(path, header, payload)
    elif header.data == "ascii":
        arr = _decode_ascii(path, header, bytes(payload), raw.count(b"\n", 0, header.data_offset) + 1)
    else:
        arr = _decode_compressed(path, header, payload)
    return (header, arr) if with_header else arr


def _as_points(nbytes: int, itemsize: int) -> str:
    whole, rest = divmod(nbytes, itemsize)
    return f"{nbytes} bytes ({whole} points" + (f" and {rest} bytes" if rest else "") + f" of {itemsize} bytes)"


def _decode_binary(path, header: PCDHeader, payload) -> np.ndarray:
    dtype = header.dtype()
    need = dtype.itemsize * header.points
    if len(payload) != need:
        raise PCDError(f"{path}: {'truncated ' if len(payload) < need else ''}binary data: "
                       f"{_as_points(len(payload), dtype.itemsize)}, but POINTS {header.points} needs {need} bytes")
    # Copy so the array owns its memory and is writeable, not a view of `raw`.
    return np.frombuffer(payload, dtype=dtype, count=header.points).copy()


def _decode_ascii(path, header: PCDHeader, payload: bytes, first_line: int = 1) -> np.ndarray:
    ncols = sum(header.counts)
    # Row by row, since a short row followed by a long one would still give the right total.
    rows = [(first_line + i, len(line.split())) for i, line in enumerate(payload.split(b"\n")) if line.strip()]
    if len(rows) != header.points:
        raise PCDError(f"{path}: {'truncated ' if len(rows) < header.points else ''}ascii data: "
                       f"{len(rows)} rows, but POINTS is {header.points}")
    lineno, found = next(((ln, k) for ln, k in rows if k != ncols), (0, ncols))
    if found != ncols:
        raise PCDError(f"{path}:{lineno}: ascii row has {found} values, FIELDS/COUNT need {ncols}")
    tokens = payload.split()
    table = np.array(tokens[: ncols * header.points]).reshape(header.points, ncols)
    out = np.zeros(header.points, dtype=header.dtype())
    col = 0
    for name, count in zip(header.fields, header.counts):
        if name != "_":
            target = out[name].reshape(header.points, count)
            cells = table[:, col:col + count]
            try:
                target[...] = cells.astype(target.dtype)
            except ValueError:
                # Integer columns written as "3.0" or "nan": go through float.
                try:
                    target[...] = cells.astype(np.float64)
                except ValueError:
                    # numpy's message quotes the cell; a file is named by its line instead.
                    row = next(i for i, values in enumerate(cells) if not _numbers(values))
                    raise PCDError(f"{path}:{rows[row][0]}: field {name!r}: expected "
                                   f"{'a number' if count == 1 else f'{count} numbers'}") from None
        col += count
    return out


def _numbers(values) -> bool:
    try:
        [float(v) for v in values]
    except ValueError:
        return False
    return True


def _decode_compressed(path, header: PCDHeader, payload) -> np.ndarray:
    if len(payload) < 8:
        raise PCDError(f"{path}: truncated binary_compressed data: missing size words")
    csize, usize = np.frombuffer(payload[:8], dtype="<u4")
    if len(payload) != 8 + csize:
        raise PCDError(f"{path}: {'truncated ' if len(payload) < 8 + csize else ''}binary_compressed data: "
                       f"the size words announce {csize} compressed bytes, {len(payload) - 8} follow them")
    try:
        buf = lzf_decompress(bytes(payload[8:8 + csize]), int(usize))
    except ValueError as exc:
        raise PCDError(f"{path}: corrupt binary_compressed data: {exc}") from None
    dtype = header.dtype()
    if len(buf) != dtype.itemsize * header.points:
        raise PCDError(f"{path}: binary_compressed data decompresses to {_as_points(len(buf), dtype.itemsize)}, "
                       f"but POINTS {header.points} needs {dtype.itemsize * header.points} bytes")
    # The compressed payload is stored field by field (structure of arrays).
    out = np.zeros(header.points, dtype=dtype)
    pos = 0
    for name, size, typ, count in zip(header.fields, header.sizes, header.types, header.counts):
        nbytes = size * count * header.points
        if name != "_":
            col = np.frombuffer(buf, dtype="<" + _TYPE_CODES[(typ, size)],
                                count=count * header.points, offset=pos)
            out[name] = col.reshape(out[name].shape)
        pos += nbytes
    return out


def lzf_decompress(data: bytes, expected_size: int) -> bytes:
    """Decompress a raw LZF stream (liblzf format, as written by PCL)."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        ctrl = data[i]
        i += 1
        if ctrl < 32:  # literal run of ctrl+1 bytes
            run = ctrl + 1
            if i + run > n:
                raise ValueError(f"literal run past end of input at byte {i - 1}")
            out += data[i:i + run]
            i += run
            continue
        length = ctrl >> 5
        if length == 7:
            if i >= n:
                raise ValueError("back-reference length past end of input")
            length += data[i]
            i += 1
        if i >= n:
            raise ValueError("back-reference offset past end of input")
        back = ((ctrl & 0x1F) << 8) + data[i] + 1
        i += 1
        length += 2
        start = len(out) - back
        if start < 0:
            raise ValueError(f"back-reference before start of output at byte {i - 2}")
        if back >= length:
            out += out[start:start + length]
        else:  # overlapping copy repeats the last `back` bytes
            pattern = bytes(out[start:])
            out += (pattern * (length // back + 1))[:length]
    if len(out) != expected_size:
        raise ValueError(f"decompressed {len(out)} bytes, header says {expected_size}")
    return bytes(out)


def lzf_compress(data: bytes) -> bytes:
    """Valid LZF stream using literals plus run-length back-references.

    Not a competitive compressor (no match search): it exists so files written
    with ``data="binary_compressed"`` are readable by PCL and by tests.
    """
    buf = np.frombuffer(data, dtype=np.uint8)
    out = bytearray()
    if buf.size == 0:
        return bytes(out)
    # Run boundaries found vectorised; only the run loop is Python.
    starts = np.flatnonzero(np.concatenate(([True], buf[1:] != buf[:-1])))
    ends = np.append(starts[1:], buf.size)
    literal = bytearray()

    def flush():
        for k in range(0, len(literal), 32):
            chunk = literal[k:k + 32]
            out.append(len(chunk) - 1)
            out.extend(chunk)
        literal.clear()

    for s, e in zip(starts.tolist(), ends.tolist()):
        run = e - s
        if run < 4:
            literal.extend(data[s:e])
            continue
        literal.append(data[s])
        flush()
        rest = run - 1
        while rest >= 3:  # back-reference distance 1 repeats the byte
            m = min(rest, 264)  # a tail shorter than 3 goes out as literal
            length = m - 2
            if length < 7:
                out.append(length << 5)
            else:
                out += bytes((7 << 5, length - 7))
            out.append(0)
            rest -= m
        literal.extend(data[e - rest:e])
    flush()
    return bytes(out)


def read_pcd_bin(path: str | os.PathLike,
                 fields: tuple[str, ...] = ("x", "y", "z", "intensity", "ring")) -> np.ndarray:
    """Read a nuScenes/t4 ``.pcd.bin`` (rows of float32) into a structured array."""
    path = Path(path)
    raw = path.read_bytes()
    row = 4 * len(fields)
    if len(raw) % row:
        raise PCDError(f"{path}: size {len(raw)} bytes is not a multiple of {len(fields)} "
                       f"float32 fields {fields} ({row} bytes per point); truncated or "
                       f"wrong field list")
    dtype = np.dtype([(f, "<f4") for f in fields])
    return np.frombuffer(raw, dtype=dtype).copy()


def write_pcd(path: str | os.PathLike, array: np.ndarray, data: str = "binary",
              viewpoint=(0, 0, 0, 1, 0, 0, 0), width: int | None = None,
              height: int = 1) -> None:
    """Write a structured array as a PCD v0.7 file."""
    if data not in _DATA_KINDS:
        raise ValueError(f"data must be one of {_DATA_KINDS}, got {data!r}")
    array = np.asarray(array)
    if array.dtype.names is None:
        raise ValueError("write_pcd needs a structured array (named fields)")
    array = array.reshape(-1)
    fields, sizes, types, counts, formats = [], [], [], [], []
    for name in array.dtype.names:
        ft = array.dtype.fields[name][0]
        base, shape = (ft.subdtype if ft.subdtype else (ft, ()))
        if base.kind not in _KIND_TO_TYPE or (_KIND_TO_TYPE[base.kind], base.itemsize) not in _TYPE_CODES:
            raise ValueError(f"field {name!r}: dtype {ft} cannot be stored in PCD")
        count = int(np.prod(shape)) if shape else 1
        fields.append(name)
        sizes.append(base.itemsize)
        types.append(_KIND_TO_TYPE[base.kind])
        counts.append(count)
        code = "<" + base.str[1:]
        formats.append(code if count == 1 else (code, (count,)))
    width = array.size if width is None else width
    if width * height != array.size:
        raise ValueError(f"WIDTH {width} x HEIGHT {height} != {array.size} points")
    packed = np.empty(array.size, dtype=np.dtype({"names": fields, "formats": formats}))
    for name in fields:
        packed[name] = array[name]
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        f"FIELDS {' '.join(fields)}\nSIZE {' '.join(map(str, sizes))}\n"
        f"TYPE {' '.join(types)}\nCOUNT {' '.join(map(str, counts))}\n"
        f"WIDTH {width}\nHEIGHT {height}\nVIEWPOINT {' '.join(str(v) for v in viewpoint)}\n"
        f"POINTS {array.size}\nDATA {data}\n"
    ).encode("ascii")
    if data == "binary":
        body = packed.tobytes()
    elif data == "binary_compressed":
        soa = b"".join(np.ascontiguousarray(packed[name]).tobytes() for name in fields)
        comp = lzf_compress(soa)
        body = np.array([len(comp), len(soa)], dtype="<u4").tobytes() + comp
    else:
        cols = []
        for name, typ, count in zip(fields, types, counts):
            col = packed[name].reshape(array.size, count)
            # repr-precision floats so an ascii round trip is exact
            fmt = (lambda v: np.format_float_positional(v, unique=True, trim="-")) if typ == "F" else str
            cols.append(np.vectorize(fmt, otypes=[object])(col) if col.size else col.astype(object))
        table = np.concatenate(cols, axis=1) if cols else np.empty((array.size, 0), object)
        body = "".join(" ".join(row) + "\n" for row in table.tolist()).encode("ascii")
    Path(path).write_bytes(header + body)


def xyz(array: np.ndarray, dtype=None) -> np.ndarray:
    """(N, 3) coordinates from a structured cloud or an (N, >=3) plain array.

    The result dtype follows the x/y/z fields (float32 stays float32) unless
    ``dtype`` is given.
    """
    array = np.asarray(array)
    if array.dtype.names is None:
        if array.ndim != 2 or array.shape[1] < 3:
            raise ValueError(f"expected structured cloud or (N, >=3) array, got {array.shape}")
        out = array[:, :3]
        return np.ascontiguousarray(out, dtype=dtype or out.dtype)
    missing = [c for c in "xyz" if c not in array.dtype.names]
    if missing:
        raise ValueError(f"cloud has no field(s) {missing}; fields are {array.dtype.names}")
    flat = array.reshape(-1)
    if dtype is None:
        dtype = np.result_type(*(flat.dtype.fields[c][0] for c in "xyz"))
    out = np.empty((flat.size, 3), dtype=dtype)
    for i, c in enumerate("xyz"):
        out[:, i] = flat[c]
    return out
