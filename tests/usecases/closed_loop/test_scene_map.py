"""The map a closed-loop scene's GIF draws: a ScenarioNet scenario's lanes, road lines, road edges
and crosswalks (none for an L5 zarr), and the GIFs of a ScenarioNet scenario drawn on it, in one
batch and in chunks."""
import json
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO_ROOT
from pytest_driveeval.geometry.polygons import points_in_polygon
from pytest_driveeval.io.scenarionet.scenarionet import MapFeature, ScenarioNetScene, read_scenario, scenario_files
from pytest_driveeval.io.scenarionet.scenarionet_l5 import ScenarioNetDataset
from pytest_driveeval.usecases.closed_loop.scene_map import drawn_map, drawn_map_of


def made_scene(features: list[MapFeature]) -> ScenarioNetScene:
    return ScenarioNetScene(Path("made.pkl"), "made", "test", 0.1, np.arange(3) * 0.1, 0, None, features, [], {})


def test_each_kind_of_feature_goes_to_its_layer_in_two_columns():
    lane_polygon = np.array([[0.0, -2, 0], [10, -2, 0], [10, 2, 0], [0, 2, 0]])
    scene = made_scene([
        MapFeature("lane", "LANE_SURFACE_STREET", "lane", polyline=np.array([[0.0, 0, 0.0], [10, 0, 0.0]]),
                   polygon=lane_polygon),
        # no polygon: its boundaries at the default width make its surface
        MapFeature("bare", "LANE_FREEWAY", "lane", polyline=np.array([[0.0, 10, 0.3], [0, 20, 0.3]])),
        MapFeature("line", "ROAD_LINE_BROKEN_SINGLE_WHITE", "road_line", polyline=np.array([[0.0, 2, 1], [10, 2, 1]])),
        MapFeature("edge", "ROAD_EDGE_BOUNDARY", "road_edge", polyline=np.array([[0.0, 4], [10, 4]])),
        MapFeature("walk", "CROSSWALK", "area", polygon=np.array([[4.0, -2], [5, -2], [5, 2], [4, 2]])),
        MapFeature("bump", "SPEED_BUMP", "area", polygon=np.array([[6.0, -2], [7, -2], [7, 2]])),
        MapFeature("stop", "STOP_SIGN", "point", position=np.array([5.0, 2.0, 0.0])),
    ])
    drawn = drawn_map(scene)
    assert len(drawn.lane_surfaces) == 2
    assert np.array_equal(drawn.lane_surfaces[0], lane_polygon[:, :2])
    assert drawn.lane_surfaces[1].shape == (4, 2)  # left boundary there, right boundary back
    assert np.allclose(sorted(set(drawn.lane_surfaces[1][:, 0])), [-1.85, 1.85])
    assert [a.tolist() for a in drawn.road_lines] == [[[0, 2], [10, 2]]]
    assert [a.tolist() for a in drawn.road_edges] == [[[0, 4], [10, 4]]]
    assert [a.tolist() for a in drawn.crosswalks] == [[[4, -2], [5, -2], [5, 2], [4, 2]]]
    assert drawn.present() == ["lane", "road line", "road edge", "crosswalk"]


def test_an_l5_dataset_has_no_map_to_draw():
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset

    assert drawn_map_of(L5Dataset.open(REPO_ROOT / "fixtures" / "l5kit" / "generated.zarr"), 0) is None


def test_a_real_nuscenes_scene_has_lanes_and_road_lines_under_its_logged_car(shared_data):
    folder = shared_data / "scenarionet" / "nuscenes"
    dataset = ScenarioNetDataset(folder)
    drawn = drawn_map_of(dataset, 1)
    scene = read_scenario(scenario_files(folder)[1])
    assert len(drawn.lane_surfaces) > 100 and len(drawn.road_lines) > 50
    assert all(a.ndim == 2 and a.shape[1] == 2 for a in drawn.lane_surfaces + drawn.road_lines)
    # In the scenario's own frame, the one the unroll drives in: the logged car is on a lane.
    xy = scene.tracks.position[scene.sdc, ::10, :2]
    on = np.zeros(len(xy), bool)
    for polygon in drawn.lane_surfaces:
        on |= points_in_polygon(xy[:, 0], xy[:, 1], polygon)
    assert on.mean() > 0.9


SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - nuscenes_mini:
        Path: {data}
  Model: log_replay
  Unroll: {{Scenes: [1, 3], StartFrame: 10, Steps: 30}}
  Conditions:
    Collisions: {{Front: 0, Side: 0, Rear: 0, AtFaultOnly: true}}
  Artefacts: {{Animations: all}}
{executor}"""


def test_the_gifs_of_a_scenarionet_scenario_draw_its_map_in_one_batch_and_in_chunks(pytester, shared_data):
    pytest.importorskip("torch")
    PIL = pytest.importorskip("PIL.Image")
    from pytest_driveeval.report.birdseye import LEGEND_OUTLINE
    from pytest_driveeval.report.map_layers import LANE, ROAD_LINE

    data = shared_data / "scenarionet" / "nuscenes"
    pytester.makefile(".scenario.yaml", batch=SCENARIO.format(name="batch", data=data, executor=""),
                      chunks=SCENARIO.format(name="chunks", data=data,
                                             executor="  Executor: {Kind: local, ChunkSize: 1}\n"))
    pytester.runpytest("-p", "no:randomly")
    folder = pytester.path / "driveeval-results"
    records = {r["scenario"]: r for r in json.loads((folder / "summary.json").read_text())["results"]}
    assert set(records) == {"batch", "chunks"}
    assert len(records["chunks"]["details"]["executor"]["chunks"]) == 2
    for record in records.values():
        for scene in (1, 3):
            with PIL.open(folder / record["artefacts"][f"scene_{scene}_gif"]) as image:
                rgb = np.asarray(image.convert("RGB"))
            colour = (rgb[..., None, :] == np.array([LANE, ROAD_LINE, LEGEND_OUTLINE])).all(-1).sum((0, 1))
            assert colour[0] > 2000 and colour[1] > 100 and colour[2] > 100, (record["scenario"], scene, colour)
