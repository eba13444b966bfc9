"""The part of zarr format 2 that l5kit datasets use: 1-D arrays, C order, one file per
chunk, decoded with numcodecs.  zarr 3 cannot read l5kit's structured dtypes and
zarr 2 is unmaintained, so the layout is read and written here directly; files
written here open in zarr 2.18 and match it byte for byte once decoded.
"""
from __future__ import annotations

import base64
import json
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numcodecs
import numpy as np

from ...core.errors import DataError

__all__ = ["ZarrArray1D", "ZarrFormatError", "describe_dtype", "dtype_from_zarr", "dtype_mismatch", "dtype_to_zarr",
           "write_array", "zarr_json"]

_CHUNK_CACHE_SIZE = 8  # decoded chunks kept per array: neighbouring scenes share chunks


class ZarrFormatError(DataError, ValueError):
    """A zarr v2 array that cannot be read as stored."""


def dtype_from_zarr(descr: Any) -> np.dtype:
    """zarr 2 writes ``dtype.descr`` as JSON, so tuples became lists."""
    if isinstance(descr, str):
        return np.dtype(descr)
    fields = []
    for field in descr:
        name, typ = field[0], field[1]
        if isinstance(typ, list):  # nested structured field
            typ = dtype_from_zarr(typ)
        fields.append((name, typ, tuple(field[2])) if len(field) > 2 else (name, typ))
    return np.dtype(fields)


def dtype_to_zarr(dtype: np.dtype) -> list:
    # descr entries are (name, type) or (name, type, shape); JSON wants lists.
    return [[field[0], field[1], list(field[2])] if len(field) > 2 else [field[0], field[1]] for field in dtype.descr]


def describe_dtype(dtype: np.dtype) -> str:
    if dtype.names is None:
        return dtype.str
    parts = []
    for name in dtype.names:
        sub = dtype.fields[name][0]
        base, shape = (sub.base, sub.shape) if sub.subdtype else (sub, ())
        parts.append(f"{name}:{base.str}{list(shape) if shape else ''}")
    return "{" + ", ".join(parts) + "}"


def dtype_mismatch(expected: np.dtype, found: np.dtype) -> str | None:
    """Human-readable difference between two structured dtypes, or None if equal."""
    if expected == found:
        return None
    exp_names, found_names = expected.names or (), found.names or ()
    if exp_names != found_names:
        missing = [n for n in exp_names if n not in found_names]
        extra = [n for n in found_names if n not in exp_names]
        detail = []
        if missing:
            detail.append(f"missing fields {missing}")
        if extra:
            detail.append(f"unexpected fields {extra}")
        if not detail:
            detail.append(f"field order {list(found_names)} instead of {list(exp_names)}")
        return "; ".join(detail)
    diffs = []
    for name in exp_names:
        e, f = expected.fields[name][0], found.fields[name][0]
        if e != f:
            diffs.append(f"field {name!r} is {describe_dtype(np.dtype([(name, f)]))[1:-1]} "
                         f"instead of {describe_dtype(np.dtype([(name, e)]))[1:-1]}")
    return "; ".join(diffs) or "layout (offsets/itemsize) differs"


