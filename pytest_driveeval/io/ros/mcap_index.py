"""Check an MCAP file's chunks against its own index before trusting it.

``rosbags`` reads chunks at the offsets the summary gives and does not check
that a chunk is really there: with a chunk cut out of the file it either
refuses to open ("Invalid MCAP summary offset") or decodes whatever bytes now
sit at that offset.  :func:`chunk_problem` says, in words a user can act on,
which chunk is missing or damaged: its number, byte offset, log-time range and
the messages it held.  It reads record headers only (a seek and a few bytes per
chunk), never the chunks' data.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

__all__ = ["chunk_problem"]

MAGIC = b"\x89MCAP0\r\n"
FOOTER_SIZE = 37  # op, length, summary_start, summary_offset_start, crc, magic
OP_FOOTER, OP_CHANNEL, OP_CHUNK, OP_CHUNK_INDEX, OP_DATA_END = 0x02, 0x04, 0x06, 0x08, 0x0F
MAX_OP, PRIVATE_OPS = 0x10, 0x80  # 0x80.. are other tools' own records: valid, skipped
RECOVER = "`mcap recover` (the mcap CLI) salvages the readable messages into a new file"


def _known(op: int) -> bool:
    return 0 < op <= MAX_OP or op >= PRIVATE_OPS


@dataclass(frozen=True)
class ChunkEntry:
    number: int          # 1-based, in index order
    start_ns: int
    end_ns: int
    offset: int
    length: int          # of the whole record, opcode and length prefix included
    uncompressed_size: int
    counts: dict         # channel id -> messages

    def key(self) -> tuple[int, int, int]:
        return self.start_ns, self.end_ns, self.uncompressed_size


def _secs(ns: int) -> str:
    return f"{ns / 1e9:.3f}"


def _read_at(f: BinaryIO, offset: int, size: int) -> bytes:
    f.seek(offset)
    return f.read(size)


def _record_at(f: BinaryIO, offset: int) -> tuple[int, int] | None:
    head = _read_at(f, offset, 9)
    return (head[0], struct.unpack_from("<Q", head, 1)[0]) if len(head) == 9 else None


def _string(body: bytes, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", body, pos)
    return body[pos + 4:pos + 4 + n].decode("utf-8", "replace"), pos + 4 + n


def _parse_summary(f: BinaryIO, start: int, end: int) -> tuple[list[ChunkEntry], dict[int, str]] | None:
    """Chunk index and channel topics of the summary at ``start``; None unless its records
    run exactly to ``end`` (the footer): bytes at a wrong offset almost never do."""
    chunks, topics, pos = [], {}, start
    try:
        while pos < end:
            op, length = _record_at(f, pos) or (0, 0)
            if not _known(op) or pos + 9 + length > end:
                return None
            if op in (OP_CHUNK_INDEX, OP_CHANNEL):
                body = _read_at(f, pos + 9, length)
                if op == OP_CHANNEL:
                    cid, _ = struct.unpack_from("<HH", body)
                    topics[cid] = _string(body, 4)[0]
                else:
                    start_ns, end_ns, offset, clen, maplen = struct.unpack_from("<QQQQI", body)
                    offsets = sorted((o, c) for c, o in struct.iter_unpack("<HQ", body[36:36 + maplen]))
                    (index_len,) = struct.unpack_from("<Q", body, 36 + maplen)
                    _, p = _string(body, 44 + maplen)
                    _, usize = struct.unpack_from("<QQ", body, p)
                    ends = [o for o, _ in offsets[1:]] + [offset + clen + index_len]
                    counts = {c: (e - o - 15) // 16 for (o, c), e in zip(offsets, ends)}
                    chunks.append(ChunkEntry(len(chunks) + 1, start_ns, end_ns, offset, clen, usize, counts))
            pos += 9 + length
    except struct.error:
        return None
    return (chunks, topics) if pos == end else None


def _scan(f: BinaryIO, start: int, end: int) -> tuple[set, int | None, int | None, tuple | None]:
    """Walk the data section's record headers: (chunk keys seen, Data End offset or None,
    byte where the records stop making sense or None, last intact chunk's times)."""
    seen, pos, last = set(), start, None
    while pos < end:
        rec = _record_at(f, pos)
        if rec is None or not _known(rec[0]) or pos + 9 + rec[1] > end:
            return seen, None, pos, last
        op, length = rec
        if op == OP_DATA_END:
            return seen, pos, None, last
        if op == OP_CHUNK:
            start_ns, end_ns, usize = struct.unpack("<QQQ", _read_at(f, pos + 9, 24))
            seen.add((start_ns, end_ns, usize))
            last = (start_ns, end_ns)
        pos += 9 + length
    return seen, None, pos, last


