"""A sqlite3 bag's messages read straight into buffers of their own, one copy each.

rosbags fetches a message as a Python ``bytes``: SQLite first gathers the blob
from its overflow pages (4 KiB each) into a buffer of its own, and apsw then
copies that into the ``bytes`` object, so a 3 MB cloud is copied twice before
numpy sees it, and the two copies cost more than reading the file itself.
SQLite's incremental blob I/O reads the overflow pages from the OS page cache
straight into an array allocated for that one message: one copy, as for
``readinto`` on the file.

Each message keeps its own buffer (read-only, as the ``bytes`` were), so a
cloud a caller holds on to is never overwritten by the next one, and memory is
freed with the last cloud that views it.  Rows come in rosbags' own order (log
time, then row id for equal log times, as its query gives through the bag's
timestamp index); everything else (which connection a row belongs to, split
bags, zstd-compressed messages) stays rosbags' own code.
"""
from __future__ import annotations

from collections.abc import Collection, Iterator
from functools import partial
from typing import Any

import numpy as np

__all__ = ["read_into_buffers"]


def read_into_buffers(reader: Any) -> bool:
    """Have the sqlite3 storages of an open rosbags ``Reader`` yield one buffer per message.

    False (nothing changed) for mcap bags, or when rosbags' internals are not the
    ones this was written against: the bag is then read as rosbags reads it."""
    storage = getattr(reader, "storage", None)
    storages = getattr(storage, "storages", [storage])  # a bag folder holds one storage per file
    if not storages or not all(_is_sqlite(s) for s in storages):
        return False
    for s in storages:
        # An instance attribute, so DirectoryReader.messages (which maps the storages'
        # connections onto the bag's and decompresses) calls this in place of the method.
        s.messages = partial(_messages, s)
    return True


def _is_sqlite(storage: Any) -> bool:
    try:
        from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader
    except ImportError:
        return False
    return type(storage) is Sqlite3Reader and hasattr(storage.dbconn, "blob_open")


def _messages(storage: Any, connections: Collection[Any], start: int | None = None,
              stop: int | None = None) -> Iterator[tuple[Any, int, memoryview]]:
    """Sqlite3Reader.messages with the same rows and order, each blob in a fresh array."""
    ids = tuple({c.id for c in connections})
    query = ["SELECT topics.id, messages.timestamp, messages.rowid",
             "FROM messages JOIN topics ON messages.topic_id=topics.id",
             f"WHERE topics.id IN ({','.join('?' * len(ids))})"]
    args: list[int] = list(ids)
    if start is not None:
        query.append("AND messages.timestamp >= ?")
        args.append(start)
    if stop is not None:
        query.append("AND messages.timestamp < ?")
        args.append(stop)
    query.append("ORDER BY messages.timestamp, messages.rowid")
    connmap = {c.id: c for c in storage.connections}
    db = storage.dbconn
    blob = None
    try:
        for cid, stamp, rowid in db.execute(" ".join(query), args):
            if blob is None:
                blob = db.blob_open("main", "messages", "data", rowid, False)
            else:
                blob.reopen(rowid)
            buf = np.empty(blob.length(), dtype=np.uint8)
            blob.read_into(buf)
            buf.flags.writeable = False
            yield connmap[cid], stamp, memoryview(buf)
    finally:
        if blob is not None:
            blob.close()

