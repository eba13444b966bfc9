"""Large blobs of a SQLite table read from the file's pages, hundreds of pages per system call.

SQLite keeps a blob longer than a page in a chain of overflow pages (4 KiB by
default) and reads that chain one ``pread`` per page; for a 3 MB point cloud
those 800 system calls cost more than copying the bytes.  A file written in one
go (as a recorder writes a bag) lays each chain out on consecutive pages, so
here the chain is read with ``preadv``: each page's 4-byte link into a scratch
array, its content straight into the caller's buffer, 512 pages per call.

Nothing is taken on trust: the row is found by walking the table's b-tree from
its root page, its record must give the blob the length SQLite reports, and
every link read must name the next page (and the last none).  Whatever does
not fit (a chain with a gap, a blob that fits in its page, another platform) is
``None``, and the caller reads that blob through SQLite as before.  The layout
followed is SQLite's documented, stable file format
(https://www.sqlite.org/fileformat2.html, sections 1.3, 1.6, 2.1).
"""
from __future__ import annotations

import ctypes
import os
import struct
from pathlib import Path

import numpy as np

__all__ = ["PageReader"]

_TABLE_LEAF, _TABLE_INTERIOR = 0x0D, 0x05
_IOV_MAX = 1024  # Linux' limit on iovecs per preadv call
_MAX_CACHED = 4096  # interior pages kept (4096 of them index some 10^6 rows)


def _preadv():
    try:
        fn = ctypes.CDLL(None, use_errno=True).preadv
    except (OSError, AttributeError):
        return None
    fn.restype = ctypes.c_ssize_t
    fn.argtypes = [ctypes.c_int, ctypes.c_void_p, ctypes.c_int, ctypes.c_longlong]
    return fn


# 64-bit POSIX only: there off_t is 64 bits, as the signature above says.
_PREADV = _preadv() if os.name == "posix" and ctypes.sizeof(ctypes.c_void_p) == 8 else None


def _varint(buf: bytes, pos: int) -> tuple[int, int]:
    """SQLite's big-endian varint at ``pos``: (value, position after it)."""
    value = 0
    for i in range(8):
        byte = buf[pos + i]
        value = (value << 7) | (byte & 0x7F)
        if byte < 0x80:
            return value, pos + i + 1
    return (value << 8) | buf[pos + 8], pos + 9


def _serial_size(t: int) -> int:
    """Bytes a record column of serial type ``t`` takes."""
    if t < 12:
        return (0, 1, 2, 3, 4, 6, 8, 8, 0, 0, 0, 0)[t]
    return (t - 12) // 2