def _describe(chunk: ChunkEntry, total: int, topics: dict[int, str]) -> str:
    msgs = ", ".join(f"{topics.get(c, f'channel {c}')} x{n}" for c, n in sorted(chunk.counts.items()) if n)
    return (f"chunk {chunk.number} of {total} (log time {_secs(chunk.start_ns)} .. {_secs(chunk.end_ns)} s, "
            f"{msgs or 'no messages'}; indexed at byte {chunk.offset})")


def _misplaced(f: BinaryIO, chunk: ChunkEntry) -> str | None:
    """What sits at the chunk's indexed offset if it is not that chunk, else None."""
    head = _read_at(f, chunk.offset, 9 + 24)
    if len(head) < 9 + 24:
        return "the file ends before it"
    op, length = head[0], struct.unpack_from("<Q", head, 1)[0]
    if op != OP_CHUNK:
        return f"that byte holds {'zeros' if not any(head) else f'a record of type 0x{op:02x}'}, not a chunk"
    start_ns, end_ns, usize = struct.unpack_from("<QQQ", head, 9)
    if (start_ns, end_ns, usize) != chunk.key():
        return f"the chunk found there covers log time {_secs(start_ns)} .. {_secs(end_ns)} s"
    if length != chunk.length - 9:
        return f"the chunk there is {length + 9} bytes long, the index says {chunk.length}"
    return None


def _missing(path: Path, missing: list[ChunkEntry], total: int, topics: dict[int, str], why: str) -> str:
    head = f"{path.name}: {_describe(missing[0], total, topics)} is missing"
    if len(missing) > 1:
        head += f", and {len(missing) - 1} more (chunks {', '.join(str(c.number) for c in missing[1:])})"
    return f"{head}: {why}; {RECOVER}"


def chunk_problem(path: str | Path) -> str | None:
    """Why the MCAP file's chunks do not match its index, or None if they do (or it has no index).

    A file without an MCAP footer (the recorder was stopped hard) is reported too;
    other malformations (and unreadable files) are left to the reader's own errors.
    """
    path = Path(path)
    try:
        return _problem(path)
    except (OSError, struct.error):
        return None


def _problem(path: Path) -> str | None:
    with open(path, "rb") as f:
        size = f.seek(0, 2)
        if _read_at(f, 0, 8) != MAGIC:
            return None
        footer = _read_at(f, size - FOOTER_SIZE, FOOTER_SIZE) if size >= FOOTER_SIZE else b""
        if len(footer) < FOOTER_SIZE or footer[-8:] != MAGIC or footer[0] != OP_FOOTER:
            return (f"{path.name} does not end with an MCAP footer: the file was cut short (the recorder "
                    f"stopped before closing it, or a copy was incomplete); {RECOVER}")
        footer_start = size - FOOTER_SIZE
        (summary_start,) = struct.unpack_from("<Q", footer, 9)
        if summary_start == 0:
            return None  # unindexed: the reader scans the records in order
        header = _record_at(f, 8)
        data_start = 8 + 9 + header[1] if header else 8
        parsed = _parse_summary(f, summary_start, footer_start) if summary_start <= footer_start else None
        bad = []
        if parsed is not None:
            bad = [(c, why) for c in parsed[0] if (why := _misplaced(f, c)) is not None]
            if not bad:
                return None
        # A chunk not at its offset is missing, damaged, or moved by bytes cut out before
        # it: walking the records tells which, if they still chain up to the index.
        seen, data_end, broken, last = _scan(f, data_start, footer_start)
        if data_end is None:
            if bad:
                (first, why), more = bad[0], len(bad) - 1
                return (f"{path.name}: {_describe(first, len(parsed[0]), parsed[1])} is missing or damaged: "
                        f"{why}" + (f"; {more} later chunk(s) too" if more else "") + f"; {RECOVER}")
            since = (f"the start of the chunk of log time {_secs(last[0])} .. {_secs(last[1])} s"
                     if last else "the start of the data")
            return (f"{path.name} is damaged: its records stop making sense at byte {broken}, and its index "
                    f"cannot be found; the damage lies between {since} and that byte; {RECOVER}")
        actual_summary = data_end + 9 + (_record_at(f, data_end) or (0, 0))[1]
        if parsed is None:
            parsed = _parse_summary(f, actual_summary, footer_start)
            if parsed is None:
                return f"{path.name}: its index (the MCAP summary section) is unreadable; {RECOVER}"
        chunks, topics = parsed
        missing = [c for c in chunks if c.key() not in seen]
        shift = summary_start - actual_summary
        why = (f"the file is {shift} bytes shorter than its index says" if shift > 0 else
               f"the file is {-shift} bytes longer than its index says" if shift < 0 else
               "the chunks after it are no longer where the index says")
        if missing:
            return _missing(path, missing, len(chunks), topics, why)
        return f"{path.name}: every chunk is there, but {why}; {RECOVER}"
