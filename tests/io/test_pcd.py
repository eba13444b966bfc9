"""PCD / .pcd.bin readers and writer, on the real VLP16 and t4 sweeps and on generated clouds."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pytest_driveeval.io.t4.pcd import (
    PCDError,
    lzf_compress,
    lzf_decompress,
    read_pcd,
    read_pcd_bin,
    read_pcd_header,
    write_pcd,
    xyz,
)

VLP16 = "pointclouds/vlp16_sample.pcd"
T4_BIN = "t4_sample/data/LIDAR_TOP/n015-2018-07-24-11-22-45+0800__LIDAR_TOP__1532402927647951.pcd.bin"


def mixed_cloud(n=50, seed=0):
    rng = np.random.default_rng(seed)
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "u1"),
                   ("channel", "<u2"), ("t", "<f8"), ("rgb", "u1", (3,)), ("k", "<i4")])
    a = np.zeros(n, dt)
    for name in dt.names:
        col = a[name]
        col[...] = rng.uniform(-100, 100, col.shape) if col.dtype.kind == "f" else \
            rng.integers(0, 200, col.shape)
    return a


def test_vlp16_real_file(shared_data):
    header, cloud = read_pcd(shared_data / VLP16, with_header=True)
    assert header.data == "binary" and header.points == 14831 == cloud.size
    assert cloud.dtype["intensity"] == np.uint8 and cloud.dtype["channel"] == np.uint16
    assert cloud.dtype["time_stamp"] == np.uint32 and cloud.dtype["x"] == np.float32
    # distance is stored by the driver; it must agree with the decoded xyz
    r = np.linalg.norm(xyz(cloud).astype(np.float64), axis=1)
    assert np.allclose(r, cloud["distance"], atol=2e-3)
    assert set(np.unique(cloud["channel"])) <= set(range(16))


@pytest.mark.parametrize("kind", ["binary", "ascii", "binary_compressed"])
def test_vlp16_roundtrip_all_encodings(shared_data, tmp_path, kind):
    cloud = read_pcd(shared_data / VLP16)
    write_pcd(tmp_path / "c.pcd", cloud, data=kind)
    back = read_pcd(tmp_path / "c.pcd")
    assert back.dtype == cloud.dtype and np.array_equal(back, cloud)


def test_pcd_bin_real(shared_data):
    cloud = read_pcd_bin(shared_data / T4_BIN)
    assert cloud.size == 34688 and cloud.dtype.names == ("x", "y", "z", "intensity", "ring")
    assert xyz(cloud).shape == (34688, 3) and xyz(cloud).dtype == np.float32
    assert 0 <= cloud["ring"].min() and cloud["ring"].max() <= 31  # 32-beam HDL-32E


def test_pcd_bin_truncated(tmp_path):
    p = tmp_path / "bad.pcd.bin"
    p.write_bytes(np.zeros(11, "<f4").tobytes())
    with pytest.raises(PCDError, match="bad.pcd.bin"):
        read_pcd_bin(p)


@pytest.mark.parametrize("kind", ["binary", "ascii", "binary_compressed"])
def test_subarray_and_mixed_types_roundtrip(tmp_path, kind):
    a = mixed_cloud()
    write_pcd(tmp_path / "m.pcd", a, data=kind)
    h = read_pcd_header(tmp_path / "m.pcd")
    assert h.counts[h.fields.index("rgb")] == 3 and h.types[h.fields.index("k")] == "I"
    assert np.array_equal(read_pcd(tmp_path / "m.pcd"), a)


def test_padding_fields_skipped(tmp_path):
    body = np.zeros(2, np.dtype([("x", "<f4"), ("pad", "<f4"), ("y", "<f4")]))
    body["x"], body["y"] = [1, 2], [3, 4]
    head = (b"VERSION 0.7\nFIELDS x _ y\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
            b"WIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA binary\n")
    (tmp_path / "p.pcd").write_bytes(head + body.tobytes())
    c = read_pcd(tmp_path / "p.pcd")
    assert c.dtype.names == ("x", "y") and c["y"].tolist() == [3, 4]


def test_truncated_binary_names_file(tmp_path, shared_data):
    raw = (shared_data / VLP16).read_bytes()
    (tmp_path / "t.pcd").write_bytes(raw[:-10])
    with pytest.raises(PCDError, match=r"t\.pcd: truncated binary"):
        read_pcd(tmp_path / "t.pcd")


@pytest.mark.parametrize("bad, line, msg", [
    ("SIZE 4 4\n", 3, "SIZE has 2 entries"),
    ("TYPE X F F\n", 4, "unsupported TYPE"),
    ("DATA zip\n", 9, "DATA must be"),
    ("WIDTH -3\n", 6, "WIDTH must be"),
])
def test_bad_header_names_file_and_line(tmp_path, bad, line, msg):
    lines = ["VERSION 0.7\n", "FIELDS x y z\n", "SIZE 4 4 4\n", "TYPE F F F\n", "COUNT 1 1 1\n",
             "WIDTH 1\n", "HEIGHT 1\n", "POINTS 1\n", "DATA ascii\n"]
    key = bad.split()[0]
    lines = [bad if ln.startswith(key) else ln for ln in lines]
    (tmp_path / "h.pcd").write_text("".join(lines) + "1 2 3\n")
    with pytest.raises(PCDError, match=rf"h\.pcd:{line}: .*{msg}"):
        read_pcd(tmp_path / "h.pcd")


def test_missing_data_line(tmp_path):
    (tmp_path / "n.pcd").write_text("VERSION 0.7\nFIELDS x\nSIZE 4\nTYPE F\n")
    with pytest.raises(PCDError, match="n.pcd:.*DATA"):
        read_pcd(tmp_path / "n.pcd")


def test_corrupt_compressed(tmp_path):
    a = mixed_cloud(10)
    write_pcd(tmp_path / "c.pcd", a, data="binary_compressed")
    raw = (tmp_path / "c.pcd").read_bytes()
    at = raw.index(b"DATA binary_compressed\n") + len(b"DATA binary_compressed\n")
    bad_size = raw[:at + 4] + (10**6).to_bytes(4, "little") + raw[at + 8:]
    (tmp_path / "c.pcd").write_bytes(bad_size)
    with pytest.raises(PCDError, match=r"c\.pcd: corrupt binary_compressed.*header says 1000000"):
        read_pcd(tmp_path / "c.pcd")
    (tmp_path / "c.pcd").write_bytes(raw[:-5])
    with pytest.raises(PCDError, match=r"c\.pcd: truncated binary_compressed"):
        read_pcd(tmp_path / "c.pcd")
    with pytest.raises(ValueError, match="before start of output"):
        lzf_decompress(bytes([0, 65, 0x20, 5]), 4)


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=2000), st.integers(0, 300), st.integers(0, 255))
def test_lzf_roundtrip(data, run, byte):
    data = data + bytes([byte]) * run + data[:7]
    assert lzf_decompress(lzf_compress(data), len(data)) == data


def test_lzf_known_stream():
    # literal "ab", then back-reference distance 2 length 5 (overlapping): "ababababa"? no: 2+5
    stream = bytes([1]) + b"ab" + bytes([(3 << 5) | 0, 1])
    assert lzf_decompress(stream, 7) == b"abababa"


def test_xyz_plain_and_errors():
    assert xyz(np.ones((4, 5))).shape == (4, 3)
    with pytest.raises(ValueError, match="no field"):
        xyz(np.zeros(3, [("x", "f4"), ("y", "f4")]))


# --- a header that says fewer points than the data holds (issue 11) --------
def _fewer_points(raw: bytes, points: int, fewer: int) -> bytes:
    """The same file with WIDTH and POINTS lowered by ``fewer``: consistent with each other, not with the data."""
    for key in (b"WIDTH", b"POINTS"):
        raw = raw.replace(b"\n%s %d\n" % (key, points), b"\n%s %d\n" % (key, points - fewer), 1)
    return raw


def test_binary_data_longer_than_points_is_refused_with_the_numbers(tmp_path, shared_data):
    raw = _fewer_points((shared_data / VLP16).read_bytes(), 14831, 31)
    (tmp_path / "v.pcd").write_bytes(raw)
    with pytest.raises(PCDError, match=r"v\.pcd: binary data: 474592 bytes \(14831 points of 32 bytes\), "
                                       r"but POINTS 14800 needs 473600 bytes$"):
        read_pcd(tmp_path / "v.pcd")


@pytest.mark.parametrize("kind", ["binary", "ascii", "binary_compressed"])
def test_points_smaller_than_the_data_is_refused_in_every_encoding(tmp_path, kind):
    write_pcd(tmp_path / "m.pcd", mixed_cloud(50), data=kind)
    (tmp_path / "m.pcd").write_bytes(_fewer_points((tmp_path / "m.pcd").read_bytes(), 50, 2))
    expected = {"binary": r"binary data: \d+ bytes \(50 points of \d+ bytes\), but POINTS 48 needs",
                "ascii": r"ascii data: 50 rows, but POINTS is 48",
                "binary_compressed": r"binary_compressed data decompresses to \d+ bytes \(50 points of \d+ bytes\), "
                                     r"but POINTS 48 needs"}[kind]
    with pytest.raises(PCDError, match=r"m\.pcd: " + expected):
        read_pcd(tmp_path / "m.pcd")


def test_binary_data_with_a_partial_extra_point(tmp_path):
    write_pcd(tmp_path / "b.pcd", mixed_cloud(5), data="binary")
    (tmp_path / "b.pcd").write_bytes((tmp_path / "b.pcd").read_bytes() + b"\x00" * 7)
    with pytest.raises(PCDError, match=r"b\.pcd: binary data: \d+ bytes \(5 points and 7 bytes of \d+ bytes\)"):
        read_pcd(tmp_path / "b.pcd")


def test_ascii_row_with_a_value_missing_names_its_line(tmp_path):
    head = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 3\nHEIGHT 1\nPOINTS 3\nDATA ascii\n"
    (tmp_path / "a.pcd").write_text(head + "1 2 3\n4 5\n7 8 9 10\n")
    with pytest.raises(PCDError, match=r"a\.pcd:11: ascii row has 2 values, FIELDS/COUNT need 3"):
        read_pcd(tmp_path / "a.pcd")
    (tmp_path / "a.pcd").write_text(head + "1 2 3\n4 5 6\n")
    with pytest.raises(PCDError, match=r"a\.pcd: truncated ascii data: 2 rows, but POINTS is 3"):
        read_pcd(tmp_path / "a.pcd")


def test_bytes_after_the_compressed_block_are_refused(tmp_path):
    write_pcd(tmp_path / "c.pcd", mixed_cloud(10), data="binary_compressed")
    (tmp_path / "c.pcd").write_bytes((tmp_path / "c.pcd").read_bytes() + b"\n")
    with pytest.raises(PCDError, match=r"c\.pcd: binary_compressed data: the size words announce (\d+) "
                                       r"compressed bytes, (\d+) follow them"):
        read_pcd(tmp_path / "c.pcd")


@pytest.mark.parametrize("header, line, expected", [
    ("FIELDS x\nSIZE SECRETKEY\nTYPE F\nWIDTH 1\nDATA ascii\n1\n", 2, "SIZE must be whole numbers, one per field"),
    ("FIELDS x\nSIZE 4\nTYPE SECRETKEY\nWIDTH 1\nDATA ascii\n1\n", 3, "field 1 of 1: unsupported TYPE for its SIZE 4"),
    ("FIELDS x\nSIZE 4\nTYPE F\nWIDTH SECRETKEY\nDATA ascii\n1\n", 4, "WIDTH must be one whole number"),
    ("FIELDS x\nSIZE 4\nTYPE F\nWIDTH 1\nVIEWPOINT SECRETKEY\nDATA ascii\n1\n", 5, "VIEWPOINT must be 7 numbers"),
    ("FIELDS x\nSIZE 4\nTYPE F\nWIDTH 1\nDATA SECRETKEY\n1\n", 5, "DATA must be one of ascii, binary"),
    ("FIELDS x y\nSIZE 4 4\nTYPE F F\nWIDTH 2\nDATA ascii\n1 2\n3 SECRETKEY\n", 7, "field 'y': expected a number"),
])
def test_a_bad_pcd_is_named_by_line_and_never_quoted(tmp_path, header, line, expected):
    path = tmp_path / "p.pcd"
    path.write_text(header)
    with pytest.raises(PCDError) as raised:
        read_pcd(path)
    assert str(raised.value).startswith(f"{path}:{line}: ") and expected in str(raised.value)
    assert "SECRET" not in str(raised.value)
