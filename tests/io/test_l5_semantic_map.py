"""The L5 semantic map codec: l5kit's own mock map, geometry, round trips, queries, bad files."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from conftest import REPO_ROOT
from pytest_driveeval.core.errors import DataError
from pytest_driveeval.io.l5.l5_semantic_map import (GREEN, RED, YELLOW, Polylines, SemanticMap, read_semantic_map,
                                                 write_semantic_map)

MOCK = REPO_ROOT / "fixtures" / "l5kit" / "semantic_map"
# The l5kit dataset's world frame (l5kit's test artefact meta.json, copied to MOCK).
W2E = np.array([[0.846617444, 0.323463078, -0.422623402, -2698767.44],
                [-0.532201938, 0.514559352, -0.672301845, -4293151.58],
                [-3.05311332e-16, 0.794103464, 0.6077826, 3855164.76],
                [0.0, 0.0, 0.0, 1.0]])
A_WGS84, B_WGS84 = 6378137.0, 6356752.314245179


# A wire-format writer of the test's own, so the reader is checked against bytes it did not make.
def _v(n: int) -> bytes:
    out = b""
    while True:
        out += bytes([(n & 0x7F) | (0x80 if n > 0x7F else 0)])
        n >>= 7
        if not n:
            return out


def _ld(field: int, payload: bytes) -> bytes:
    return _v(field << 3 | 2) + _v(len(payload)) + payload


def _zz(values) -> bytes:
    return b"".join(_v(((v << 1) ^ (v >> 31)) & 0xFFFFFFFF) for v in values)


def _element(eid: bytes, kind: int, body: bytes) -> bytes:
    return _ld(2, _ld(1, _ld(1, eid)) + _ld(2, _ld(kind, body)))


def _frame(lat_e7: int, lng_e7: int) -> bytes:
    return _ld(2, _ld(1, _v(1 << 3 | 5) + struct.pack("<i", lat_e7) + _v(2 << 3 | 5) + struct.pack("<i", lng_e7)))


def _write(tmp_path, data: bytes):
    pb = tmp_path / "semantic_map.pb"
    pb.write_bytes(data)
    meta = tmp_path / "meta.json"
    meta.write_text('{"world_to_ecef": %s}' % W2E.tolist())
    return pb, meta


def _world(ecef: np.ndarray) -> np.ndarray:
    return np.linalg.solve(W2E, np.c_[ecef, np.ones(len(ecef))].T).T[:, :2]


def test_l5kits_mock_map():
    # The 40 bytes, by hand: 12 26 = elements (38 bytes); 12 24 = element (36);
    # 1a 22 = lane (34), with no id and no geo_frame (origin lat 0, lng 0);
    # 1a 0f = left boundary: 0a 03 02 04 06 -> x deltas zigzag 1, 2, 3 cm;
    # 12 03 14 14 14 -> y 10, 10, 10 cm; 1a 03 00 00 00 -> z 0.
    # 22 0f = right boundary: x 1, 2, 3 cm; y 3c -> 30, 30, 30 cm; z 0.
    assert (MOCK / "semantic_map.pb").read_bytes()[:8].hex() == "122612241a221a0f"
    smap = read_semantic_map(MOCK / "semantic_map.pb", MOCK / "meta.json")
    assert smap.lane_ids.tolist() == [""]
    assert len(smap.crosswalks) == 0 and len(smap.face_ids) == 0 and len(smap.lane_control_ids) == 0
    # At lat = lng = 0 east is ECEF +y, north +z, up +x from (a, 0, 0).
    east = np.array([0.01, 0.03, 0.06])
    for line, north in ((smap.lanes_left[0], [0.1, 0.2, 0.3]), (smap.lanes_right[0], [0.3, 0.6, 0.9])):
        expected = _world(np.c_[np.full(3, A_WGS84), east, north])
        np.testing.assert_allclose(line, expected, atol=1e-6)
    np.testing.assert_array_equal(smap.world_to_ecef, W2E)


def _independent_enu_to_ecef(lat_deg, lng_deg, enu):
    lat, lng = np.radians(lat_deg), np.radians(lng_deg)
    n = A_WGS84**2 / np.sqrt((A_WGS84 * np.cos(lat)) ** 2 + (B_WGS84 * np.sin(lat)) ** 2)
    origin = np.array([n * np.cos(lat) * np.cos(lng), n * np.cos(lat) * np.sin(lng),
                       n * (B_WGS84 / A_WGS84) ** 2 * np.sin(lat)])
    rot = np.array([[-np.sin(lng), -np.sin(lat) * np.cos(lng), np.cos(lat) * np.cos(lng)],
                    [np.cos(lng), -np.sin(lat) * np.sin(lng), np.cos(lat) * np.sin(lng)],
                    [0.0, np.cos(lat), np.sin(lat)]])  # columns: east, north, up
    return origin + enu @ rot.T


def test_geometry_matches_l5kits_transform(tmp_path):
    lat_e7, lng_e7 = 374_300_000, -1_221_500_000  # Palo Alto, near the dataset's world origin
    boundary = _ld(1, _zz([1000, 500])) + _ld(2, _zz([-200, 300])) + _ld(3, _zz([0, -7]))
    lane = _frame(lat_e7, lng_e7) + _ld(3, boundary) + _ld(4, boundary)
    pb, meta = _write(tmp_path, _element(b"L1", 3, lane))
    smap = read_semantic_map(pb, meta)
    enu = np.array([[10.0, -2.0, 0.0], [15.0, 1.0, -0.07]])
    expected = _world(_independent_enu_to_ecef(37.43, -122.15, enu))
    np.testing.assert_allclose(smap.lanes_left[0], expected, atol=1e-6)
    # The world frame is east-north-up near its origin: 10 m east is about +10 m in world x.
    assert 9.9 < smap.lanes_left[0][0, 0] - _world(_independent_enu_to_ecef(37.43, -122.15, np.zeros((1, 3))))[0, 0] < 10.1


def test_faces_lights_crosswalks_and_oneof_rules(tmp_path):
    empty = b""
    elements = [
        _element(b"red", 4, _ld(11, empty)),
        _element(b"left_green", 4, _ld(31, empty)),
        _element(b"upper_right_yellow", 4, _ld(42, empty)),
        _element(b"u_turn", 4, _ld(46, empty)),  # l5kit's is_traffic_face ignores u-turn faces
        _element(b"flashing", 4, _ld(9, empty)),
        _element(b"red_then_green", 4, _ld(11, empty) + _ld(13, empty)),  # a oneof keeps the last member
        _element(b"tl", 4, _ld(29, _ld(3, _ld(1, b"red")) + _ld(3, _ld(1, b"left_green")))),
        # A crosswalk with packed x and unpacked (one varint per field) y; the empty one has no points.
        _element(b"walk", 4, _frame(0, 0) + _ld(3, _zz([100, 200])) + _v(4 << 3) + _zz([50]) + _v(4 << 3) + _zz([-50])
                 + _ld(16, empty)),
        _element(b"walk_without_points", 4, _ld(16, empty)),
        _element(b"lane", 3, _ld(8, _ld(1, b"tl")) + _ld(8, _ld(1, b"red")) + _ld(3, _ld(1, _zz([1])) + _ld(2, _zz([2])))
                 + _ld(4, _ld(1, _zz([3])) + _ld(2, _zz([4])))),
    ]
    pb, meta = _write(tmp_path, _ld(1, b"fragment") + b"".join(elements))
    smap = read_semantic_map(pb, meta)
    assert smap.face_ids.tolist() == ["red", "left_green", "upper_right_yellow", "red_then_green"]
    assert smap.face_colours.tolist() == [RED, GREEN, YELLOW, GREEN]
    assert smap.traffic_light_ids.tolist() == ["tl"]
    assert smap.face_light_index.tolist() == [0, 0, -1, -1]
    assert smap.crosswalk_ids.tolist() == ["walk"]
    enu = np.array([[1.0, 0.5, 0.0], [3.0, 0.0, 0.0]])
    np.testing.assert_allclose(smap.crosswalks[0], _world(_independent_enu_to_ecef(0.0, 0.0, enu)), atol=1e-6)
    assert smap.lane_ids.tolist() == ["lane"] and smap.lane_controls(0).tolist() == ["tl", "red"]


def _random_map(rng, num_lanes=40) -> SemanticMap:
    lefts, rights = [], []
    for _ in range(num_lanes):
        k = rng.integers(2, 30)
        centre = rng.uniform(-3000, 3000, 2) + np.cumsum(rng.normal(0, 3, (k, 2)), axis=0)
        lefts.append(centre + [0, 1.75])
        rights.append(centre - [0, 1.75] if rng.random() > 0.1 else np.zeros((0, 2)))
    controls = [["tl_a", "face_r", "face_g"] if i % 3 == 0 else [] for i in range(num_lanes)]
    return SemanticMap(
        lane_ids=np.array([f"lane-{i}-é" for i in range(num_lanes)]),
        lanes_left=Polylines.from_list(lefts), lanes_right=Polylines.from_list(rights),
        lane_control_offsets=np.concatenate([[0], np.cumsum([len(c) for c in controls])]),
        lane_control_ids=np.array([c for cs in controls for c in cs]),
        crosswalk_ids=np.array(["cw0", "cw1"]),
        crosswalks=Polylines.from_list([rng.uniform(-100, 100, (4, 2)), rng.uniform(-100, 100, (5, 2))]),
        face_ids=np.array(["face_r", "face_y", "face_g"]), face_colours=np.array([RED, YELLOW, GREEN], np.int8),
        world_to_ecef=W2E, traffic_light_ids=np.array(["tl_a"]), face_light_index=np.array([0, 0, 0]),
    )


def test_round_trip(tmp_path):
    smap = _random_map(np.random.default_rng(3))
    pb, meta = tmp_path / "sub" / "semantic_map.pb", tmp_path / "sub" / "meta.json"
    write_semantic_map(pb, meta, smap)
    back = read_semantic_map(pb, meta)
    for name in ("lane_ids", "lane_control_offsets", "lane_control_ids", "crosswalk_ids", "face_ids",
                 "face_colours", "traffic_light_ids", "face_light_index", "world_to_ecef"):
        np.testing.assert_array_equal(getattr(back, name), getattr(smap, name), err_msg=name)
    for name in ("lanes_left", "lanes_right", "crosswalks"):
        a, b = getattr(back, name), getattr(smap, name)
        np.testing.assert_array_equal(a.offsets, b.offsets, err_msg=name)
        np.testing.assert_allclose(a.points, b.points, atol=0.01, err_msg=name)  # whole centimetres
        np.testing.assert_allclose(a.bounds, b.bounds, atol=0.01, err_msg=name)
    assert np.isnan(back.lanes_right.bounds).any()  # the empty boundaries stay empty
    assert not list(tmp_path.glob("sub/.*"))  # no temporary files left behind


def test_bounds_queries_follow_l5kits_indices_in_bounds():
    rng = np.random.default_rng(0)
    smap = _random_map(rng, num_lanes=200)
    bounds = smap.lane_bounds
    for _ in range(50):
        centre, half = rng.uniform(-3000, 3000, 2), rng.uniform(1, 400)
        # l5kit: center > min - half and center < max + half on both axes.
        expected = [i for i, (x0, y0, x1, y1) in enumerate(bounds)
                    if centre[0] > x0 - half and centre[1] > y0 - half and centre[0] < x1 + half and centre[1] < y1 + half]
        got = smap.lanes_within(centre[0] - half, centre[1] - half, centre[0] + half, centre[1] + half)
        assert got.tolist() == expected
    # Touching is not overlapping; a lane with one empty boundary is found by the other.
    x0, y0, x1, y1 = bounds[0]
    assert 0 not in smap.lanes_within(x1, y0, x1 + 5, y1)
    assert 0 in smap.lanes_within(x1 - 0.01, y0, x1 + 5, y1)
    cw = smap.crosswalks.bounds[1]
    assert smap.crosswalks_within(*cw).tolist() == [i for i in (0, 1) if
                                                    (smap.crosswalks.bounds[i][:2] < cw[2:]).all()
                                                    and (smap.crosswalks.bounds[i][2:] > cw[:2]).all()]
    assert 1 in smap.crosswalks_within(*cw)


@pytest.mark.parametrize("damage", ["truncate", "garbage", "group", "long_varint"])
def test_corrupt_file_names_the_file(tmp_path, damage):
    good = tmp_path / "good.pb"
    write_semantic_map(good, tmp_path / "meta.json", _random_map(np.random.default_rng(1), 5))
    data = good.read_bytes()
    data = {"truncate": data[:-3], "garbage": b"\x12\xff\xff\xff\x0f" + data, "group": b"\x0b" + data,
            "long_varint": _element(b"x", 3, _ld(3, _ld(1, b"\x80\x80\x80\x80\x80\x01")))}[damage]
    bad = tmp_path / "semantic_map.pb"
    bad.write_bytes(data)
    with pytest.raises(DataError, match=r"semantic_map\.pb.*corrupt or truncated.*byte \d+"):
        read_semantic_map(bad, tmp_path / "meta.json")


def test_an_element_id_that_is_not_text_is_counted_never_quoted(tmp_path):
    pb, meta = _write(tmp_path, _element(b"SECRET\xff\xfeKEY", 3, _ld(3, b"")))
    with pytest.raises(DataError, match=r"semantic_map\.pb.*byte \d+: element id \(11 bytes\) is not UTF-8") as raised:
        read_semantic_map(pb, meta)
    assert "SECRET" not in str(raised.value)


def test_mismatched_delta_counts_are_an_error(tmp_path):
    lane = _ld(3, _ld(1, _zz([1, 2])) + _ld(2, _zz([1])))
    pb, meta = _write(tmp_path, _element(b"L", 3, lane))
    with pytest.raises(DataError, match="semantic_map.pb.*must match"):
        read_semantic_map(pb, meta)


def test_missing_or_bad_meta_and_missing_map(tmp_path):
    with pytest.raises(DataError, match=r"nowhere[/\\]meta\.json: meta\.json not found.*world_to_ecef"):
        read_semantic_map(MOCK / "semantic_map.pb", tmp_path / "nowhere" / "meta.json")
    meta = tmp_path / "meta.json"
    meta.write_text('{\n "world_to_ecef": [1, 2,\n')
    with pytest.raises(DataError, match=r"meta\.json:3: not valid JSON"):
        read_semantic_map(MOCK / "semantic_map.pb", meta)
    meta.write_text('{"world_to_ecef": [[1, 0], [0, 1]]}')
    with pytest.raises(DataError, match="4x4"):
        read_semantic_map(MOCK / "semantic_map.pb", meta)
    with pytest.raises(DataError, match=r"missing\.pb: semantic map not found"):
        read_semantic_map(tmp_path / "missing.pb", MOCK / "meta.json")


def test_inconsistent_map_and_unwritable_colour(tmp_path):
    smap = _random_map(np.random.default_rng(2), 4)
    with pytest.raises(ValueError, match="one polyline per lane id"):
        SemanticMap(**{**smap.__dict__, "lane_ids": smap.lane_ids[:3]})
    unknown = SemanticMap(**{**smap.__dict__, "face_colours": np.array([RED, 0, GREEN], np.int8)})
    with pytest.raises(ValueError, match="face 'face_y': colour 0"):
        write_semantic_map(tmp_path / "m.pb", tmp_path / "meta.json", unknown)
    assert not (tmp_path / "m.pb").exists()
