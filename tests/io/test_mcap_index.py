"""A chunk cut out of (or zeroed in) an MCAP bag is named by its number, log times and messages."""
from __future__ import annotations

import re
import shutil
import struct

import numpy as np
import pytest

from pytest_driveeval.io.ros.mcap_index import chunk_problem
from pytest_driveeval.io.ros.pointcloud2 import encode_pointcloud2, make_cloud
from pytest_driveeval.io.ros.rosbag import (
    Bag,
    BagError,
    BagWriter,
    iter_pointclouds,
    tf_message,
)

T0 = 1_700_000_000_000_000_000
RECOVER = "`mcap recover` (the mcap CLI) salvages the readable messages into a new file"


@pytest.fixture(scope="module")
def chunked(tmp_path_factory):
    """An mcap bag of 12 clouds of 400 kB and their /tf: rosbags closes a chunk past 1 MiB, so
    chunks of 3 clouds (the 12th /tf alone in the last)."""
    path = tmp_path_factory.mktemp("mcap") / "bag"
    with BagWriter(path, "mcap") as w:
        for i in range(12):
            stamp = T0 + i * 100_000_000
            w.write("/points", encode_pointcloud2(make_cloud(25_000, rng=np.random.default_rng(i)), "base_link", stamp))
            w.write("/tf", tf_message([("map", "base_link", stamp, (i, 0, 0), (0, 0, 0, 1))]))
    from rosbags.rosbag2 import Reader
    with Reader(path / "bag.mcap") as r:
        chunks = list(r.storage.chunks)  # read by rosbags, not by the code under test
    assert len(chunks) == 5
    return path, chunks


def damaged(chunked, tmp_path, edit):
    src, chunks = chunked
    dst = tmp_path / "bag"
    shutil.copytree(src, dst)
    raw = (dst / "bag.mcap").read_bytes()
    (dst / "bag.mcap").write_bytes(edit(raw, chunks))
    return dst


def third_chunk(chunks):
    """Byte range of chunk 3 and its message indexes: where the next chunk starts."""
    return chunks[2].chunk_start_offset, chunks[3].chunk_start_offset


CHUNK_3 = "chunk 3 of 5 (log time 1700000000.500 .. 1700000000.800 s, /points x3, /tf x3; indexed at byte {offset})"


def test_a_clean_bag_passes(chunked):
    assert chunk_problem(chunked[0] / "bag.mcap") is None
    assert len(list(iter_pointclouds(chunked[0], "/points"))) == 12


def test_a_chunk_cut_out_is_named(chunked, tmp_path):
    bag = damaged(chunked, tmp_path, lambda raw, c: raw[:third_chunk(c)[0]] + raw[third_chunk(c)[1]:])
    a, b = third_chunk(chunked[1])
    with pytest.raises(BagError) as exc:
        Bag(bag)  # rosbags alone: "Invalid MCAP summary offset."
    assert str(exc.value) == (f"{bag}: bag.mcap: {CHUNK_3.format(offset=a)} is missing: the file is {b - a} bytes "
                              f"shorter than its index says; {RECOVER}")


def test_a_chunk_cut_out_under_a_mended_footer_is_named(chunked, tmp_path):
    def cut_and_mend(raw, chunks):
        a, b = third_chunk(chunks)
        raw = raw[:a] + raw[b:]
        start, offsets = struct.unpack_from("<QQ", raw, len(raw) - 28)
        return raw[:-28] + struct.pack("<QQ", start - (b - a), offsets - (b - a)) + raw[-12:]
    bag = damaged(chunked, tmp_path, cut_and_mend)
    expected = CHUNK_3.format(offset=third_chunk(chunked[1])[0]) + " is missing: the chunks after it are no longer " \
        "where the index says"
    with pytest.raises(BagError, match=re.escape(expected)):
        Bag(bag)


def test_a_zeroed_chunk_is_named(chunked, tmp_path):
    def zero(raw, chunks):
        a, b = third_chunk(chunks)
        return raw[:a] + bytes(b - a) + raw[b:]
    bag = damaged(chunked, tmp_path, zero)
    assert chunk_problem(bag / "bag.mcap") == (f"bag.mcap: {CHUNK_3.format(offset=third_chunk(chunked[1])[0])} "
                                               f"is missing or damaged: that byte holds zeros, not a chunk; {RECOVER}")


def test_bytes_cut_inside_a_chunk_locate_the_damage(chunked, tmp_path):
    a = third_chunk(chunked[1])[0]
    bag = damaged(chunked, tmp_path, lambda raw, c: raw[:a + 5000] + raw[a + 9000:])
    problem = chunk_problem(bag / "bag.mcap")
    assert problem.startswith("bag.mcap is damaged: its records stop making sense at byte ")
    assert "the damage lies between the start of the chunk of log time 1700000000.500 .. 1700000000.800 s" in problem


def test_a_file_cut_short_has_no_footer(chunked, tmp_path):
    bag = damaged(chunked, tmp_path, lambda raw, c: raw[: len(raw) // 2])
    with pytest.raises(BagError, match=r"bag.mcap does not end with an MCAP footer: the file was cut short"):
        Bag(bag)


def test_not_an_mcap_or_unindexed_is_left_to_the_reader(tmp_path):
    (tmp_path / "x.mcap").write_bytes(b"not an mcap")
    assert chunk_problem(tmp_path / "x.mcap") is None
    assert chunk_problem(tmp_path / "missing.mcap") is None