class ZarrArray1D:
    """Lazy reader of one 1-D zarr v2 array directory."""

    def __init__(self, store: Path, name: str, expected_dtype: np.dtype | None = None,
                 error: type[ZarrFormatError] | None = None, every_chunk_written: bool = False):
        self.error = error or ZarrFormatError  # callers name their format in the errors they catch
        # zarr may leave out a chunk that is all fill value; a format whose rows
        # are never all zeros (L5's) says so, and a missing chunk is then a lost file.
        self.every_chunk_written = every_chunk_written
        self.store, self.name, self.dir = store, name, store / name
        meta_path = self.dir / ".zarray"
        if not meta_path.is_file():
            raise self.error(f"{store}: array {name!r} is missing (expected {meta_path})")
        try:
            meta = json.loads(meta_path.read_text())
        except (OSError, ValueError) as exc:
            raise self.error(f"{meta_path}: unreadable array metadata: {exc}") from exc
        self.meta_path = meta_path
        self._check(meta.get("zarr_format") == 2, f"zarr_format 2 expected, found {meta.get('zarr_format')!r}")
        self._check(meta.get("order", "C") == "C", f"order 'C' expected, found {meta.get('order')!r}")
        shape, chunks = meta.get("shape"), meta.get("chunks")
        self._check(isinstance(shape, list) and len(shape) == 1 and isinstance(chunks, list) and len(chunks) == 1,
                    f"a 1-D array expected, found shape {shape} chunks {chunks}")
        self.length, self.chunk_len = int(shape[0]), int(chunks[0])
        self._check(self.chunk_len > 0, f"chunk length must be positive, found {self.chunk_len}")
        try:
            self.dtype = dtype_from_zarr(meta["dtype"])
        except (KeyError, TypeError, ValueError) as exc:
            raise self.error(f"{meta_path}: array {name!r} has an unreadable dtype {meta.get('dtype')!r}: {exc}") from exc
        if expected_dtype is not None:
            diff = dtype_mismatch(expected_dtype, self.dtype)
            if diff:
                raise self.error(
                    f"{meta_path}: array {name!r} has the wrong dtype ({diff}); "
                    f"expected {describe_dtype(expected_dtype)}, found {describe_dtype(self.dtype)}")
        try:
            self.compressor = numcodecs.get_codec(meta["compressor"]) if meta.get("compressor") else None
            self.filters = [numcodecs.get_codec(f) for f in meta.get("filters") or []]
        except (KeyError, TypeError, ValueError) as exc:
            raise self.error(f"{meta_path}: array {name!r} uses an unsupported codec: {exc}") from exc
        self.fill = self._fill_value(meta.get("fill_value"))
        self.num_chunks = -(-self.length // self.chunk_len)
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        # The last chunk evicted, decoded into again: a fresh buffer per chunk cost as much in
        # page faults as the decoding itself.  Only read() uses chunks, and it copies out of them.
        self._spare: np.ndarray | None = None

    def _check(self, ok: bool, what: str) -> None:
        if not ok:
            raise self.error(f"{self.dir / '.zarray'}: array {self.name!r}: {what}")

    def _fill_value(self, raw: Any) -> np.ndarray:
        fill = np.zeros((), dtype=self.dtype)
        if raw is None or raw == 0:
            return fill
        if self.dtype.names is not None:  # zarr 2 stores structured fill values as base64 bytes
            try:
                data = base64.standard_b64decode(raw)
            except (TypeError, ValueError) as exc:
                raise self.error(f"{self.meta_path}: array {self.name!r}: bad fill_value: {exc}") from exc
            self._check(len(data) == self.dtype.itemsize,
                        f"fill_value holds {len(data)} bytes, dtype itemsize is {self.dtype.itemsize}")
            return np.frombuffer(data, dtype=self.dtype).reshape(())
        fill[()] = raw
        return fill

    def _chunk(self, index: int) -> np.ndarray:
        cached = self._cache.get(index)
        if cached is not None:
            self._cache.move_to_end(index)
            return cached
        path = self.dir / str(index)
        if not path.exists() and self.every_chunk_written:
            first = index * self.chunk_len
            raise self.error(
                f"{self.store}: chunk {index} of array {self.name!r} (rows {first}..{min(first + self.chunk_len, self.length) - 1})"
                f" is missing: {path} does not exist; every chunk of this format holds data, so the file was "
                "deleted or lost: restore the dataset")
        if not path.exists():  # zarr leaves chunks equal to the fill value unwritten
            chunk = np.full(self.chunk_len, self.fill, dtype=self.dtype)
        else:
            raw = path.read_bytes()
            try:
                buf = self._decode(raw)
                for codec in reversed(self.filters):
                    buf = codec.decode(buf)
                data = np.frombuffer(memoryview(buf).cast("B"), dtype=np.uint8)
            except Exception as exc:  # numcodecs raises assorted types for garbage input
                raise self.error(
                    f"{path}: corrupt chunk {index} of array {self.name!r} in {self.store}: "
                    f"cannot decode with {self.compressor}: {exc}") from exc
            full = self.chunk_len * self.dtype.itemsize
            # Edge chunks are written padded by zarr, but be lenient with trimmed ones.
            valid = min(self.chunk_len, self.length - index * self.chunk_len) * self.dtype.itemsize
            if data.size not in (full, valid):
                raise self.error(
                    f"{path}: corrupt chunk {index} of array {self.name!r} in {self.store}: "
                    f"decoded {data.size} bytes, expected {full} ({self.chunk_len} x {self.dtype.itemsize}-byte rows)")
            chunk = data.view(self.dtype)
        self._cache[index] = chunk
        if len(self._cache) > _CHUNK_CACHE_SIZE:
            evicted = self._cache.popitem(last=False)[1].view(np.uint8)
            if evicted.flags.writeable and evicted.size == self.chunk_len * self.dtype.itemsize:
                self._spare = evicted
        return chunk

    def _decode(self, raw: bytes):
        if self.compressor is None:
            return raw
        if not self.filters:
            full = self.chunk_len * self.dtype.itemsize
            out = self._spare if self._spare is not None else np.empty(full, np.uint8)
            self._spare = None
            try:
                return self.compressor.decode(raw, out=out)
            except Exception:  # noqa: BLE001 - e.g. a trimmed edge chunk; decoded again below, where a corrupt one is named
                pass
        return self.compressor.decode(raw)

    def read(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Rows ``[start, stop)`` as a fresh (writable, owned) structured array."""
        stop = self.length if stop is None else stop
        if not 0 <= start <= stop <= self.length:
            raise self.error(f"{self.store}: array {self.name!r}: rows [{start}, {stop}) outside [0, {self.length})")
        out = np.empty(stop - start, dtype=self.dtype)
        if stop == start:
            return out
        first, last = start // self.chunk_len, (stop - 1) // self.chunk_len
        for c in range(first, last + 1):
            c0 = c * self.chunk_len
            lo, hi = max(start, c0), min(stop, c0 + self.chunk_len)
            # As bytes: numpy copies a structured dtype field by field, 3-4x slower than memcpy.
            out[lo - start:hi - start].view(np.uint8)[:] = self._chunk(c)[lo - c0:hi - c0].view(np.uint8)
        return out


def zarr_json(obj: Any) -> str:
    # Same formatting as zarr 2, so stores diff cleanly against zarr-written ones.
    return json.dumps(obj, indent=4, sort_keys=True, ensure_ascii=True, separators=(",", ": "))


def write_array(directory: Path, array: np.ndarray, chunk_len: int, codec: numcodecs.abc.Codec) -> None:
    directory.mkdir(exist_ok=True)
    for stale in directory.iterdir():  # an overwrite with fewer rows must not leave old chunks behind
        if stale.name.isdigit():
            stale.unlink()
    meta = {
        "chunks": [chunk_len],
        "compressor": codec.get_config(),
        "dtype": dtype_to_zarr(array.dtype),
        "fill_value": base64.standard_b64encode(bytes(array.dtype.itemsize)).decode("ascii"),
        "filters": None,
        "order": "C",
        "shape": [len(array)],
        "zarr_format": 2,
    }
    (directory / ".zarray").write_text(zarr_json(meta))
    for index, c0 in enumerate(range(0, len(array), chunk_len)):
        chunk = array[c0:c0 + chunk_len]
        if len(chunk) < chunk_len:  # zarr v2 stores edge chunks at full size
            padded = np.zeros(chunk_len, dtype=array.dtype)
            padded[:len(chunk)] = chunk
            chunk = padded
        (directory / str(index)).write_bytes(codec.encode(chunk.view(np.uint8)))
