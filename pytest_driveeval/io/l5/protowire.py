"""Just enough of the protocol buffers wire format to read and write l5kit's map.

Messages are walked field by field in Python (``fields``); the bulk of a map,
its packed ``sint32`` coordinate deltas, is decoded and encoded for all elements
at once with numpy (``decode_sint32_spans``, ``encode_sint32``), which is what
makes a hand-written codec as fast as the C parser plus the Python it needs to
hand the values over (see benchmarks/bench_semantic_map.py).

Wire types: 0 varint, 1 fixed 64 bit, 2 length-delimited, 5 fixed 32 bit; the
deprecated groups (3, 4) are rejected.  Errors are ``WireError`` with the byte
offset; callers add the file name.
"""
from __future__ import annotations

import struct

import numpy as np

VARINT, FIXED64, LENGTH, FIXED32 = 0, 1, 2, 5
_MAX_VARINT_BYTES = 10
_SINT32_BYTES = 5  # 32 bits of zigzag in 7-bit groups


class WireError(ValueError):
    def __init__(self, offset: int, message: str):
        self.offset = offset
        super().__init__(f"byte {offset}: {message}")


def read_varint(buf: bytes, pos: int, end: int) -> tuple[int, int]:
    """(value, position after it)."""
    if pos >= end:
        raise WireError(pos, "truncated varint")
    b = buf[pos]
    if b < 0x80:  # tags and short lengths: most calls stop here
        return b, pos + 1
    start, value, shift = pos, b & 0x7F, 7
    pos += 1
    while True:
        if pos >= end:
            raise WireError(start, "truncated varint")
        b = buf[pos]
        value |= (b & 0x7F) << shift
        pos += 1
        if b < 0x80:
            return value, pos
        shift += 7
        if shift >= 7 * _MAX_VARINT_BYTES:
            raise WireError(start, "varint longer than 10 bytes")


def fields(buf: bytes, pos: int, end: int):
    """Yield ``(field, wire_type, a, b)`` for each field of the message in ``buf[pos:end]``.

    ``buf[a:b]`` is the field's payload: the bytes of a length-delimited
    field's content, of a varint, or of a fixed-size value.
    """
    while pos < end:
        key, pos = read_varint(buf, pos, end)
        field, wire = key >> 3, key & 7
        if field == 0:
            raise WireError(pos, "field number 0")
        if wire == LENGTH:
            size, start = read_varint(buf, pos, end)
            pos = start + size
            if pos > end:
                raise WireError(start, f"field {field}: length {size} runs past the end of its message ({end})")
            yield field, wire, start, pos
        elif wire == VARINT:
            start = pos
            _, pos = read_varint(buf, pos, end)
            yield field, wire, start, pos
        elif wire == FIXED32 or wire == FIXED64:
            start, pos = pos, pos + (4 if wire == FIXED32 else 8)
            if pos > end:
                raise WireError(start, f"field {field}: truncated fixed-size value")
            yield field, wire, start, pos
        else:
            raise WireError(pos, f"field {field}: unsupported wire type {wire}")


def sfixed32(buf: bytes, pos: int) -> int:
    return struct.unpack_from("<i", buf, pos)[0]


def decode_sint32_spans(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Decode the zigzag varints in each byte span ``buf[starts[i]:ends[i]]``.

    Returns (values int64 in span order, number of values per span).  A span
    is a packed field's payload or one unpacked varint; each must hold whole varints.
    """
    starts, ends = np.asarray(starts, np.int64), np.asarray(ends, np.int64)
    lengths = ends - starts
    counts = np.zeros(starts.size, np.int64)
    total = int(lengths.sum())
    if total == 0:
        return np.zeros(0, np.int64), counts
    filled = lengths > 0
    first = np.cumsum(lengths) - lengths  # each span's first byte in the gathered array
    index = np.repeat(starts - first, lengths) + np.arange(total)
    data = buf[index]
    last = data < 0x80
    open_end = filled & ~last[np.maximum(first + lengths - 1, 0)]
    if open_end.any():
        raise WireError(int(ends[open_end][0]), "packed varints cut off at the end of their field")
    value_start = np.flatnonzero(np.concatenate([[True], last[:-1]]))
    which = np.cumsum(last) - last
    place = np.arange(total) - value_start[which]
    if place.max() >= _SINT32_BYTES:
        at = int(index[np.argmax(place >= _SINT32_BYTES)])
        raise WireError(at, "varint too long for a sint32")
    shifted = (data & 0x7F).astype(np.uint64) << (7 * place).astype(np.uint64)
    raw = np.add.reduceat(shifted, value_start)
    values = (raw >> np.uint64(1)).astype(np.int64) ^ -(raw & np.uint64(1)).astype(np.int64)
    counts[filled] = np.add.reduceat(last.astype(np.int64), first[filled])
    return values, counts


def encode_sint32(values: np.ndarray) -> tuple[bytes, np.ndarray]:
    """Zigzag varints of ``values``, all in one byte string, and each value's end offset in it."""
    v = np.asarray(values, np.int64)
    if v.size and (v.min() < -(2**31) or v.max() >= 2**31):
        raise ValueError("value out of sint32 range")
    zigzag = ((v << 1) ^ (v >> 63)).astype(np.uint64)
    nbytes = np.ones(v.size, np.int64)
    for k in range(1, _SINT32_BYTES):
        nbytes += zigzag >= np.uint64(1 << (7 * k))
    ends = np.cumsum(nbytes)
    which = np.repeat(np.arange(v.size), nbytes)
    place = np.arange(int(ends[-1]) if v.size else 0) - (ends - nbytes)[which]
    out = (zigzag[which] >> (7 * place).astype(np.uint64)) & np.uint64(0x7F)
    more = place < nbytes[which] - 1
    out = out.astype(np.uint8) | (more.astype(np.uint8) << 7)
    return out.tobytes(), ends


def varint(value: int) -> bytes:
    out = bytearray()
    while value >= 0x80:
        out.append((value & 0x7F) | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


def length_field(field: int, payload: bytes) -> bytes:
    return varint(field << 3 | LENGTH) + varint(len(payload)) + payload


def sfixed32_field(field: int, value: int) -> bytes:
    return varint(field << 3 | FIXED32) + struct.pack("<i", value)


def varint_field(field: int, value: int) -> bytes:
    return varint(field << 3 | VARINT) + varint(value)
