"""The generator's L5 semantic map: beside the zarr, consistent with its lanes and lights."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import REPO_ROOT
from pytest_driveeval.io.l5.l5_semantic_map import GREEN, RED, YELLOW, read_meta, read_semantic_map
from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
from pytest_driveeval.synth.scenegen import LANE_WIDTH, generate_zarr, road_layout, semantic_map

NUM_FRAMES = 60


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    path = tmp_path_factory.mktemp("gen") / "synthetic.zarr"
    generate_zarr(path, 3, NUM_FRAMES, seed=5)
    return path


def _distance_to_polyline(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    a, b = line[:-1], line[1:]
    ab = b - a
    t = np.clip(np.einsum("pkj,kj->pk", points[:, None] - a, ab) / np.einsum("kj,kj->k", ab, ab), 0, 1)
    return np.linalg.norm(points[:, None] - (a + t[..., None] * ab), axis=-1).min(axis=1)


def test_map_and_meta_are_written_beside_the_zarr(generated):
    smap = read_semantic_map(generated.parent / "semantic_map.pb", generated.parent / "meta.json")
    expected = semantic_map(NUM_FRAMES)
    assert smap.lane_ids.tolist() == expected.lane_ids.tolist()
    np.testing.assert_allclose(smap.lanes_left.points, expected.lanes_left.points, atol=0.01)
    np.testing.assert_allclose(smap.crosswalks.points, expected.crosswalks.points, atol=0.01)
    # The same world frame as the real dataset's meta.json, so either zarr can sit beside it.
    np.testing.assert_array_equal(read_meta(generated.parent / "meta.json"),
                                  read_meta(REPO_ROOT / "fixtures" / "l5kit" / "semantic_map" / "meta.json"))


def test_faces_are_the_zarrs_with_their_colours(generated):
    smap = read_semantic_map(generated.parent / "semantic_map.pb", generated.parent / "meta.json")
    dataset = L5Dataset.open(generated)
    zarr_faces = {f for k in range(dataset.num_scenes) for f in dataset.scene(k).traffic_light_faces["face_id"].tolist()}
    assert zarr_faces and set(smap.face_ids.tolist()) == zarr_faces
    by_word = {"red": RED, "amber": YELLOW, "green": GREEN}
    assert {f: c for f, c in zip(smap.face_ids.tolist(), smap.face_colours.tolist())} == {
        f: by_word[f.rsplit("_", 1)[1]] for f in zarr_faces}
    controlled = [i for i in range(len(smap.lane_ids)) if len(smap.lane_controls(i))]
    assert [smap.lane_ids[i] for i in controlled] == [f"{name}/junction" for name in
                                                     ("east_0", "east_1", "west_0", "bike_east", "cross_north")]
    for i in controlled:
        light = smap.lane_controls(i)[0]
        faces = smap.face_ids[smap.face_light_index == list(smap.traffic_light_ids).index(light)]
        assert smap.lane_controls(i).tolist() == [light, *faces.tolist()]


def test_boundaries_lie_half_a_lane_width_from_the_centerlines():
    smap = semantic_map(NUM_FRAMES)
    centres = road_layout(NUM_FRAMES)["lanes"]
    for i, lane_id in enumerate(smap.lane_ids.tolist()):
        name = lane_id.split("/")[0]
        half = 0.75 if name == "bike_east" else LANE_WIDTH / 2
        for side in (smap.lanes_left[i], smap.lanes_right[i]):
            np.testing.assert_allclose(_distance_to_polyline(side, centres[name]), half, atol=0.02, err_msg=lane_id)
        # Left is on the left of travel: the cross product of direction and left - right is positive.
        d = smap.lanes_left[i][-1] - smap.lanes_left[i][0]
        offset = smap.lanes_left[i][0] - smap.lanes_right[i][0]
        assert d[0] * offset[1] - d[1] * offset[0] > 0, lane_id
    assert not any(lane.startswith("walk") for lane in smap.lane_ids.tolist())  # sidewalks are not lanes


def test_crosswalks_are_at_the_junction():
    layout = road_layout(NUM_FRAMES)
    smap = semantic_map(NUM_FRAMES)
    jx, jy = layout["junction"]
    assert len(smap.crosswalks) == 4
    assert sorted(smap.crosswalks_within(jx - 15, jy - 15, jx + 15, jy + 15).tolist()) == [0, 1, 2, 3]
    assert smap.crosswalks_within(jx + 50, jy - 15, jx + 80, jy + 15).size == 0


def test_map_is_deterministic_and_not_silently_replaced(tmp_path):
    first = generate_zarr(tmp_path / "a.zarr", 1, 20, seed=1)
    data = (first.parent / "semantic_map.pb").read_bytes()
    generate_zarr(tmp_path / "b.zarr", 1, 20, seed=2)  # the same layout: the same map, allowed
    assert (tmp_path / "semantic_map.pb").read_bytes() == data
    with pytest.raises(FileExistsError, match="semantic_map.pb holds another map"):
        generate_zarr(tmp_path / "c.zarr", 1, 20, seed=1, junction_at=300.0)
    assert not (tmp_path / "c.zarr").exists()
    generate_zarr(tmp_path / "d.zarr", 1, 20, seed=1, map_dir=tmp_path / "elsewhere", junction_at=300.0)
    assert read_semantic_map(tmp_path / "elsewhere" / "semantic_map.pb", tmp_path / "elsewhere" / "meta.json"
                             ).crosswalks.bounds[:, 0].min() > 290
