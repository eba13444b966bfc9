"""Blobs read from a SQLite file's pages (io.sqlite_pages) are SQLite's own bytes, or not read at all."""
from __future__ import annotations

import ctypes
import sqlite3

import numpy as np
import pytest

from pytest_driveeval.io import sqlite_pages
from pytest_driveeval.io.pointcloud2 import XYZI_FIELDS, XYZIRC_FIELDS, encode_pointcloud2, make_cloud
from pytest_driveeval.io.rosbag import POINTCLOUD2, Bag, BagError, BagWriter, default_typestore, iter_pointclouds
from pytest_driveeval.io.sqlite_pages import PageReader

apsw = pytest.importorskip("apsw")
pytestmark = pytest.mark.skipif(sqlite_pages._PREADV is None, reason="no preadv on this platform")

SCHEMA = ("CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, "
          "timestamp INTEGER NOT NULL, data BLOB NOT NULL)")
SIZES = [0, 7, 3000, 70_000, 70_001, 1 << 20, 3_200_123]


def make_db(path, sizes, page_size=4096, pragmas=(), reserve=0):
    rng = np.random.default_rng(len(sizes))
    blobs = [rng.integers(0, 256, n, dtype=np.uint8).tobytes() for n in sizes]
    con = apsw.Connection(str(path))
    if reserve:  # bytes SQLite leaves unused at the end of every page (e.g. for encryption)
        n = ctypes.c_int(reserve)
        con.file_control("main", 38, ctypes.addressof(n))  # SQLITE_FCNTL_RESERVE_BYTES
    con.execute(f"PRAGMA page_size={page_size}")
    for p in pragmas:
        con.execute(p)
    con.execute(SCHEMA)
    with con:
        for i, b in enumerate(blobs):
            con.execute("INSERT INTO messages (topic_id, timestamp, data) VALUES (1, ?, ?)", (i, b))
    con.close()
    return blobs


def reader(path, **kw):
    con = sqlite3.connect(path)
    (root,) = con.execute("SELECT rootpage FROM sqlite_master WHERE name='messages'").fetchone()
    con.close()
    return PageReader(path, root, 3, **kw)


def sqlite_rows(path):
    con = sqlite3.connect(f"file:{path}?immutable=1", uri=True)
    rows = con.execute("SELECT rowid, length(data), data FROM messages ORDER BY rowid").fetchall()
    con.close()
    return rows


@pytest.mark.parametrize("page_size", [512, 1024, 4096, 65536])
def test_blobs_read_from_pages_are_sqlites_bytes(tmp_path, page_size):
    path = tmp_path / "m.db3"
    make_db(path, SIZES, page_size)
    pages = reader(path, min_pages=2)
    assert pages.page == page_size
    read = 0
    for rowid, length, data in sqlite_rows(path):
        got = pages.read(rowid, length)
        if got is not None:
            assert got.tobytes() == data
            read += 1
        else:  # only blobs that fit in a page or two are left to SQLite
            assert length < 2 * page_size
    pages.close()
    assert read >= 2


def test_rows_are_found_through_a_deep_b_tree(tmp_path):
    path = tmp_path / "m.db3"
    make_db(path, [20_000 if i % 37 == 0 else i % 50 for i in range(3000)], page_size=512)
    con = sqlite3.connect(path)
    (depth,) = con.execute("SELECT max(length(path) - length(replace(path, '/', ''))) FROM dbstat "
                           "WHERE name = 'messages' AND pagetype = 'leaf'").fetchone()
    con.close()
    assert depth >= 3  # root, interior pages, leaves
    pages = reader(path, min_pages=2)
    read = [pages.read(rowid, length) for rowid, length, _ in sqlite_rows(path)]
    for got, (_, length, data) in zip(read, sqlite_rows(path)):
        assert (got is not None) == (length == 20_000) and (got is None or got.tobytes() == data)


def test_reserved_bytes_at_each_page_end_are_skipped(tmp_path):
    path = tmp_path / "m.db3"
    make_db(path, SIZES, 1024, reserve=32)
    pages = reader(path, min_pages=2)
    assert pages.usable == 1024 - 32
    for rowid, length, data in sqlite_rows(path):
        got = pages.read(rowid, length)
        assert got is None or got.tobytes() == data
    assert pages.read(7, 3_200_123) is not None


def test_a_chain_with_gaps_is_left_to_sqlite(tmp_path):
    """Freed pages reused, auto-vacuum's pointer-map pages: the chain is not one run of pages."""
    path = tmp_path / "m.db3"
    make_db(path, [300_000, 50_000, 300_000], 4096, pragmas=["PRAGMA auto_vacuum=FULL"])
    con = sqlite3.connect(path)
    with con:
        con.execute("DELETE FROM messages WHERE id = 1")
        con.execute("INSERT INTO messages (topic_id, timestamp, data) VALUES (1, 9, ?)",
                    (np.arange(2_000_000, dtype=np.uint8).tobytes(),))
    con.close()
    pages = reader(path, min_pages=2)
    results = {rowid: pages.read(rowid, length) for rowid, length, _ in sqlite_rows(path)}
    for rowid, _, data in sqlite_rows(path):
        assert results[rowid] is None or results[rowid].tobytes() == data
    assert results[4] is None  # 2 MB across freed pages and pointer-map pages: not contiguous