class PageReader:
    """Blob column ``column`` of the rowid table whose b-tree starts at page ``root``."""

    def __init__(self, path: str | os.PathLike, root: int, column: int, min_pages: int = 16):
        self.fd = os.open(path, os.O_RDONLY)
        head = os.pread(self.fd, 100, 0)
        wal = Path(f"{path}-wal")
        if len(head) < 100 or head[:16] != b"SQLite format 3\0" or (wal.exists() and wal.stat().st_size):
            # The newest version of a page may be in the -wal file rather than here.
            os.close(self.fd)
            raise ValueError(f"{path}: not a SQLite 3 file, or one with a write-ahead log")
        size = struct.unpack(">H", head[16:18])[0]
        self.page = 65536 if size == 1 else size
        self.usable = self.page - head[20]  # minus the bytes reserved at each page's end
        self.root, self.column, self.min_pages = root, column, min_pages
        self._interior: dict[int, tuple[bytes, tuple[int, ...], int]] = {}  # page, cell offsets, header
        self._spare = np.empty(max(self.page - self.usable, 1), dtype=np.uint8)
        self._links = np.empty(0, dtype=">u4")

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1

    def read(self, rowid: int, length: int) -> np.ndarray | None:
        """The blob of row ``rowid`` (``length`` bytes as SQLite says), or None if not read here."""
        if _PREADV is None or length < self.min_pages * self.usable:
            return None
        found = self._cell(rowid)
        if found is None:
            return None
        page, pos = found
        payload, pos = _varint(page, pos)
        key, pos = _varint(page, pos)
        if key != rowid:
            return None
        start = self._blob_offset(page, pos, payload)
        if start is None or start[1] != length or start[0] + length != payload:
            return None  # not the blob SQLite has, or not the record's last column
        offset = start[0]
        local = self._local_size(payload)
        if local >= payload or offset >= local or pos + local + 4 > len(page):
            return None
        first = struct.unpack(">I", page[pos + local:pos + local + 4])[0]
        out = np.empty(length, dtype=np.uint8)
        head = local - offset
        out[:head] = np.frombuffer(page, dtype=np.uint8, count=head, offset=pos + offset)
        return out if self._read_chain(first, out, head) else None

    def _local_size(self, payload: int) -> int:
        u = self.usable
        if payload <= u - 35:
            return payload
        m = ((u - 12) * 32 // 255) - 23
        k = m + (payload - m) % (u - 4)
        return k if k <= u - 35 else m

    def _blob_offset(self, page: bytes, pos: int, payload: int) -> tuple[int, int] | None:
        """(offset in the record, length) of the column, if a blob whose header is in the page."""
        header, p = _varint(page, pos)
        if header > min(self._local_size(payload), len(page) - pos):
            return None
        offset = header
        for col in range(self.column + 1):
            if p >= pos + header:
                return None  # fewer columns than expected
            t, p = _varint(page, p)
            if t in (10, 11):
                return None  # reserved serial types: SQLite calls the record corrupt
            if col < self.column:
                offset += _serial_size(t)
        if t < 12 or t % 2:
            return None  # not a blob
        return offset, (t - 12) // 2

    def _page(self, number: int) -> bytes | None:
        data = os.pread(self.fd, self.page, (number - 1) * self.page)
        return data if len(data) == self.page else None

    def _cell(self, rowid: int) -> tuple[bytes, int] | None:
        """The leaf page holding ``rowid`` and its cell's offset there."""
        number = self.root
        for _ in range(32):  # deeper than any real b-tree
            known = self._interior.get(number)
            if known is None:
                page = self._page(number)
                if page is None:
                    return None
                h = 100 if number == 1 else 0
                kind, cells = page[h], struct.unpack(">H", page[h + 3:h + 5])[0]
                if kind == _TABLE_LEAF:
                    return self._leaf_cell(page, h, cells, rowid)
                if kind != _TABLE_INTERIOR:
                    return None
                if len(self._interior) >= _MAX_CACHED:
                    self._interior.clear()
                known = self._interior[number] = (
                    page, struct.unpack(f">{cells}H", page[h + 12:h + 12 + 2 * cells]), h)
            page, ptrs, h = known
            lo, hi = 0, len(ptrs)
            while lo < hi:  # first cell whose key (largest rowid on its left) >= rowid
                mid = (lo + hi) // 2
                if _varint(page, ptrs[mid] + 4)[0] < rowid:
                    lo = mid + 1
                else:
                    hi = mid
            at = ptrs[lo] if lo < len(ptrs) else h + 8  # else the right-most pointer
            number = struct.unpack(">I", page[at:at + 4])[0]
        return None

    @staticmethod
    def _leaf_cell(page: bytes, h: int, cells: int, rowid: int) -> tuple[bytes, int] | None:
        ptrs = struct.unpack(f">{cells}H", page[h + 8:h + 8 + 2 * cells])
        lo, hi = 0, cells
        while lo < hi:  # cells are sorted by rowid
            mid = (lo + hi) // 2
            if _varint(page, _varint(page, ptrs[mid])[1])[0] < rowid:
                lo = mid + 1
            else:
                hi = mid
        return (page, ptrs[lo]) if lo < cells else None

    def _read_chain(self, first: int, out: np.ndarray, done: int) -> bool:
        """Overflow pages first, first+1, ... into out[done:]; False unless each link says so."""
        content = self.usable - 4
        pages = -(-(out.size - done) // content)
        if pages > len(self._links):
            self._grow(pages)
        per_page = self._iov.shape[1]
        iov = self._iov[:pages].copy()
        iov[:, 1, 0] += out.__array_interface__["data"][0] + done
        iov = iov.reshape(-1, 2)[:pages * per_page - (per_page - 2)]  # the last page: link and content
        iov[-1, 1] = out.size - done - content * (pages - 1)
        left = (out.size - done) + (pages - 1) * (self.page - self.usable) + 4 * pages  # bytes to read
        step = _IOV_MAX // per_page
        for i in range(0, pages, step):
            want = min(step * self.page, left)
            got = _PREADV(self.fd, iov[i * per_page:].__array_interface__["data"][0],
                          min(step * per_page, len(iov) - i * per_page), (first - 1 + i) * self.page)
            if got != want:
                return False  # past the end of the file, or an error: SQLite will say which
            left -= want
        links = self._links[:pages].astype(np.int64)
        links -= first
        return links[-1] == -first and links[:-1].tobytes() == self._steps[:pages - 1].tobytes()

    def _grow(self, pages: int) -> None:
        """Scratch for the links and the iovec template (content offsets relative to the buffer)."""
        pages = max(pages, 2 * len(self._links))
        self._links = np.empty(pages, dtype=">u4")
        self._steps = np.arange(1, pages + 1, dtype=np.int64)
        reserved = self.page - self.usable
        iov = np.zeros((pages, 3 if reserved else 2, 2), dtype=np.uint64)
        iov[:, 0, 0] = self._links.__array_interface__["data"][0] + 4 * np.arange(pages, dtype=np.uint64)
        iov[:, 0, 1] = 4
        iov[:, 1, 0] = (self.usable - 4) * np.arange(pages, dtype=np.uint64)
        iov[:, 1, 1] = self.usable - 4
        if reserved:
            iov[:, 2, 0] = self._spare.__array_interface__["data"][0]
            iov[:, 2, 1] = reserved
        self._iov = iov