def test_wrong_length_row_or_truncated_file_read_nothing(tmp_path):
    path = tmp_path / "m.db3"
    make_db(path, [1 << 20, 1 << 20])
    pages = reader(path)
    assert pages.read(1, (1 << 20) - 1) is None  # not the length SQLite gives
    assert pages.read(3, 1 << 20) is None  # no such row
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) - 100_000])  # the same file, cut inside the second blob
    assert pages.read(1, 1 << 20) is not None and pages.read(2, 1 << 20) is None


def test_a_file_with_a_write_ahead_log_is_not_read_from_pages(tmp_path):
    path = tmp_path / "m.db3"
    make_db(path, [1 << 20], pragmas=["PRAGMA journal_mode=WAL"])
    writer = sqlite3.connect(path)
    writer.execute("PRAGMA wal_autocheckpoint=0")
    with writer:
        writer.execute("UPDATE messages SET data = zeroblob(1048576) WHERE id = 1")
    assert (tmp_path / "m.db3-wal").stat().st_size > 0
    with pytest.raises(ValueError, match="write-ahead log"):
        reader(path)
    writer.close()


@pytest.mark.parametrize("fields", [XYZIRC_FIELDS, XYZI_FIELDS], ids=["xyzirc", "xyzi-padded"])
def test_large_clouds_of_a_bag_come_from_pages_and_equal_rosbags_reading(tmp_path, fields, monkeypatch):
    from rosbags.rosbag2 import Reader

    clouds = [make_cloud(30_000 + 17 * i, fields, rng=np.random.default_rng(i)) for i in range(6)]
    with BagWriter(tmp_path / "bag") as w:
        for i, c in enumerate(clouds):
            w.write("/points", encode_pointcloud2(c, "lidar", 10**18 + i, height=1 + i % 2 * (c.size % 2 == 0)))
    read = []
    real = PageReader.read
    monkeypatch.setattr(PageReader, "read", lambda self, *a: read.append(real(self, *a)) or read[-1])
    with Bag(tmp_path / "bag") as bag:
        frames = list(bag.pointclouds("/points"))
        raws = [raw for *_, raw in bag.raw_messages("/points")]
    assert len(read) == 12 and all(r is not None for r in read)
    with Reader(tmp_path / "bag") as ref:
        expected = [bytes(raw) for _, _, raw in ref.messages()]
    assert [bytes(r) for r in raws] == expected
    for frame, cloud in zip(frames, clouds):
        assert np.array_equal(frame.points, cloud) and frame.points.dtype == cloud.dtype
        assert not frame.points.flags.writeable  # as the views over rosbags' bytes were


def test_a_truncated_bag_of_large_clouds_still_names_the_file(tmp_path):
    with BagWriter(tmp_path / "bag") as w:
        for i in range(8):
            w.write("/points", encode_pointcloud2(make_cloud(40_000), "lidar", 10**18 + i))
    (f,) = (tmp_path / "bag").glob("*.db3")
    raw = f.read_bytes()
    f.write_bytes(raw[: len(raw) * 3 // 4])
    with pytest.raises(BagError, match=r"bag.*\.db3.*malformed"):
        list(iter_pointclouds(tmp_path / "bag", "/points"))


def test_equal_log_times_come_in_rosbags_order(tmp_path):
    from rosbags.rosbag2 import Reader

    with BagWriter(tmp_path / "bag") as w:
        for i in range(12):  # log times 0, 0, 0, 1, 1, 1, ... written out of order
            cloud = make_cloud(5_000 if i % 2 else 5, rng=np.random.default_rng(i))
            w.write("/points", encode_pointcloud2(cloud, f"f{i}", 10**18 + i), log_time_ns=10**18 + (11 - i) // 3)
    with Reader(tmp_path / "bag") as ref:
        expected = [bytes(raw) for _, _, raw in ref.messages()]
    with Bag(tmp_path / "bag") as bag:
        assert [bytes(raw) for *_, raw in bag.raw_messages("/points")] == expected
        assert [f.frame_id for f in bag.pointclouds("/points")] == ["f9", "f10", "f11", "f6", "f7", "f8", "f3",
                                                                   "f4", "f5", "f0", "f1", "f2"]


@pytest.mark.parametrize("mode", ["message", "file"])
def test_compressed_sqlite_bags_read_the_same_clouds(tmp_path, mode):
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

    clouds = [make_cloud(40_000, rng=np.random.default_rng(i)) for i in range(3)]
    ts = default_typestore()
    w = Writer(tmp_path / "bag", version=8)
    w.set_compression(CompressionMode[mode.upper()], CompressionFormat.ZSTD)
    with w:
        conn = w.add_connection("/points", POINTCLOUD2, typestore=ts)
        for i, c in enumerate(clouds):
            w.write(conn, 10**18 + i, ts.serialize_cdr(encode_pointcloud2(c, "lidar", 10**18 + i), POINTCLOUD2))
    frames = list(iter_pointclouds(tmp_path / "bag", "/points"))
    assert len(frames) == 3 and all(np.array_equal(f.points, c) for f, c in zip(frames, clouds))
